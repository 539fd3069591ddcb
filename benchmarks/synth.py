"""Benchmark of `slz synth`: render speed at 640x480 and the size of a 100-frame recording.

Usage: .venv/bin/python benchmarks/synth.py [--frames 100] [--scene parking_lot]
Prints a table and writes benchmarks/results/synth.json. Per-stage times come from one
pass of render -> sensor model -> ground-truth lookup per frame (no writing); the
recording rows time the whole `synthesize` (render + encode + write + sidecar + preview).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import harness

from slzcli.config import load_config
from slzcli.synth import record
from slzcli.synth.flight import make_flight
from slzcli.synth.groundtruth import pixel_safe_mask
from slzcli.synth.scenes import load_scene
from slzcli.synth.sensor import apply_color_model


def size_of(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def stage_times(scene: str, frames: int) -> dict[str, float]:
    cfg = load_config()
    t0 = time.perf_counter()
    world = record.build_world(load_scene(scene), cfg)
    build_s = time.perf_counter() - t0
    flight_seed, rng = record.seeds(0)
    flight = make_flight(record.scenario_start(cfg.synth.scenarios, 1), frames, cfg.synth.rate_hz, "hover",
                         cfg.synth.flight, flight_seed, cfg.synth.start_stamp_ns)
    t = {"render": 0.0, "sensor": 0.0, "truth": 0.0}
    for T in flight.T_world_camera:
        a = time.perf_counter()
        r = world.renderer.render(T, world.intrinsics)
        b = time.perf_counter()
        world.depth_sensor.measure(r.depth_m, T, rng)
        apply_color_model(r.rgb, cfg.synth.sensor, rng)
        c = time.perf_counter()
        pixel_safe_mask(world.raster, r.point_world, r.hit)
        d = time.perf_counter()
        t["render"] += b - a
        t["sensor"] += c - b
        t["truth"] += d - c
    per = {k: 1000 * v / frames for k, v in t.items()}
    total = sum(per.values())
    return {"world_build_s": build_s, **{f"{k}_ms": v for k, v in per.items()}, "frame_ms": total,
            "frames_per_s": 1000 / total, "raster_cells": int(world.raster.safe.size)}


def recording(scene: str, frames: int, color: str, depth: str, folder: Path) -> dict[str, float | str]:
    cfg = load_config()
    out = folder / f"{scene}_{color}_{depth}.mcap"
    opts = record.SynthOptions(scene=scene, frames=frames, rate_hz=cfg.synth.rate_hz, path="hover", seed=0,
                               start_m=record.scenario_start(cfg.synth.scenarios, 1), fmt="mcap", color_encoding=color,
                               depth_encoding=depth)
    t0 = time.perf_counter()
    record.synthesize(out, opts, cfg)
    wall = time.perf_counter() - t0
    gt = Path(str(out) + ".gt.npz")
    return {"encoding": f"{color} + {depth}", "frames": frames, "seconds": wall, "frames_per_s": frames / wall,
            "recording_mb": size_of(out) / 1e6, "ground_truth_mb": size_of(gt) / 1e6,
            "mb_per_frame": size_of(out) / 1e6 / frames}


def main() -> None:
    ap = harness.parser(__doc__, "synth")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--scene", default="parking_lot")
    args = ap.parse_args()
    stages = stage_times(args.scene, min(args.frames, 30))
    with tempfile.TemporaryDirectory() as tmp:
        recs = [recording(args.scene, args.frames, "rgb8", "16UC1", Path(tmp)),
                recording(args.scene, args.frames, "jpeg", "16UC1", Path(tmp))]
    print(f"slz synth benchmark: {args.scene}, 640x480, scenario 1 start; {os.cpu_count()} CPUs "
          f"(shared machine: wall times are upper bounds)")
    print(f"world build (meshes, raycaster, safety raster {stages['raster_cells']} cells): "
          f"{stages['world_build_s']:.2f} s")
    print(f"per frame: render {stages['render_ms']:.0f} ms, sensor {stages['sensor_ms']:.0f} ms, "
          f"truth {stages['truth_ms']:.0f} ms -> {stages['frames_per_s']:.2f} frames/s")
    print(f"{'recording (MCAP)':<18} {'frames':>6} {'s':>7} {'fps':>6} {'MB':>8} {'MB/frame':>9} {'GT MB':>7}")
    for r in recs:
        print(f"{r['encoding']:<18} {r['frames']:>6} {r['seconds']:>7.1f} {r['frames_per_s']:>6.2f} "
              f"{r['recording_mb']:>8.1f} {r['mb_per_frame']:>9.2f} {r['ground_truth_mb']:>7.1f}")
    result = {"scene": args.scene, "resolution": [640, 480], "stages": stages, "recordings": recs,
              "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    harness.write_results(args.out, result, indent=1)


if __name__ == "__main__":
    main()
