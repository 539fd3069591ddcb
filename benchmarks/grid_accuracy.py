"""What the working grid costs in accuracy: mask precision and recall against ground truth, the code of a
git revision against the current code, on the same rendered frames (issue 18).

    python benchmarks/grid_accuracy.py [--before aed6bd3] [--scenes a,b] [--altitudes 3,5,7.5,10]
                                       [--sensors d435,gauss0.003] [--seeds 0,1] [--frames 2]

The current code computes the maps on blocks of at least ``terrain.limits.finest_block_m`` on the ground,
scores them there (``TerrainMaps.grid``) and runs the plan-view filter on ``mask.plan_samples_per_cell``
samples per footprint cell; the revision (default: the last commit before that) computed the maps' last
steps, the score and the mask on every pixel. Per cell (scene x altitude x sensor x seed of
benchmarks/sensor_matrix.py, a `slz synth` hover straight down at the scene's own scenario x, y) both run
on every frame with the true pose (so SLAM is not part of it): the fuzzy method's mask, the maps'
block size, and the pixel counts against ``synth``'s ground-truth safe mask (summed over the frames).
Prints per cell and the pooled precision / recall, writes benchmarks/results/grid_accuracy.json.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import harness
import numpy as np
import stages  # the before/after loader of the detection core
from sensor_matrix import SCENES, SENSORS

from slzcli.config import load_config
from slzcli.evaluate.safety import mask_counts, total
from slzcli.sources import open_recording
from slzcli.synth.groundtruth import load_ground_truth
from slzcli.synth.record import scenario_start
from slzcli.synth.scenes import load_scene

CACHE = Path(tempfile.gettempdir()) / "slz_grid_accuracy"


def render(scene: str, altitude: float, sensor: str, seed: int, frames: int) -> Path:
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"{scene}_{altitude:g}_{sensor}_{seed}_{frames}.mcap"
    if not path.exists():
        cfg = load_config(None, SENSORS[sensor])
        x, y, _ = scenario_start(cfg.synth.scenarios, load_scene(scene).scenario)
        sets = [a for s in SENSORS[sensor] for a in ("--set", s)]
        subprocess.run([sys.executable, "-m", "slzcli.cli", "synth", scene, "-o", str(path), "--frames", str(frames),
                        "--start", f"{x},{y},{altitude}", "--path", "hover", "--seed", str(seed), *sets],
                       check=True, capture_output=True)
    return path


def run_cell(cores: list[stages.Core], path: Path, sensor: str) -> dict[str, Any]:
    config = load_config(None, SENSORS[sensor])
    truth = load_ground_truth(path)
    poses = np.load(str(path) + ".gt.npz")["T_world_camera"]
    tol = round(config.synth.ground_truth.stamp_tolerance_ms * 1e6)
    counts: dict[str, list[Any]] = {c.name: [] for c in cores}
    blocks: dict[str, list[int]] = {c.name: [] for c in cores}
    with open_recording(path, config) as rec:
        frames = [dataclasses.replace(f, T_world_camera=poses[i]) for i, f in enumerate(rec.frames())]
    for core in cores:
        scorer = core.scorer(config)
        tracker = core.noise.NoiseTracker(config.terrain.noise, config.terrain.noise_estimate)
        for frame in frames:
            _cpu, _wall, (maps, sm) = stages.run_frame(core, frame, config, scorer, tracker)
            counts[core.name].append(mask_counts(sm.mask, truth.safe_mask(frame.stamp_ns, tolerance_ns=tol)))
            blocks[core.name].append(maps.work.block_px if maps.work is not None else 0)
    return {name: {**total(c).as_dict(), "counts": [dataclasses.asdict(x) for x in c], "block_px": blocks[name]}
            for name, c in counts.items()}


def pooled(rows: list[dict[str, Any]], name: str) -> dict[str, Any]:
    from slzcli.evaluate.safety import MaskCounts

    return total([MaskCounts(**c) for r in rows for c in r[name]["counts"]]).as_dict()


def main() -> None:
    ap = harness.parser(__doc__, "grid_accuracy")
    ap.add_argument("--before", default="aed6bd3")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--altitudes", default="3,5,7.5,10")
    ap.add_argument("--sensors", default="d435,gauss0.003")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--frames", type=int, default=2)
    args = ap.parse_args()
    cores = [stages.revision_core(args.before), stages.current_core()]
    rows: list[dict[str, Any]] = []
    f = lambda v: "  -  " if v is None else f"{v:.3f}"  # noqa: E731
    print(f"{'scene':<12} {'z m':>4} {'sensor':<10} {'seed':>4} {'block':>9} {'prec before':>11} {'after':>6} "
          f"{'recall before':>13} {'after':>6}")
    for sensor in args.sensors.split(","):
        for scene in args.scenes.split(","):
            for z in (float(a) for a in args.altitudes.split(",")):
                for seed in (int(s) for s in args.seeds.split(",")):
                    res = run_cell(cores, render(scene, z, sensor, seed, args.frames), sensor)
                    b, a = res["before"], res["after"]
                    rows.append({"scene": scene, "altitude_m": z, "sensor": sensor, "seed": seed, **res})
                    print(f"{scene:<12} {z:>4g} {sensor:<10} {seed:>4} {b['block_px'][0]:>4}->{a['block_px'][0]:<4} "
                          f"{f(b['precision']):>11} {f(a['precision']):>6} {f(b['recall']):>13} {f(a['recall']):>6}",
                          flush=True)
                    summary = {n: pooled(rows, n) for n in ("before", "after")}
                    harness.write_results(args.out, {"before": args.before, "frames": args.frames,
                                                     "sensors": SENSORS, "pooled": summary, "rows": rows},
                                          indent=1, say=False)
    for n in ("before", "after"):
        s = pooled(rows, n)
        print(f"pooled {n}: precision {f(s['precision'])} recall {f(s['recall'])}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
