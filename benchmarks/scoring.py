"""Scoring stage timing and accuracy on one core: fuzzy exact, the compiled evaluators (closed
form, the default for the shipped rules, and the simplex table, the general fallback), Bayes,
mask, the compiled evaluators' errors, and scikit-fuzzy for reference.

Run: .venv/bin/python benchmarks/scoring.py [--repeats N]
Prints a table and writes benchmarks/results/scoring.json. Times are medians of wall time
and of process CPU time (the CPU time is less disturbed when other jobs share the cores;
the load average at start is recorded).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import itertools  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import cv2  # noqa: E402
import harness  # noqa: E402
import numpy as np  # noqa: E402

from slzcli.config import load_config  # noqa: E402
from slzcli.scoring import MaskParams, bayes, closed_form, fuzzy, get_scorer, lut, score_frame  # noqa: E402
from slzcli.scoring.rules import load_rules  # noqa: E402
from slzcli.types import Intrinsics, TerrainMaps  # noqa: E402

harness.use_test_helpers()
from skfuzzy_oracle import skfuzzy_simulation  # noqa: E402

H, W = 480, 640


def realistic_maps(seed: int = 0) -> tuple[TerrainMaps, np.ndarray]:
    """Smooth fields with sharp obstacles and holes, like the terrain stage's output."""
    rng = np.random.default_rng(seed)

    def field(sigma: float) -> np.ndarray:
        f = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), sigma)
        return (f - f.min()) / (f.max() - f.min())

    obstacles = np.zeros((H, W), np.uint8)
    for _ in range(12):
        cv2.circle(obstacles, (int(rng.integers(0, W)), int(rng.integers(0, H))), int(rng.integers(10, 50)), 1, -1)
    edge_dist = cv2.distanceTransform(1 - obstacles, cv2.DIST_L2, 5)
    flat = np.clip(edge_dist / 60.0, 0, 1).astype(np.float32)
    steep = np.clip(field(40) * 1.4 - 0.1, 0, 1) * (1 - obstacles)
    incl = np.clip(field(15) * 0.6 + 0.5 * flat, 0, 1)
    dvar = np.clip(1.0 - 0.3 * field(5) - 0.7 * obstacles, 0, 1)
    depth = (5.0 + 0.5 * field(60)).astype(np.float32)
    valid = rng.random((H, W)) > 0.02
    depth[~valid] = np.nan
    maps = {"depth_variance": dvar, "flatness": flat, "inclination": incl, "steepness": steep}
    maps = {k: np.where(valid, v, 0).astype(np.float32) for k, v in maps.items()}
    return TerrainMaps(**maps, valid=valid, slope_deg=np.zeros((H, W), np.float32)), depth


def timed(fn, repeats: int) -> tuple[float, float]:
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall) * 1e3), float(np.median(cpu) * 1e3)


def skfuzzy_ms_per_pixel(rb, n: int) -> float:
    sim = skfuzzy_simulation(rb)
    x = np.random.default_rng(1).random((len(rb.inputs), n))
    t0 = time.perf_counter()
    for v, row in zip(rb.inputs, x, strict=True):
        sim.input[v.name] = row
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.compute()
    return (time.perf_counter() - t0) * 1e3 / n


def main() -> None:
    ap = harness.parser(__doc__, "scoring")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--sk-pixels", type=int, default=500)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    load0 = os.getloadavg()[0]
    config = load_config()
    rb = load_rules(config.scoring.fuzzy.rules)
    levels = config.scoring.fuzzy.lut_levels

    t0 = time.perf_counter()
    table = lut.build(rb, levels)
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    program = closed_form.build(rb)
    program_build_s = time.perf_counter() - t0
    assert program is not None, "the shipped rules should compile to the closed form"

    maps, depth = realistic_maps()
    K = Intrinsics(462.137, 462.137, 320.0, 240.0, W, H)
    fuzzy_c = get_scorer(config.scoring, config.mask, "fuzzy")
    bayes_s = get_scorer(config.scoring, config.mask, "bayes")
    inputs = [maps.as_dict()[n] for n in rb.input_names]
    flat = np.stack([x.ravel() for x in inputs]).astype(np.float64)
    score = fuzzy_c(maps)

    rows = {}
    a, b = np.random.default_rng(0).random((2, H, W), dtype=np.float32)
    rows["reference: one float32 add (a + b)"] = timed(lambda: np.add(a, b), args.repeats)
    rows["fuzzy exact"] = timed(lambda: fuzzy.evaluate_exact(rb, flat), max(1, args.repeats // 10))
    rows["fuzzy compiled: closed form (default)"] = timed(lambda: program(inputs), args.repeats)
    rows["fuzzy compiled: simplex table (fallback)"] = timed(lambda: table(inputs), args.repeats)
    rows["fuzzy compiled (scorer, valid mask)"] = timed(lambda: fuzzy_c(maps), args.repeats)
    rows["bayes (scorer)"] = timed(lambda: bayes_s(maps), args.repeats)
    rows["bayes fuse only"] = timed(lambda: bayes.fuse(list(maps.as_dict().values()), 0.5, 0.01), args.repeats)
    rows["mask (median depth + blur + erode + threshold)"] = timed(lambda: _mask_only(score, depth, K, config),
                                                                    args.repeats)
    params = MaskParams.of(config)
    rows["score_frame (compiled fuzzy + mask)"] = timed(lambda: score_frame(fuzzy_c, maps, depth, K, params),
                                                         args.repeats)

    exact_frame = fuzzy.evaluate_exact(rb, flat).reshape(H, W)
    frame_err = float(np.max(np.abs(table(inputs) - exact_frame)[maps.valid]))
    frame_err_cf = float(np.max(np.abs(program(inputs) - exact_frame)[maps.valid]))
    rng = np.random.default_rng(3)
    vals = [0.0, 0.25, 0.5, 0.75, 1.0, 0.5 - 1e-4, 0.5 + 1e-4, 0.25 + 1e-3, 0.75 - 1e-3]
    kinks = np.array(list(itertools.product(vals, repeat=len(rb.inputs)))).T
    pts = np.concatenate([rng.random((len(rb.inputs), 100_000)), kinks], axis=1).astype(np.float32)
    exact_pts = fuzzy.evaluate_exact(rb, pts.astype(np.float64))
    rand_err = float(np.max(np.abs(table(list(pts)) - exact_pts)))
    rand_err_cf = float(np.max(np.abs(program(list(pts)) - exact_pts)))

    sk_ms_px = skfuzzy_ms_per_pixel(rb, args.sk_pixels)
    sk_frame_ms = sk_ms_px * H * W
    compiled_ms = rows["fuzzy compiled: closed form (default)"][0]

    print(f"scoring benchmark, {W}x{H}, one thread; load average at start {load0:.2f} "
          f"({os.cpu_count()} cores shared with other jobs)")
    print(f"{'stage':48s} {'wall ms':>10s} {'cpu ms':>10s}")
    for name, (wall, cpu) in rows.items():
        print(f"{name:48s} {wall:10.2f} {cpu:10.2f}")
    print(f"closed form: {len(program.program)} array ops, {program.n_registers} buffers of "
          f"{closed_form.CHUNK_PX} px, build {program_build_s * 1e3:.1f} ms; max |closed form - exact|: "
          f"{rand_err_cf:.2e} (100k random + {kinks.shape[1]} kink points), {frame_err_cf:.2e} (this frame)")
    print(f"simplex table: {levels} levels, build {build_s:.2f} s; max |table - exact|: "
          f"{rand_err:.4f} (100k random + {kinks.shape[1]} kink points), {frame_err:.4f} (this frame)")
    print(f"scikit-fuzzy: {sk_ms_px:.3f} ms/pixel on {args.sk_pixels} px -> {sk_frame_ms / 1e3:.1f} s/frame; "
          f"compiled / scikit-fuzzy = {compiled_ms / sk_frame_ms:.2e} (x{sk_frame_ms / compiled_ms:.0f} faster)")
    print("(the reference row measures the machine's contention: 0.13 ms on this machine at load 0.5)")
    print(f"mean score {float(score[maps.valid].mean()):.3f}")

    harness.write_results(args.out, {
        "frame": [W, H], "threads": 1, "load_average_start": load0,
        "median_ms": {k: {"wall": v[0], "cpu": v[1]} for k, v in rows.items()},
        "closed_form": {"ops": len(program.program), "buffers": program.n_registers,
                        "chunk_px": closed_form.CHUNK_PX, "build_s": program_build_s,
                        "max_error_random_and_kinks": rand_err_cf, "max_error_frame": frame_err_cf,
                        "points": int(pts.shape[1])},
        "table": {"levels": levels, "build_s": build_s, "max_error_random_and_kinks": rand_err,
                  "max_error_frame": frame_err, "points": int(pts.shape[1])},
        "skfuzzy": {"ms_per_pixel": sk_ms_px, "pixels": args.sk_pixels, "frame_ms_extrapolated": sk_frame_ms,
                    "compiled_over_skfuzzy": compiled_ms / sk_frame_ms},
    })


def _mask_only(score: np.ndarray, depth: np.ndarray, K: Intrinsics, config) -> None:
    from slzcli.scoring.mask import landing_mask
    landing_mask("fuzzy", score, depth, K.fx, K.fy, config.uav.footprint_m, config.mask.margin_factor,
                 config.mask.threshold, config.mask.smooth_m)


if __name__ == "__main__":
    main()
