"""Benchmark of the synth depth sensor models: sigma_z, bias, holes and error correlation length vs range.

Usage: .venv/bin/python benchmarks/sensor_noise.py [--seeds 2] [--timing-frames 5]
For each model (stereo d435, stereo d455; gaussian a = 0.0005, 0.0015, 0.003 for reference) and
each range z = 2..10 m, the camera hovers straight down over (a) a level asphalt plane and
(b) the ground of `parking_lot` (pixels whose ray hits the ground object, from the scenario-1
spot). Per frame: error = measured - exact depth on those pixels; a plane fitted to the error
(least squares, refitted once without 3-sigma outliers) is removed, so a constant or tilted
offset is bias, not noise; sigma_z = 1.4826 x MAD of the rest; bias = median error; holes =
the NaN fraction; correlation length = the lag (colour px, and metres on the ground) where the
error's autocorrelation falls below 1/e. Then the stereo model on `parking_lot` variants at 8 m
and the ms per frame of render + sensor at 640x480 for gaussian vs stereo. Prints tables and
writes benchmarks/results/sensor_noise.json. Intel's reference: RMS = z^2 x 0.08 px / (f B),
f = 424 px (848 px, 90 deg HFOV), B = 50 mm (D435) or 95 mm (D455).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import harness
import numpy as np

from slzcli.config import load_config
from slzcli.synth import record
from slzcli.synth.flight import R_WORLD_CAMERA_DOWN
from slzcli.synth.scenes import SCENES_DIR, load_scene
from slzcli.synth.sensor import get_depth_sensor

RANGES_M = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
MODELS = {
    "stereo d435": ["synth.sensor.model=stereo", "synth.sensor.preset=d435"],
    "stereo d455": ["synth.sensor.model=stereo", "synth.sensor.preset=d455"],
    "gaussian a=0.0005": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.0005"],
    "gaussian a=0.0015": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.0015"],
    "gaussian a=0.003": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.003"],
}
INTEL_SUBPIXEL_PX = 0.08           # Intel "Tuning depth cameras for best performance": typical subpixel
INTEL_F_PX = 424.0                 # 848 px at 90 deg HFOV
INTEL_BASELINE_M = {"stereo d435": 0.050, "stereo d455": 0.095}
PLANE = 'description: "a level asphalt plane"\nground: {size_m: [60, 60], material: asphalt}\nobjects: []\n'
PARKING_SPOT_XY = (0.0, 1.0)       # the open driving lane of parking_lot
VARIANTS = ("", "grass", "hard", "sand", "low_light", "high_light")
COARSE_TRUTH = ["synth.ground_truth.raster_m=0.5"]   # the safety raster is not used here


def down_pose(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_WORLD_CAMERA_DOWN
    T[:3, 3] = (x, y, z)
    return T


def error_stats(err: np.ndarray, mask: np.ndarray, z: float, f_px: float) -> dict[str, float]:
    """sigma (MAD after a fitted plane), bias, holes and correlation length of one frame's depth error."""
    H, W = err.shape
    valid = mask & np.isfinite(err)
    holes = 1.0 - valid.sum() / max(mask.sum(), 1)
    if valid.sum() < 100:
        return {"sigma_m": float("nan"), "bias_m": float("nan"), "holes": float(holes), "corr_px": float("nan"),
                "corr_m": float("nan")}
    v, u = np.nonzero(valid)
    e = err[valid].astype(np.float64)
    A = np.stack([u / W, v / H, np.ones_like(e)], axis=1)
    keep = np.ones(len(e), bool)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(A[keep], e[keep], rcond=None)
        res = e - A @ coef
        mad = np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res - np.median(res)) < 3 * 1.4826 * mad + 1e-12
    sigma = 1.4826 * float(np.median(np.abs(res - np.median(res))))
    field = np.zeros((H, W))
    field[valid] = np.clip(res - np.median(res), -5 * sigma, 5 * sigma)     # flying pixels do not set the scale
    corr_px = correlation_length(field, valid)
    return {"sigma_m": sigma, "bias_m": float(np.median(e)), "holes": float(holes), "corr_px": corr_px,
            "corr_m": corr_px * z / f_px}


def correlation_length(field: np.ndarray, valid: np.ndarray) -> float:
    """Lag (px) at which the masked autocorrelation (mean of the x and y profiles) drops below 1/e."""
    H, W = field.shape
    F = np.fft.rfft2(field, s=(2 * H, 2 * W))
    M = np.fft.rfft2(valid.astype(float), s=(2 * H, 2 * W))
    ac = np.fft.irfft2(F * np.conj(F), s=(2 * H, 2 * W))
    n = np.fft.irfft2(M * np.conj(M), s=(2 * H, 2 * W))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = ac / np.maximum(n, 1.0)
    r = r / r[0, 0]
    n_lag = min(H, W) // 4
    prof = 0.5 * (r[0, :n_lag] + r[:n_lag, 0])
    below = np.flatnonzero(prof < np.exp(-1.0))
    if len(below) == 0:
        return float(len(prof))
    k = int(below[0])
    # linear interpolation between the last lag above 1/e and the first below
    return float(k - 1 + (prof[k - 1] - np.exp(-1.0)) / (prof[k - 1] - prof[k])) if k > 0 else 0.0


def run_model(name: str, overrides: list[str], worlds: dict[str, record.World], seeds: int) -> list[dict[str, Any]]:
    cfg = load_config(overrides=overrides + COARSE_TRUTH)
    rows: list[dict[str, Any]] = []
    for scene, world in worlds.items():
        sensor = get_depth_sensor(cfg.synth.sensor, world.renderer, world.intrinsics)
        for z in RANGES_M:
            per = []
            for seed in range(seeds):
                x0, y0 = PARKING_SPOT_XY if scene == "parking_lot ground" else (0.0, 0.0)
                T = down_pose(x0 + 0.31 * seed, y0 - 0.17 * seed, z)
                r = world.renderer.render(T, world.intrinsics)
                meas = sensor.measure(r.depth_m, T, np.random.default_rng(seed))
                mask = r.object_id == 1 if scene == "parking_lot ground" else np.isfinite(r.depth_m)
                per.append(error_stats(meas - r.depth_m, mask, z, world.intrinsics.fx))
            row: dict[str, Any] = {"model": name, "scene": scene, "z_m": z}
            for key in per[0]:
                row[key] = float(np.nanmean([p[key] for p in per]))
            if name in INTEL_BASELINE_M:
                row["intel_rms_m"] = z * z * INTEL_SUBPIXEL_PX / (INTEL_F_PX * INTEL_BASELINE_M[name])
            rows.append(row)
            print(f"  {name:18s} {scene:18s} z={z:4.1f}  sigma {1000 * float(row['sigma_m']):7.1f} mm  "
                  f"bias {1000 * float(row['bias_m']):7.1f} mm  holes {float(row['holes']):.3f}  "
                  f"corr {float(row['corr_px']):4.1f} px", flush=True)
    return rows


def variants_at(z: float, seeds: int) -> list[dict[str, Any]]:
    """The stereo d435 model on parking_lot's ground in every ground-material and light variant."""
    cfg = load_config(overrides=["synth.sensor.model=stereo", *COARSE_TRUTH])
    rows: list[dict[str, Any]] = []
    for v in VARIANTS:
        world = record.build_world(load_scene("parking_lot", (v,) if v else ()), cfg)
        per = []
        for seed in range(seeds):
            T = down_pose(PARKING_SPOT_XY[0] + 0.31 * seed, PARKING_SPOT_XY[1] - 0.17 * seed, z)
            r = world.renderer.render(T, world.intrinsics)
            meas = world.depth_sensor.measure(r.depth_m, T, np.random.default_rng(seed))
            per.append(error_stats(meas - r.depth_m, r.object_id == 1, z, world.intrinsics.fx))
        row: dict[str, Any] = {"variant": v or "(none)", "ground": world.scene.ground.material, "z_m": z,
                                  **{k: float(np.nanmean([p[k] for p in per])) for k in per[0]}}
        rows.append(row)
        print(f"  {row['variant']:12s} ground {row['ground']:8s} sigma {1000 * float(row['sigma_m']):6.1f} mm  "
              f"holes {float(row['holes']):.3f}", flush=True)
    return rows


def timing(frames: int) -> dict[str, dict[str, float]]:
    """ms per frame of render + depth sensor at 640x480 colour (parking_lot, scenario 1), per model and setting."""
    out: dict[str, dict[str, float]] = {}
    for name, overrides in (("gaussian", ["synth.sensor.model=gaussian"]),
                            ("stereo d435", ["synth.sensor.model=stereo"]),
                            ("stereo d435, 424x240 infrared", ["synth.sensor.model=stereo",
                                                              "synth.sensor.stereo.ir_width_px=424",
                                                              "synth.sensor.stereo.ir_height_px=240"]),
                            ("stereo d435, supersample_x 1", ["synth.sensor.model=stereo",
                                                             "synth.sensor.stereo.supersample_x=1"])):
        cfg = load_config(overrides=overrides + COARSE_TRUTH)
        world = record.build_world(load_scene("parking_lot"), cfg)
        rng = np.random.default_rng(0)
        t_render = t_sensor = 0.0
        for i in range(frames):
            T = down_pose(0.05 * i, 0.0, 10.0)
            a = time.perf_counter()
            r = world.renderer.render(T, world.intrinsics)
            b = time.perf_counter()
            world.depth_sensor.measure(r.depth_m, T, rng)
            c = time.perf_counter()
            t_render += b - a
            t_sensor += c - b
        out[name] = {"render_ms": 1000 * t_render / frames, "sensor_ms": 1000 * t_sensor / frames,
                     "frame_ms": 1000 * (t_render + t_sensor) / frames}
        print(f"  {name:30s} render {out[name]['render_ms']:.0f} ms + depth sensor {out[name]['sensor_ms']:.0f} ms "
              f"= {out[name]['frame_ms']:.0f} ms/frame", flush=True)
    return out


def main() -> None:
    ap = harness.parser(__doc__, "sensor_noise")
    ap.add_argument("--seeds", type=int, default=2, help="hover positions / noise draws per range")
    ap.add_argument("--timing-frames", type=int, default=5)
    args = ap.parse_args()
    cfg = load_config(overrides=COARSE_TRUTH)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "_common.yaml").write_text((SCENES_DIR / "_common.yaml").read_text())
        (folder / "plane.yaml").write_text(PLANE)
        worlds = {"level plane": record.build_world(load_scene(folder / "plane.yaml"), cfg),
                  "parking_lot ground": record.build_world(load_scene("parking_lot"), cfg)}
        print("sigma_z / bias / holes vs range (640x480 colour camera; stereo at 848x480 infrared)")
        rows = [row for name, ov in MODELS.items() for row in run_model(name, ov, worlds, args.seeds)]
    print("stereo d435 on parking_lot's ground at 8 m, per variant")
    var = variants_at(8.0, args.seeds)
    print("time per frame at 640x480")
    times = timing(args.timing_frames)

    print("\n| z m | Intel D435 RMS mm | stereo d435 plane | stereo d435 parking lot | Intel D455 RMS mm | "
          "stereo d455 plane | stereo d455 parking lot | gaussian 0.0005 / 0.0015 / 0.003 |")
    print("|---|---|---|---|---|---|---|---|")
    pick = {(str(r["model"]), str(r["scene"]), float(r["z_m"])): r for r in rows}

    def cell(model: str, scene: str, z: float) -> str:
        r = pick[(model, scene, z)]
        return (f"{1000 * float(r['sigma_m']):.0f} mm ({1000 * float(r['bias_m']):+.0f}, "
                f"{100 * float(r['holes']):.1f} %, {float(r['corr_px']):.1f} px)")
    for z in RANGES_M:
        g = " / ".join(f"{1000 * float(pick[(m, 'level plane', z)]['sigma_m']):.0f}"
                       for m in MODELS if m.startswith("gaussian"))
        print(f"| {z:.0f} | {1000 * float(pick[('stereo d435', 'level plane', z)]['intel_rms_m']):.0f} | "
              f"{cell('stereo d435', 'level plane', z)} | {cell('stereo d435', 'parking_lot ground', z)} | "
              f"{1000 * float(pick[('stereo d455', 'level plane', z)]['intel_rms_m']):.0f} | "
              f"{cell('stereo d455', 'level plane', z)} | {cell('stereo d455', 'parking_lot ground', z)} | {g} |")
    result = {"ranges_m": list(RANGES_M), "seeds": args.seeds, "rows": rows, "variants_8m": var,
              "timing_640x480": times,
              "config": {"stereo": load_config().to_dict()["synth"]["sensor"]["stereo"]},
              "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    harness.write_results(args.out, result, indent=1)


if __name__ == "__main__":
    main()
