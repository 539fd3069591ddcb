"""fuzzy vs bayes vs px4slp (the PX4-Avoidance grid planner) on the cells of the sensor x altitude matrix.

    python benchmarks/compare_px4slp.py [--cells clear_field:5:d435,...] [--frames 6] [--seed 0] [--workers 2]

Per cell (scene:altitude:sensor, as benchmarks/sensor_matrix.py builds them): `slz synth SCENE --start X,Y,Z`
(the scene's scenario x, y; straight down at Z m) with the sensor, then `slz compare --methods
fuzzy,bayes,px4slp` on it (SLAM as `slz detect` runs it, detection on every 3rd frame): the three methods
see the same frames, poses, depth and map points. Reported per method: mask precision and recall
against ground truth (summed over the detection frames), the committed site (truly safe? its clearance
to the nearest hazard), and the median time per detection frame (SLAM + maps + score + mask + select;
px4slp reads no terrain map: its maps time is 0). Prints a table, writes
benchmarks/results/compare_px4slp.csv and .json (after every cell).
"""

from __future__ import annotations

import csv
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import harness
from sensor_matrix import DETECT, SCENES, SENSORS

METHODS = ("fuzzy", "bayes", "px4slp")
DEFAULT_CELLS = ",".join([f"{s}:5:d435" for s in SCENES] +
                         [f"{s}:{z}:d435" for s in ("clear_field", "parking_lot") for z in (3, 7.5, 10)])
COLUMNS = ("scene", "altitude_m", "sensor", "seed", "method", "detections", "status", "site_safe", "clearance_m",
           "precision", "recall", "pr_auc", "frame_median_ms", "score_median_ms", "mask_median_ms",
           "select_median_ms", "maps_median_ms", "slam_median_ms", "reason")


def run_cell(scene: str, altitude: float, sensor: str, frames: int, seed: int, tmp: str) -> list[dict[str, Any]]:
    from slzcli.compare import compare_recording
    from slzcli.config import load_config
    from slzcli.outputs.records_json import to_json_object
    from slzcli.synth.record import SynthOptions, scenario_start, synthesize
    from slzcli.synth.scenes import load_scene

    cfg = load_config(None, SENSORS[sensor] + DETECT)
    x, y, _ = scenario_start(cfg.synth.scenarios, load_scene(scene).scenario)
    path = Path(tmp) / f"{scene}_{altitude:g}_{sensor}_{seed}.mcap"
    synthesize(path, SynthOptions(scene, frames, cfg.synth.rate_hz, "hover", seed, (x, y, altitude)), cfg)
    t0 = time.perf_counter()
    res: dict[str, Any] = to_json_object(compare_recording(path, cfg, METHODS).record)  # as compare.json has it
    wall = time.perf_counter() - t0
    path.unlink(missing_ok=True)
    rows = []
    for m in METHODS:
        r = res["methods"][m]
        gt = r.get("ground_truth") or {}
        mask, site, t = gt.get("mask") or {}, gt.get("site"), r["timings_ms"]
        rows.append({"scene": scene, "altitude_m": altitude, "sensor": sensor, "seed": seed, "method": m,
                     "detections": r["detections"], "status": r["status"],
                     "site_safe": None if site is None else site.get("safe"),
                     "clearance_m": None if site is None else site.get("clearance_m"),
                     "precision": mask.get("precision"), "recall": mask.get("recall"), "pr_auc": gt.get("pr_auc"),
                     "frame_median_ms": t["frame"]["median_ms"], "score_median_ms": t["score"]["median_ms"],
                     "mask_median_ms": t["mask"]["median_ms"], "select_median_ms": t["select"]["median_ms"],
                     "maps_median_ms": t["maps"]["median_ms"], "slam_median_ms": t["slam"]["median_ms"],
                     "reason": r.get("reason"), "compare_wall_s": round(wall, 1)})
    return rows


def main() -> None:
    ap = harness.parser(__doc__, "compare_px4slp")
    ap.add_argument("--cells", default=DEFAULT_CELLS, help="scene:altitude:sensor,...")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    cells = [(s, float(z), sensor) for s, z, sensor in (c.split(":") for c in args.cells.split(","))]
    rows: list[dict[str, Any]] = []
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:
        harness.write_results(args.out.with_suffix(".json"), {
            "frames": args.frames, "seed": args.seed, "detect": DETECT, "sensors": SENSORS, "methods": METHODS,
            "rows": rows}, indent=1, say=False)
        with args.out.with_suffix(".csv").open("w", newline="") as fh:
            w = csv.DictWriter(fh, COLUMNS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)

    def f(v: Any, p: int = 3) -> str:
        return "-" if v is None else f"{v:.{p}f}" if isinstance(v, float) else str(v)

    print(f"{'scene':<12} {'z m':>4} {'sensor':<6} {'method':<7} {'prec':>6} {'recall':>6} {'site':<12} {'safe':>5} "
          f"{'clear m':>7} {'frame ms':>9} {'score ms':>9}")
    fresh: dict[str, Any] = {"max_tasks_per_child": 1} if sys.version_info >= (3, 11) else {}
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(args.workers, **fresh) as pool:
        futures = [pool.submit(run_cell, s, z, sensor, args.frames, args.seed, tmp) for s, z, sensor in cells]
        for cell, fut in zip(cells, futures, strict=True):
            try:
                new = fut.result()
            except Exception as err:  # one cell's failure is a row, not the end of the run
                print(f"{cell}: failed: {type(err).__name__}: {err}", flush=True)
                rows.append({"scene": cell[0], "altitude_m": cell[1], "sensor": cell[2], "reason": f"error: {err}"})
                save()
                continue
            rows.extend(new)
            save()
            for r in new:
                print(f"{r['scene']:<12} {r['altitude_m']:>4g} {r['sensor']:<6} {r['method']:<7} "
                      f"{f(r['precision']):>6} {f(r['recall']):>6} {r['status']:<12} {f(r['site_safe']):>5} "
                      f"{f(r['clearance_m'], 2):>7} {f(r['frame_median_ms'], 1):>9} {f(r['score_median_ms'], 1):>9}",
                      flush=True)
    print(f"wrote {args.out.with_suffix('.csv')} and .json")


if __name__ == "__main__":
    main()
