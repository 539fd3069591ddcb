"""The fusion's CPU time per frame, and its results against the code of another commit (same up to rounding).

    python benchmarks/fusion_speed.py [--cache DIR] [--flights GLOB] [--reference REV] [--repeats 3]
                                      [--every 3] [--resize 848x480] [--out PATH]

Each cached flight (benchmarks/fusion_render.py: depth, true poses) is replayed through ``FusedTerrain`` as
``slz detect`` feeds it: every frame fused (``add``), and on every ``--every``-th frame the verdict of the
cells in view (``maps_in_view``) with its score and mask rendered into the frame's pixels, as the ``fused``
method does on a detection frame. Timed with ``time.process_time`` (the CPU the process spent, one core's worth:
the replay is single-threaded; the wall clock of a loaded machine is not a cost), per frame, repeated
``--repeats`` times; the medians and means over all frames and repeats are reported.

``--reference REV``: the same replay with the code as it was at REV (``harness.reference_checkout``), in a
fresh interpreter, in the same run (so both see the same machine load), and the two compared: the fused
heights, variances, looks and frames of every cell, the maps' verdicts on every detection frame and the
rendered masks must be equal up to float rounding (heights and variances within 1e-9 relative, verdicts
and masks identical); the arrays that are not the same bits are listed beside (``not_bit_identical``). The
reference's replay is this script run from that checkout (the harness puts the package beside it first).
``--resize WxH``: the frames resized (nearest) to another size first (the cache's 640 x 480 to the D435's
848 x 480; the intrinsics scaled with them). The machine's load (``os.getloadavg``)
is written beside the numbers: two cores shared with other jobs. Writes benchmarks/results/fusion_speed.json.
"""

from __future__ import annotations

import glob
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import harness
import numpy as np

HERE = Path(__file__).resolve().parent


def _load(path: Path, resize: str | None) -> tuple[Any, np.ndarray, np.ndarray]:
    import cv2

    from slzcli.types import Intrinsics

    d = np.load(path)
    k = d["K"]
    intr = Intrinsics(float(k[0]), float(k[1]), float(k[2]), float(k[3]), int(k[4]), int(k[5]))
    depth = d["depth"]
    if resize:
        w, h = (int(v) for v in resize.split("x"))
        depth = np.stack([cv2.resize(x, (w, h), interpolation=cv2.INTER_NEAREST) for x in depth])
        intr = intr.scaled(w, h)
    return intr, depth, d["T"]


def replay(path: Path, every: int, repeats: int, resize: str | None, dump: Path | None) -> dict[str, Any]:
    """One flight through the fusion: CPU ms per frame of ``add`` and of a detection frame's verdict."""
    from slzcli.config import load_config
    from slzcli.fusion import session
    from slzcli.fusion.grid import region, seen_bounds
    from slzcli.fusion.session import FusedTerrain
    from slzcli.scoring import get_scorer
    from slzcli.terrain.noise import NoiseTracker

    intr, depth, T = _load(path, resize)
    cfg = load_config(None, [])
    scorer = get_scorer(cfg.scoring, cfg.mask, "fuzzy")
    tracker = NoiseTracker(cfg.terrain.noise, cfg.terrain.noise_estimate)
    noises = [tracker.update(x) for x in depth]
    add_ms: list[float] = []
    view_ms: list[float] = []
    out: dict[str, Any] = {}
    for rep in range(repeats):
        ft = FusedTerrain(cfg, scorer)
        for i in range(len(T)):
            t0 = time.process_time()
            ft.add(depth[i], intr, T[i], noises[i], 0, i)
            add_ms.append((time.process_time() - t0) * 1e3)
            if i % every != every - 1:
                continue
            t0 = time.process_time()
            fm = ft.maps_in_view()
            assert fm is not None
            score_px, mask = _in_frame(session, fm, depth[i], intr, T[i])
            view_ms.append((time.process_time() - t0) * 1e3)
            if rep == 0:
                out[f"verdict_{i}"] = fm.verdict
                out[f"score_{i}"] = fm.score
                out[f"mask_{i}"] = mask
                out[f"score_px_{i}"] = score_px
        if rep == 0 and ft.grid is not None:
            bounds = seen_bounds(ft.grid)
            assert bounds is not None
            reg = region(ft.grid, *bounds)
            out.update(bounds=np.array(bounds), h=reg.h, var=reg.var, looks=reg.looks, frames=reg.frames,
                       rejected=reg.rejected, column=reg.column)
    if dump is not None:
        np.savez(dump, **out)
    best = np.min(np.reshape(add_ms, (repeats, len(T))), axis=0)   # each frame's least disturbed repeat
    return {"flight": path.name, "frames": len(T), "size": f"{depth.shape[2]}x{depth.shape[1]}",
            "add_cpu_ms_median": float(np.median(add_ms)), "add_cpu_ms_mean": float(np.mean(add_ms)),
            "add_cpu_ms_best_median": float(np.median(best)), "add_cpu_ms_best_mean": float(np.mean(best)),
            "verdict_cpu_ms_median": float(np.median(view_ms)), "verdict_cpu_ms_mean": float(np.mean(view_ms))}


def _in_frame(session: Any, fm: Any, depth: np.ndarray, intr: Any, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The score and the mask at the frame's pixels as the ``fused`` method renders them (by the code of
    either commit: the pixels' cells found once, or by each of the older functions)."""
    from slzcli.fusion.verdict import SAFE

    if hasattr(session, "pixel_cells"):
        index = session.pixel_cells(fm, depth, intr, T)
        return (session.cells_in_frame(fm.score.astype(np.float32), index),
                session.cells_in_frame(fm.verdict == SAFE, index))
    return (session.render_in_frame(fm.score, fm, depth, intr, T), session.verdict_in_frame(fm, depth, intr, T))


def compare(new: Path, old: Path) -> dict[str, Any]:
    """Where two dumps differ beyond float rounding (empty: they agree)."""
    a, b = np.load(new), np.load(old)
    diff: dict[str, Any] = {}
    if set(a.files) != set(b.files):
        return {"files": sorted(set(a.files) ^ set(b.files))}
    for k in a.files:
        x, y = a[k], b[k]
        if x.shape != y.shape:
            diff[k] = f"shape {x.shape} vs {y.shape}"
        elif x.dtype.kind == "f":
            both = np.isnan(x) & np.isnan(y)
            close = np.isclose(x, y, rtol=1e-9, atol=1e-12) | both
            if not close.all():
                err = np.abs(x - y)[~close]
                diff[k] = f"{int((~close).sum())} values differ, largest by {float(np.nanmax(err)):.3g}"
        elif not np.array_equal(x, y):
            diff[k] = f"{int(np.count_nonzero(x != y))} values differ"
    return diff


def not_bitwise(new: Path, old: Path) -> list[str]:
    """The arrays of two dumps that are not the same bits (NaN equal to NaN)."""
    a, b = np.load(new), np.load(old)
    return sorted(k for k in set(a.files) & set(b.files)
                  if a[k].shape != b[k].shape or a[k].dtype != b[k].dtype
                  or not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"))


def main() -> None:
    ap = harness.parser(__doc__, "fusion_speed")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache")
    ap.add_argument("--flights", default="*")
    ap.add_argument("--reference", help="a git revision whose code to time and compare against")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--every", type=int, default=3, help="a detection every this many frames")
    ap.add_argument("--resize", help="WxH: resize the frames first (e.g. 848x480)")
    ap.add_argument("--dump", type=Path, help=argparse_hidden())
    ap.add_argument("--json-row", action="store_true", help=argparse_hidden())
    a = ap.parse_args()
    flights = [Path(p) for p in sorted(glob.glob(str(a.cache / (a.flights + ".npz")))) if not p.endswith(".tmp.npz")]
    if a.json_row:   # the reference run: one flight, its row on stdout, and whose code ran it
        import slzcli

        print(json.dumps({**replay(flights[0], a.every, a.repeats, a.resize, a.dump), "package": slzcli.__file__}))
        return
    rows = []
    with tempfile.TemporaryDirectory(prefix="slz-fusion-speed-") as tmp:
        for p in flights:
            load = os.getloadavg()[0]
            new = replay(p, a.every, a.repeats, a.resize, Path(tmp) / "new.npz")
            row: dict[str, Any] = {**new, "load_1min": round(load, 2)}
            if a.reference:
                row["reference"] = _reference(a, p, Path(tmp) / "old.npz")
                row["differences"] = compare(Path(tmp) / "new.npz", Path(tmp) / "old.npz")
                row["not_bit_identical"] = not_bitwise(Path(tmp) / "new.npz", Path(tmp) / "old.npz")
            rows.append(row)
            print(_line(p.name, new, row.get("reference"), row.get("differences"), load)
                  + (f" | not bit-identical: {row['not_bit_identical'] or 'none'}" if a.reference else ""), flush=True)
    harness.write_results(a.out, {"reference": a.reference, "repeats": a.repeats, "every": a.every,
                                  "resize": a.resize, "flights": rows})


def _line(name: str, new: dict[str, Any], ref: dict[str, Any] | None, diff: dict[str, Any] | None,
          load: float) -> str:
    def ms(r: dict[str, Any]) -> str:
        return (f"add {r['add_cpu_ms_median']:5.2f} ms (mean {r['add_cpu_ms_mean']:5.2f}, best "
                f"{r.get('add_cpu_ms_best_median', math.nan):5.2f}) verdict {r['verdict_cpu_ms_median']:5.1f} ms")

    out = f"{name:44s} {new['size']} {ms(new)}"
    if ref is not None:
        out += f" | reference {ms(ref)} | differences: {diff or 'none'}"
    return out + f" | load {load:.1f}"


def _reference(a: Any, flight: Path, dump: Path) -> dict[str, Any]:
    """The replay of one flight by the code at ``a.reference``, in a fresh interpreter: this script and the harness
    copied into that checkout's benchmarks/ (the harness puts the package beside the script first on the path)."""
    with harness.reference_checkout(a.reference) as code:
        for own in (Path(__file__), Path(harness.__file__)):
            shutil.copyfile(own, code / "benchmarks" / own.name)
        cmd = [sys.executable, str(code / "benchmarks" / Path(__file__).name), "--cache", str(flight.parent),
               "--flights", flight.name.removesuffix(".npz"), "--repeats", str(a.repeats), "--every", str(a.every),
               "--dump", str(dump), "--json-row"] + (["--resize", a.resize] if a.resize else [])
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"the reference replay failed:\n{res.stderr}")
    row: dict[str, Any] = json.loads(res.stdout.strip().splitlines()[-1])
    if not Path(row.pop("package")).resolve().is_relative_to(code.resolve()):
        raise SystemExit(f"the reference replay ran other code than {a.reference}'s")
    return row


def argparse_hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
