"""Render the flights of benchmarks/fusion_matrix.py once and keep them (depth, exact depth, true poses, truth).

    python benchmarks/fusion_render.py --out DIR [--scenes a,b] [--altitudes 7.5] [--sensors d435]
                                       [--motions hover,4] [--seeds 0,1,2] [--frames 30] [--rate 15]

The same code path as `slz synth` (``synth.record.build_world``, ``make_flight``, ``render_frames``), kept
in memory and written as one compressed ``.npz`` per flight instead of a recording: the matrix replays a
flight through the per-frame path and the fusion many times, and a stereo frame takes ~4 s to render.
Motion ``hover`` is the synth hover (drift and wobble); a number is a transect of that many metres due
east over the flight (``synth.flight.speed_m_s`` = metres / duration), centred on the scene's scenario
x, y. Already rendered flights are skipped.
"""

from __future__ import annotations

import time
from pathlib import Path

import harness
import numpy as np

SENSORS: dict[str, list[str]] = {
    "d435": ["synth.sensor.model=stereo", "synth.sensor.preset=d435"],
    "d455": ["synth.sensor.model=stereo", "synth.sensor.preset=d455"],
    "gauss0.003": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.003"],
}


def flight_name(scene: str, altitude: float, sensor: str, motion: str, seed: int, frames: int, rate: float) -> str:
    return f"{scene}_{altitude:g}m_{sensor}_{motion}_s{seed}_{frames}f{rate:g}hz"


def render(out: Path, scene: str, altitude: float, sensor: str, motion: str, seed: int, frames: int,
           rate: float) -> Path:
    from slzcli.config import load_config
    from slzcli.synth.flight import PathKind, make_flight
    from slzcli.synth.record import build_world, render_frames, scenario_start, seeds
    from slzcli.synth.scenes import load_scene

    path = out / (flight_name(scene, altitude, sensor, motion, seed, frames, rate) + ".npz")
    if path.exists():
        return path
    duration = frames / rate
    sets = list(SENSORS[sensor])
    kind: PathKind = "hover"
    if motion != "hover":
        sets.append(f"synth.flight.speed_m_s={float(motion) / duration}")
        kind = "transect"
    cfg = load_config(None, sets)
    sc = load_scene(scene)
    world = build_world(sc, cfg)
    x, y, _ = scenario_start(cfg.synth.scenarios, sc.scenario)
    if kind == "transect":
        x -= 0.5 * float(motion)
    flight_seed, rng = seeds(seed)
    flight = make_flight((x, y, altitude), frames, rate, kind, cfg.synth.flight, flight_seed, cfg.synth.start_stamp_ns)
    depth, true, safe = [], [], []
    for sf in render_frames(world, flight, cfg.synth.sensor, rng):
        depth.append(sf.frame.depth_m)
        true.append(sf.depth_true_m)
        safe.append(sf.safe)
    intr = world.intrinsics
    r = world.raster
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, depth=np.stack(depth), depth_true=np.stack(true), safe=np.stack(safe),
                        T=flight.T_world_camera, stamps=flight.stamps_ns,
                        K=np.array([intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height]),
                        raster_safe=r.safe, raster_usable=r.usable, raster_height=r.height_m,
                        raster_origin=np.asarray(r.origin_xy), raster_res=np.float64(r.resolution_m))
    tmp.rename(path)
    return path


def main() -> None:
    ap = harness.parser(__doc__, "fusion_render", out=False)   # renders, not a results file
    ap.add_argument("--out", type=Path, required=True, help="folder of the rendered flights (.npz each)")
    ap.add_argument("--scenes", default="clear_field,parking_lot,office")
    ap.add_argument("--altitudes", default="7.5")
    ap.add_argument("--sensors", default="d435")
    ap.add_argument("--motions", default="4,hover")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--rate", type=float, default=15.0)
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    for seed in [int(s) for s in a.seeds.split(",")]:
        for sensor in a.sensors.split(","):
            for alt in [float(x) for x in a.altitudes.split(",")]:
                for motion in a.motions.split(","):
                    for scene in a.scenes.split(","):
                        t0 = time.perf_counter()
                        p = render(a.out, scene, alt, sensor, motion, seed, a.frames, a.rate)
                        print(f"{p.name} {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
