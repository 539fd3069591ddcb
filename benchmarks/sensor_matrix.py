"""Detection quality across sensors and altitudes: every synth scene x altitude x depth sensor model.

    python benchmarks/sensor_matrix.py [--scenes a,b] [--altitudes 3,5,7.5,10] [--sensors ideal,...]
                                       [--frames 6] [--seeds 0] [--workers 2]

Per cell: `slz synth SCENE --start X,Y,Z` (the scene's own scenario x, y; straight down at Z m) with the
sensor, then `slz compare --methods fuzzy` on it (SLAM as `slz detect` runs it, detection on every 3rd
frame). Reported: mask precision, recall and PR AUC against ground truth (summed over the detection
frames), the committed site (truly safe? "no safe site" right?), the depth noise slz estimated against
the noise the sensor really put in (robust std of depth - exact depth over z^2, from an in-memory render
of the cell's first frame), how many detection frames could not vouch, and on `slopes` the RMS slope
error of the maps (degrees, pixels on landable ground, true pose) against the rendered normals.
Prints a table and writes benchmarks/results/sensor_matrix.json.

Targets (issue 16): precision >= 0.95 in every cell where anything is called safe; recall >= 0.3 up
to 7.5 m for gaussian and d455 and wherever the physics allows for d435; every committed site truly
safe; no_site gives no site everywhere.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import harness
import numpy as np

SCENES = ("clear_field", "parking_lot", "playground", "office", "slopes", "no_site")
# name -> config overrides of the synth sensor
SENSORS: dict[str, list[str]] = {
    "ideal": ["synth.sensor.model=ideal"],
    "gauss0.0015": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.0015"],
    "gauss0.003": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.003"],
    "d435": ["synth.sensor.model=stereo", "synth.sensor.preset=d435"],
    "d455": ["synth.sensor.model=stereo", "synth.sensor.preset=d455"],
}
DETECT = ["landing.detect_on=every_nth", "landing.every_nth_frame=3"]


def true_noise_and_slope(scene: str, start: tuple[float, float, float], sensor: list[str], seed: int) -> dict[str, Any]:
    """The cell's first frame rendered in memory: the noise the sensor added, and (slopes) the slope error."""
    from slzcli.config import load_config
    from slzcli.synth.flight import make_flight
    from slzcli.synth.record import build_world, render_frames, seeds
    from slzcli.synth.scenes import load_scene
    from slzcli.terrain.maps import MapParams, frame_maps

    cfg = load_config(None, sensor)
    world = build_world(load_scene(scene), cfg)
    flight_seed, rng = seeds(seed)
    flight = make_flight(start, 1, cfg.synth.rate_hz, "hover", cfg.synth.flight, flight_seed, cfg.synth.start_stamp_ns)
    sf = next(render_frames(world, flight, cfg.synth.sensor, rng))
    d, t = sf.frame.depth_m.astype(np.float64), sf.depth_true_m.astype(np.float64)
    ok = np.isfinite(d) & np.isfinite(t) & (t > 0)
    err = (d[ok] - t[ok]) / (t[ok] ** 2)
    out: dict[str, Any] = {
        "true_a_per_m": float(1.482602 * np.median(np.abs(err - np.median(err)))) if err.size else None,
        "true_bias_m_at_median": float(np.median(d[ok] - t[ok])) if err.size else None,
        "hole_fraction": float(1.0 - np.isfinite(d[np.isfinite(t)]).mean()) if np.isfinite(t).any() else None,
    }
    if scene == "slopes":
        # the maps' slope against the rendered normals on the ground and ramps, away from object
        # boundaries by half the slope window (a window straddling a ramp's edge reads a slope there:
        # that is the map working, not an error of its slope estimate)
        import cv2

        maps = frame_maps(sf.frame, MapParams.of(cfg))
        n = sf.normal_world.astype(np.float64)
        true_slope = np.degrees(np.arccos(np.clip(np.abs(n[..., 2]), 0.0, 1.0)))
        ids = sf.object_id.astype(np.int32)
        boundary = (cv2.dilate(ids.astype(np.float32), np.ones((3, 3), np.uint8)) !=
                    cv2.erode(ids.astype(np.float32), np.ones((3, 3), np.uint8))).astype(np.uint8)
        dist = cv2.distanceTransform(1 - boundary, cv2.DIST_L2, 5)
        half = 0.5 * maps.work.slope_window_blocks * maps.work.block_px if maps.work else 0.0
        sel = (ids > 0) & (dist > half) & np.isfinite(maps.slope_deg) & np.isfinite(true_slope)
        diff = maps.slope_deg[sel] - true_slope[sel]
        out["slope_rms_err_deg"] = float(np.sqrt(np.mean(diff ** 2))) if diff.size else None
        out["slope_median_abs_err_deg"] = float(np.median(np.abs(diff))) if diff.size else None
    return out


def run_cell(scene: str, altitude: float, sensor: str, frames: int, seed: int, tmp: str) -> dict[str, Any]:
    from slzcli.compare import compare_recording
    from slzcli.config import load_config
    from slzcli.outputs.records_json import to_json_object
    from slzcli.synth.record import SynthOptions, scenario_start, synthesize
    from slzcli.synth.scenes import load_scene

    t0 = time.perf_counter()
    overrides = SENSORS[sensor]
    cfg = load_config(None, overrides + DETECT)
    x, y, _ = scenario_start(cfg.synth.scenarios, load_scene(scene).scenario)
    start = (x, y, altitude)
    path = Path(tmp) / f"{scene}_{altitude:g}_{sensor}_{seed}.mcap"
    synthesize(path, SynthOptions(scene, frames, cfg.synth.rate_hz, "hover", seed, start), cfg)
    res: dict[str, Any] = to_json_object(compare_recording(path, cfg, ("fuzzy",)).record)  # as compare.json has it
    m = res["methods"]["fuzzy"]
    gt = m.get("ground_truth") or {}
    mask, site = gt.get("mask") or {}, gt.get("site")
    noise = res.get("depth_noise") or {}
    row = {"scene": scene, "altitude_m": altitude, "sensor": sensor, "seed": seed, "frames": res["frames"],
           "detections": m["detections"], "slam": res["slam_backend"],
           "precision": mask.get("precision"), "recall": mask.get("recall"), "pr_auc": gt.get("pr_auc"),
           "status": m["status"], "reason": m.get("reason"),
           "site_safe": None if site is None else site.get("safe"),
           "clearance_m": None if site is None else site.get("clearance_m"),
           "estimated_a_per_m": noise.get("a_per_m_median"), "estimated_a_by_block": noise.get("a_per_m_by_block_px"),
           "not_vouched": m.get("detections_not_vouched"), "wall_s": round(time.perf_counter() - t0, 1)}
    row.update(true_noise_and_slope(scene, start, overrides, seed))
    path.unlink(missing_ok=True)
    return row


def verdict(r: dict[str, Any]) -> str:
    if r["scene"] == "no_site":
        return "ok" if r["status"] != "site" else "SITE ON no_site"
    if r["status"] == "site" and r["site_safe"] is False:
        return "UNSAFE SITE"
    if r["precision"] is not None and r["precision"] < 0.95:
        return "low precision"
    return "ok"


def main() -> None:
    ap = harness.parser(__doc__, "sensor_matrix")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--altitudes", default="3,5,7.5,10")
    ap.add_argument("--sensors", default=",".join(SENSORS))
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    cells = [(s, float(z), sensor, int(seed)) for s in args.scenes.split(",") for z in args.altitudes.split(",")
             for sensor in args.sensors.split(",") for seed in args.seeds.split(",")]
    f = lambda v, p=3: "   -  " if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{p}f}"  # noqa: E731
    print(f"{'scene':<12} {'z m':>4} {'sensor':<12} {'seed':>4} {'prec':>6} {'recall':>6} {'AUC':>6} {'site':<12} "
          f"{'safe':>5} {'a est':>7} {'a true':>7} {'holes':>5} {'novch':>5} {'slope err':>9}  verdict")
    rows: list[dict[str, Any]] = []
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:  # after every cell: a matrix of hours is not lost to one late failure
        harness.write_results(args.out, {"frames": args.frames, "detect": DETECT, "sensors": SENSORS, "rows": rows},
                              indent=1, say=False)

    # one cell per worker process where Python allows (3.11+): a cell's memory (stereo matching at 848x480)
    # goes back when it ends
    fresh: dict[str, Any] = {"max_tasks_per_child": 1} if sys.version_info >= (3, 11) else {}
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(args.workers, **fresh) as pool:
        futures = [pool.submit(run_cell, s, z, sensor, args.frames, seed, tmp) for s, z, sensor, seed in cells]
        for cell, fut in zip(cells, futures, strict=True):
            try:
                r = fut.result()
            except Exception as err:  # one cell's failure is a row, not the end of the matrix
                print(f"{cell}: failed: {type(err).__name__}: {err}", flush=True)
                rows.append({"scene": cell[0], "altitude_m": cell[1], "sensor": cell[2], "seed": cell[3],
                             "error": f"{type(err).__name__}: {err}"})
                save()
                continue
            rows.append(r)
            save()
            print(f"{r['scene']:<12} {r['altitude_m']:>4g} {r['sensor']:<12} {r['seed']:>4} {f(r['precision'])} "
                  f"{f(r['recall'])} {f(r['pr_auc'])} {r['status']:<12} "
                  f"{r['site_safe'] if r['site_safe'] is not None else '-'!s:>5} "
                  f"{f(r['estimated_a_per_m'], 4):>7} {f(r['true_a_per_m'], 4):>7} {f(r['hole_fraction'], 2):>5} "
                  f"{r['not_vouched'] if r['not_vouched'] is not None else '-':>5} "
                  f"{f(r.get('slope_rms_err_deg'), 1):>9}  "
                  f"{verdict(r)}", flush=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
