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
import math
from dataclasses import dataclass

from slzcli.config import Config
from slzcli.errors import ConfigError


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
    from slzcli.config import load_config

    return load_config()


# ----------------------------------------------------------------------------- slz synth
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
