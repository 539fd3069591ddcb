"""The fusion's CPU time per frame, stage by stage, against the code of another commit (alternated, same machine).

    python benchmarks/fusion_stages.py [--cache DIR] [--flights GLOB] [--reference REV] [--rounds 2]
                                       [--repeats 3] [--resize 848x480] [--out PATH]

Each cached flight (benchmarks/fusion_render.py) is replayed ``--repeats`` times as ``fusion_speed.py`` does, with
the stages of ``FusedTerrain.add`` timed one by one through the functions it calls (the frame's median depth, its
limit ratios, ``measure.frame_cells``, ``grid.fuse``; then ``add`` itself on a second terrain) and on every third
frame the stages of a detection frame's verdict (``grid.region`` alone, ``maps_in_view``, ``site``, ``advice``, the
score and mask rendered into the frame's pixels). ``time.process_time`` medians, ms. ``--reference REV``: the same
script run from a checkout of REV (``harness.reference_checkout``), alternated with this code ``--rounds`` times,
so both see the same load (only their ratio travels on a shared machine). Writes
benchmarks/results/fusion_stages.json.
"""

from __future__ import annotations

import glob
import json
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
from fusion_speed import _in_frame, _load

STAGES = ("median", "limits", "frame_cells", "fuse", "add", "region", "maps", "site", "advice", "render")


def stages(path: Path, repeats: int, resize: str | None) -> dict[str, float]:
    """Median CPU ms of each stage over the flight's frames and the repeats."""
    from slzcli.config import load_config
    from slzcli.fusion import grid, kernels, measure, session
    from slzcli.fusion.session import FusedTerrain
    from slzcli.geometry import fit_intrinsics
    from slzcli.scoring import get_scorer
    from slzcli.terrain.noise import NoiseTracker

    intr, depth, T = _load(path, resize)
    cfg = load_config(None, [])
    scorer = get_scorer(cfg.scoring, cfg.mask, "fuzzy")
    tracker = NoiseTracker(cfg.terrain.noise, cfg.terrain.noise_estimate)
    noises = [tracker.update(x) for x in depth]
    params = measure.FusionParams.from_config(cfg)
    fi = fit_intrinsics(intr, depth[0].shape)
    focal = 0.5 * (fi.fx + fi.fy)
    kernels.warm_up()
    pt = time.process_time
    ms: dict[str, list[float]] = {k: [] for k in STAGES}
    for _ in range(repeats):
        g = grid.FusedGrid.empty(params)
        ft = FusedTerrain(cfg, scorer)
        for i in range(len(T)):
            t = [pt()]
            z = measure.frame_median_m(depth[i])
            t.append(pt())
            if z is None:
                continue
            step, tan = measure.frame_limit_ratios(noises[i], z, focal, cfg, params)
            t.append(pt())
            cells = measure.frame_cells(depth[i], intr, T[i], noises[i], params, step, tan, z)
            t.append(pt())
            if cells is not None:
                grid.fuse(g, cells, i)
            t.append(pt())
            ft.add(depth[i], intr, T[i], noises[i], 0, i)
            t.append(pt())
            for k, name in enumerate(STAGES[:5]):
                ms[name].append(t[k + 1] - t[k])
            if i % 3 != 2:
                continue
            t = [pt()]
            fm = ft.maps_in_view()
            t.append(pt())
            if fm is None:
                continue
            ft.site(fm)
            t.append(pt())
            ft.advice(fm, False)
            t.append(pt())
            _in_frame(session, fm, depth[i], intr, T[i])
            t.append(pt())
            reg = fm.region
            r0 = pt()
            grid.region(ft.grid, reg.x0, reg.y0, reg.shape[1], reg.shape[0])   # type: ignore[arg-type]
            ms["region"].append(pt() - r0)
            for k, name in enumerate(STAGES[6:]):
                ms[name].append(t[k + 1] - t[k])
    return {k: round(1e3 * float(np.median(v)), 3) for k, v in ms.items() if v}


def main() -> None:
    ap = harness.parser(__doc__, "fusion_stages")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache")
    ap.add_argument("--flights", default="*_1[02]m_d435_4_s0_30f15hz")
    ap.add_argument("--reference", help="a git revision whose code to time beside this one")
    ap.add_argument("--rounds", type=int, default=2, help="this code and the reference alternated this many times")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resize", default="848x480", help="WxH: resize the frames first ('' for none)")
    ap.add_argument("--json-row", action="store_true", help=_hidden())
    a = ap.parse_args()
    flights = [Path(p) for p in sorted(glob.glob(str(a.cache / (a.flights + ".npz")))) if not p.endswith(".tmp.npz")]
    if a.json_row:       # the reference run: its rows on stdout
        print(json.dumps({p.name: stages(p, a.repeats, a.resize or None) for p in flights}))
        return
    rounds: list[dict[str, Any]] = []
    for r in range(a.rounds):
        row: dict[str, Any] = {"load_1min": round(os.getloadavg()[0], 2),
                               "this": {p.name: stages(p, a.repeats, a.resize or None) for p in flights}}
        if a.reference:
            row["reference"] = _reference(a)
        rounds.append(row)
        for name in row["this"]:
            new, old = row["this"][name], (row.get("reference") or {}).get(name, {})
            print(f"round {r + 1} {name}: " + ", ".join(
                f"{k} {new[k]:.2f}" + (f" / {old[k]:.2f}" if k in old else "") for k in STAGES if k in new),
                flush=True)
    harness.write_results(a.out, {"reference": a.reference, "repeats": a.repeats, "resize": a.resize,
                                  "flights": a.flights, "rounds": rounds})


def _reference(a: Any) -> dict[str, Any]:
    with harness.reference_checkout(a.reference) as code:
        for own in (Path(__file__), Path(harness.__file__), Path(__file__).with_name("fusion_speed.py")):
            shutil.copyfile(own, code / "benchmarks" / own.name)
        cmd = [sys.executable, str(code / "benchmarks" / Path(__file__).name), "--cache", str(a.cache),
               "--flights", a.flights, "--repeats", str(a.repeats), "--resize", a.resize, "--json-row"]
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"the reference run failed:\n{res.stderr}")
    out: dict[str, Any] = json.loads(res.stdout.strip().splitlines()[-1])
    return out


def _hidden() -> str:
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
