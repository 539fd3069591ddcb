"""Sizes a config implies, computed and checked before anything is allocated or run.

Per-key ranges cannot catch ``--set uav.footprint_m=[1000,1000]`` (a fine number, a 5 GB
kernel) or ``control.sim.dynamics_dt_s=1e-9`` (a fine step, 6e10 of them): what matters is
the size of the arrays and loops a combination of keys makes. Each function here lists those
sizes as ``Implied`` items (what, how big, the bound and the key that holds it, and the key a
user would change); ``check`` refuses the first one over its bound with a ``ConfigError``
naming that key. Windows that depend on a frame's depth are bounded where they are applied
(``scoring/mask.py``, ``synth/groundtruth.py``): a window larger than the image has a known
result (nothing fits), so it is never built.
"""

from __future__ import annotations

import functools
import json
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from slzcli.config import Config, load_config
from slzcli.errors import ConfigError, DatasetError


@dataclass(frozen=True)
class Implied:
    """One array or loop a config makes: ``size`` units of ``unit``, allowed up to ``bound`` (key ``bound_key``)."""

    key: str            # the key (or option) to change, named first in the error
    what: str           # "dynamics steps of one landing", ...
    size: float
    unit: str
    bound: float
    bound_key: str
    detail: str         # how the size comes about, in the keys' terms

    @property
    def over(self) -> bool:
        return self.size > self.bound


def check(items: list[Implied]) -> None:
    """``ConfigError`` for the first item over its bound, naming the key, the size and the bound."""
    for it in items:
        if it.over:
            raise ConfigError(it.key, f"{it.detail} = {it.size:.3g} {it.unit} ({it.what}), more than "
                                      f"{it.bound_key} {it.bound:.3g}; change {it.key} (or raise {it.bound_key})")


# ----------------------------------------------------------------------------- IBVS simulation
def steps_per_run(config: Config) -> float:
    """Dynamics (RK4) steps of one landing that runs to ``control.sim.timeout_s``."""
    sim = config.control.sim
    return math.ceil(sim.timeout_s / sim.control_dt_s) * max(1, round(sim.control_dt_s / sim.dynamics_dt_s))


def simulation_sizes(config: Config, runs: int) -> list[Implied]:
    """Steps of one landing, runs of a batch and steps of the batch (``slz land simulate [--runs N]``)."""
    sim, mc = config.control.sim, config.control.montecarlo
    per_run = steps_per_run(config)
    items = [Implied(_step_key(config), "dynamics steps of one landing", per_run, "steps", sim.max_steps_per_run,
                     "control.sim.max_steps_per_run",
                     f"control.sim.timeout_s {sim.timeout_s:g} s / control.sim.dynamics_dt_s {sim.dynamics_dt_s:g} s")]
    if runs > 1:
        items += [Implied("--runs", "Monte Carlo runs", runs, "runs", mc.max_runs, "control.montecarlo.max_runs",
                          f"--runs {runs}"),
                  Implied("--runs", "dynamics steps of the whole batch", runs * per_run, "steps", mc.max_total_steps,
                          "control.montecarlo.max_total_steps",
                          f"--runs {runs} x {per_run:.3g} steps a landing")]
    return items


def _step_key(config: Config) -> str:
    """The key that made a landing long: the timeout or the step, whichever moved further from its default."""
    sim, default = config.control.sim, _default_config().control.sim
    longer = sim.timeout_s / default.timeout_s
    finer = default.dynamics_dt_s / sim.dynamics_dt_s
    return "control.sim.timeout_s" if longer > finer else "control.sim.dynamics_dt_s"


@functools.lru_cache(maxsize=1)
def _default_config() -> Config:
    return load_config()


# ----------------------------------------------------------------------------- slz synth
def synth_frames(config: Config, frames: int) -> list[Implied]:
    """The frames of one ``slz synth`` flight (arrays of that length are made before the first render)."""
    return [Implied("--frames", "frames of the flight", frames, "frames", config.synth.max_frames,
                    "synth.max_frames", f"--frames {frames}")]


def synth_sizes(config: Config, extent_xy: tuple[float, float, float, float] | None = None) -> list[Implied]:
    """The rendered image (against ``sources.max_image_px``: slz would not read a larger frame) and the
    ground-truth raster of a scene of ``extent_xy`` (xmin, xmax, ymin, ymax in metres)."""
    cam, gt = config.camera, config.synth.ground_truth
    items = [Implied("camera.width", "pixels of each rendered frame", cam.width * cam.height, "px",
                     config.sources.max_image_px, "sources.max_image_px",
                     f"camera.width {cam.width} x camera.height {cam.height}")]
    if extent_xy is not None:
        xmin, xmax, ymin, ymax = extent_xy
        cells = math.ceil((xmax - xmin) / gt.raster_m) * math.ceil((ymax - ymin) / gt.raster_m)
        items.append(Implied("synth.ground_truth.raster_m", "cells of the ground-truth safety raster", cells, "cells",
                             gt.max_cells, "synth.ground_truth.max_cells",
                             f"a {xmax - xmin:.4g} x {ymax - ymin:.4g} m scene at {gt.raster_m:g} m a cell"))
    return items


# ----------------------------------------------------------------------------- files slz reads whole
# Each is checked on its size (fstat, before a byte is read: a sparse file of 3 GB costs nothing to
# refuse), on being a regular file (a FIFO would block the read for ever), and JSON on its nesting.
# These bound slz's own small files and the text lists of recordings, not parameters of the method.
MAX_JSON_BYTES = 64 << 20  # bytes; the largest, a batch summary.json, is ~0.6 KB a recording: 100,000 recordings
MAX_JSON_DEPTH = 64        # levels; slz's own JSON nests under 10 deep (run.json: summary, config)
MAX_TEXT_LIST_BYTES = 256 << 20  # bytes; a TUM rgb.txt / depth.txt / groundtruth.txt line is ~50 B: 5 million frames
# bytes; a chunk holds whole messages, the largest a frame at sources.max_image_px (16.7 MP x 4 B = 64 MiB);
# recorders chunk at 1-4 MiB
MAX_MCAP_CHUNK_BYTES = 1 << 30
MAX_VOCABULARY_BYTES = 1 << 30  # bytes; ORB-SLAM3's ORBvoc.txt (k 10, L 6), the largest in use, is 145 MB
MAX_BAG_METADATA_BYTES = 64 << 20  # bytes; a rosbag2 metadata.yaml is ~1 KB plus ~0.2 KB a file and a topic


def read_regular(path: Path | str, limit: int, what: str) -> bytes:
    """The bytes of the regular file ``path``, refused unread (DatasetError naming it) when it is not a
    regular file or is larger than ``limit``."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO opens without a writer
    except FileNotFoundError:
        raise DatasetError(path, "not found") from None
    except OSError as err:
        raise DatasetError(path, f"cannot read ({err.strerror or err})") from err
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DatasetError(path, f"not a regular file ({file_kind(st.st_mode)}); a {what} is a file")
        too_big = f"larger than {limit / 2**20:.0f} MiB; a {what} is far smaller (is this the right file?)"
        if st.st_size > limit:
            raise DatasetError(path, f"is {st.st_size / 2**20:.0f} MiB, {too_big}")
        try:  # read(n) allocates n bytes first: ask for what fstat says, then more only if there is more
            parts = [fh.read(st.st_size + 1)]
            got = len(parts[0])
            while got > st.st_size and got <= limit and parts[-1]:
                parts.append(fh.read(min(1 << 20, limit + 1 - got)))
                got += len(parts[-1])
        except OSError as err:
            raise DatasetError(path, f"cannot read ({err.strerror or err})") from err
        data = parts[0] if len(parts) == 1 else b"".join(parts)
    if len(data) > limit:  # grew while read, or a file whose size fstat does not tell (/proc)
        raise DatasetError(path, f"is {too_big}")
    return data


def file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a file"


def load_json(path: Path | str, what: str, limit: int = MAX_JSON_BYTES) -> Any:
    """A JSON document from ``path`` within the size and nesting bounds; DatasetError naming the file otherwise."""
    raw = read_regular(path, limit, what)
    try:
        doc = json.loads(raw)
    except RecursionError:
        raise DatasetError(path, f"not a {what}: nested more than {MAX_JSON_DEPTH} levels deep") from None
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
        raise DatasetError(path, f"not readable JSON ({err})") from err
    if json_depth(doc) > MAX_JSON_DEPTH:
        raise DatasetError(path, f"not a {what}: nested more than {MAX_JSON_DEPTH} levels deep")
    return doc


def json_depth(doc: object) -> int:
    """Nesting depth of a parsed JSON value, without recursion (1 for a scalar)."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        deepest = max(deepest, depth)
        if deepest > MAX_JSON_DEPTH:
            return deepest
        if isinstance(value, dict):
            stack.extend((v, depth + 1) for v in value.values())
        elif isinstance(value, list):
            stack.extend((v, depth + 1) for v in value)
    return deepest
