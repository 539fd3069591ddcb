"""Monocular ORB-SLAM3 (the paper's SLAM, ``--profile paper``): on which synth flights does its map initialise?

    python benchmarks/monocular_init.py [--scenes a,b] [--altitudes 5,10] [--seeds 0,1] [--paths transect,hover]
                                        [--rate 30] [--seconds 2] [--set KEY=VALUE ...]

Per scene x altitude x seed x path: the flight is rendered in this process (``slz synth``'s renderer, the
``gaussian`` depth model: monocular SLAM sees the colour image only, depth only fixes the map's scale), fed
frame by frame to slz's ORB-SLAM3 backend with the ``paper`` profile (monocular, 1000 features, 8 levels,
1.2, 30 fps) and the first frame with a metric pose is reported: frame, time since the first frame, metres
flown by then (true poses), and over the frames after it the map's scale error (estimated / true path
length) and the ATE (rigid alignment, the scale is slz's, from depth). ``never`` = no pose in the flight.
Prints a table, writes benchmarks/results/monocular_init.json. The findings are in the ablation's docstring
(benchmarks/ablation.py) and docs/METHOD.md (2.2, monocular).
"""

from __future__ import annotations

import math
import time
from typing import Any

import harness
import numpy as np

SCENES = ("clear_field", "parking_lot", "playground", "office", "slopes", "no_site")


def run(scene: str, altitude: float, seed: int, path: str, rate: float, frames: int, items: list[str]
        ) -> dict[str, Any]:
    from slzcli.config import load_config
    from slzcli.evaluate.slam import ate
    from slzcli.slam import get_backend
    from slzcli.synth.flight import make_flight
    from slzcli.synth.record import build_world, render_frames, scenario_start, seeds
    from slzcli.synth.scenes import load_scene

    cfg = load_config(None, ["synth.sensor.model=gaussian", *items], "paper")
    sc = load_scene(scene)
    x, y, _ = scenario_start(cfg.synth.scenarios, sc.scenario)
    world = build_world(sc, cfg)
    flight_seed, sensor_rng = seeds(seed)
    flight = make_flight((x, y, altitude), frames, rate, path, cfg.synth.flight, flight_seed,  # type: ignore[arg-type]
                         cfg.synth.start_stamp_ns)
    backend = get_backend(cfg.slam)
    est: list[np.ndarray | None] = []
    t0 = time.perf_counter()
    try:
        for f in render_frames(world, flight, cfg.synth.sensor, sensor_rng, scene):
            est.append(backend.track(f.frame).T_world_camera)
    finally:
        backend.close()
    wall = time.perf_counter() - t0
    truth = list(flight.T_world_camera)
    first = next((i for i, p in enumerate(est) if p is not None), None)
    row: dict[str, Any] = {"scene": scene, "altitude_m": altitude, "seed": seed, "path": path, "rate_hz": rate,
                           "frames": frames, "init_frame": first, "wall_s": round(wall, 1)}
    if first is not None:
        pos = flight.T_world_camera[:, :3, 3]
        row["init_s"] = first / rate
        row["flown_at_init_m"] = float(np.linalg.norm(np.diff(pos[: first + 1], axis=0), axis=1).sum())
        row["tracked_frames"] = sum(p is not None for p in est)
        ok = [i for i, p in enumerate(est) if p is not None]
        e = np.stack([est[i][:3, 3] for i in ok])  # type: ignore[index]
        g = pos[ok]
        true_len = float(np.linalg.norm(np.diff(g, axis=0), axis=1).sum())
        row["scale_ratio"] = (float(np.linalg.norm(np.diff(e, axis=0), axis=1).sum()) / true_len
                              if true_len > 0 else None)
        row["ate_m"] = ate(est, truth).rmse_m if len(ok) >= 3 else None
    return row


def _f(v: Any, p: int = 2) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{p}f}"


def main() -> None:
    ap = harness.parser(__doc__, "monocular_init")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--altitudes", default="5,10")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--paths", default="transect")
    ap.add_argument("--rate", type=float, default=30.0, help="Hz (the paper's camera: 30 fps)")
    ap.add_argument("--seconds", type=float, default=2.0, help="length of each flight")
    ap.add_argument("--set", nargs="*", default=[], help="config overrides, e.g. synth.flight.speed_m_s=1")
    args = ap.parse_args()
    frames = max(2, round(args.seconds * args.rate))
    rows: list[dict[str, Any]] = []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    print(f"{'scene':<12} {'alt m':>5} {'seed':>4} {'path':<9} {'init':>5} {'at s':>5} {'flown m':>7} "
          f"{'tracked':>7} {'scale':>5} {'ATE m':>6}", flush=True)
    for path in args.paths.split(","):
        for scene in args.scenes.split(","):
            for alt in (float(a) for a in args.altitudes.split(",")):
                for seed in (int(s) for s in args.seeds.split(",")):
                    r = run(scene, alt, seed, path, args.rate, frames, args.set)
                    rows.append(r)
                    init = "never" if r["init_frame"] is None else str(r["init_frame"])
                    print(f"{scene:<12} {alt:>5g} {seed:>4} {path:<9} {init:>5} {_f(r.get('init_s')):>5} "
                          f"{_f(r.get('flown_at_init_m')):>7} {r.get('tracked_frames', 0):>3}/{frames:<3} "
                          f"{_f(r.get('scale_ratio')):>5} {_f(r.get('ate_m'), 3):>6}", flush=True)
                    harness.write_results(args.out, {"rate_hz": args.rate, "frames": frames, "set": args.set,
                                                     "rows": rows}, indent=1, say=False)
    inits = [r for r in rows if r["init_frame"] is not None]
    print(f"\ninitialised {len(inits)} of {len(rows)}; wrote {args.out}")


if __name__ == "__main__":
    main()
