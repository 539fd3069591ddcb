"""Per-stage time of the four terrain maps at 640x480 on one core, and Open3D for reference.

Stages (median ms over --runs calls after a warm-up): back-projection, normals (image-space
plane fit), patch PCA (reduced resolution, adaptive windows), each map, and compute_maps
(all four together, the number that counts). Reference: Open3D ``estimate_normals`` on the
same frame's full cloud (KNN 25 ~ the 5x5 window, and radius 0.5 m hybrid with max_nn 30),
one or two runs. Frames: an analytic 640x480 scene (nadir camera 10 m over ground with a box,
1 cm noise, 1 % holes) and the real RealSense frame ../shared/data/realsense_floor/000000
when present.

One core: OMP/OPENBLAS/MKL threads 1 and cv2.setNumThreads(1), set before numpy/cv2 load.
The machine may be shared: the minimum is printed next to the median as a load check, and
the 1-minute load average is recorded. compute_maps is also timed in fresh processes with
glibc's default malloc and with a 64 MiB top pad (page faults dominate otherwise; see
``allocator_comparison``).

Prints a table and writes benchmarks/results/terrain.json. Usage:
    .venv/bin/python benchmarks/terrain.py [--runs 30] [--o3d-runs 2]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import harness  # noqa: E402
import numpy as np  # noqa: E402

from slzcli.config import load_config  # noqa: E402
from slzcli.terrain import geometry as geo  # noqa: E402
from slzcli.terrain import maps as tm  # noqa: E402
from slzcli.types import Intrinsics  # noqa: E402

REALSENSE = harness.REALSENSE
cv2.setNumThreads(1)


def analytic_frame(intr: Intrinsics) -> np.ndarray:
    """Nadir camera 10 m over level ground with a 1.5 m box; 1 cm noise, 1 % random holes."""
    rng = np.random.default_rng(0)
    rx, ry = geo.pixel_rays(intr)
    rx, ry = np.broadcast_arrays(rx * 10.0, ry * 10.0)
    depth = np.full((intr.height, intr.width), 10.0, np.float32)
    on_box = (rx > 0.5) & (rx < 3.0) & (np.abs(ry) < 1.0)
    depth[on_box] = 8.5
    depth += rng.normal(0, 0.01, depth.shape).astype(np.float32)
    depth[rng.random(depth.shape) < 0.01] = np.nan
    return depth


def realsense_frame() -> tuple[np.ndarray, Intrinsics] | None:
    if not (REALSENSE / "cam_params_realsense.json").is_file():
        return None
    cam = json.loads((REALSENSE / "cam_params_realsense.json").read_text())
    k = np.array(cam["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T
    intr = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], int(cam["width"]), int(cam["height"]))
    raw = cv2.imread(str(REALSENSE / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    if raw is None:
        return None
    return np.where(raw > 0, raw.astype(np.float32) * np.float32(0.001), np.nan).astype(np.float32), intr


def timed(fn: Callable[[], Any], runs: int) -> dict[str, float]:
    fn()                                              # warm-up (caches, lazy imports)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return {"median_ms": statistics.median(times), "min_ms": min(times)}


def stages(depth: np.ndarray, intr: Intrinsics, up: np.ndarray, runs: int) -> dict[str, dict[str, float]]:
    cfg = load_config().terrain
    field = geo.normal_field(depth, intr, cfg.steepness.normal_px, cfg.steepness.min_valid_fraction)
    pca = geo.patch_pca(depth, intr, cfg.inclination.radius_m, cfg.inclination.work_px,
                        cfg.inclination.min_points, up)
    psi = tm.slope_rad(field, up)
    return {
        "back_projection": timed(lambda: geo.back_project(depth, intr), runs),
        "normals": timed(lambda: geo.normal_field(depth, intr, cfg.steepness.normal_px,
                                                  cfg.steepness.min_valid_fraction), runs),
        "normals_unit_hxwx3": timed(lambda: field.unit(), runs),
        "patch_pca": timed(lambda: geo.patch_pca(depth, intr, cfg.inclination.radius_m, cfg.inclination.work_px,
                                                 cfg.inclination.min_points, up), runs),
        "depth_variance_map": timed(lambda: tm.depth_variance_map(depth, cfg.depth_variance), runs),
        "flatness_map": timed(lambda: tm.flatness_map(depth, intr, cfg.flatness, 0.01), runs),
        "inclination_map": timed(lambda: tm.inclination_map(pca.curvature, cfg.inclination), runs),
        "steepness_map": timed(lambda: tm.steepness_map(tm.slope_rad(field, up), cfg.steepness, 15.0), runs),
        "slope_only": timed(lambda: tm.slope_rad(field, up), runs),
        "steepness_from_slope": timed(lambda: tm.steepness_map(psi, cfg.steepness, 15.0), runs),
        "total_compute_maps": timed(lambda: tm.compute_maps(depth, intr, up, cfg), runs),
    }


def open3d_normals(depth: np.ndarray, intr: Intrinsics, runs: int) -> dict[str, float]:
    import open3d as o3d

    pts = geo.back_project(depth, intr).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)].astype(np.float64)
    out = {"points": float(len(pts))}
    for name, param in (("knn25", o3d.geometry.KDTreeSearchParamKNN(25)),
                        ("hybrid_r0.5_nn30", o3d.geometry.KDTreeSearchParamHybrid(0.5, 30))):
        times = []
        for _ in range(runs):
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
            t0 = time.perf_counter()
            pc.estimate_normals(param)
            times.append((time.perf_counter() - t0) * 1e3)
        out[f"{name}_ms"] = statistics.median(times)
    return out


def total_child(frame: str, runs: int) -> None:
    """Child mode: time compute_maps alone (fresh process) and print one JSON line."""
    import resource

    c = load_config().camera
    intr = Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    if frame == "analytic_box_10m":
        depth, k, up = analytic_frame(intr), intr, np.array([0.0, 0.0, -1.0])
    else:
        real = realsense_frame()
        assert real is not None
        depth, k, up = real[0], real[1], np.array([0.326, -0.853, -0.408])
    cfg = load_config().terrain
    tm.compute_maps(depth, k, up, cfg)
    faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    t = timed(lambda: tm.compute_maps(depth, k, up, cfg), runs)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0) / (runs + 1)
    print(json.dumps({**t, "page_faults_per_call": faults}))


def allocator_comparison(frame: str, runs: int) -> dict[str, dict[str, float]]:
    """compute_maps in fresh processes: default glibc malloc vs a 64 MiB top pad.

    The maps allocate ~15 MB of 640x480 temporaries per call; with glibc's defaults the heap is
    trimmed after every call and every page faults again on the next one. A process-wide
    ``MALLOC_TOP_PAD_`` (or ``mallopt(M_TOP_PAD)``) keeps the pages; that is a deployment choice
    for the process running the pipeline, not something library code should change.
    """
    import subprocess
    import sys

    out = {}
    for name, extra in (("default_malloc", {}), ("malloc_top_pad_64MiB", {"MALLOC_TOP_PAD_": str(64 << 20)})):
        env = {**os.environ, **extra}
        proc = subprocess.run([sys.executable, __file__, "--child-total", frame, "--runs", str(runs)],
                              env=env, capture_output=True, text=True, check=True)
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    ap = harness.parser(__doc__, "terrain")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--o3d-runs", type=int, default=2)
    ap.add_argument("--child-total", metavar="FRAME", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_total:
        total_child(args.child_total, args.runs)
        return
    try:
        import open3d as o3d
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    except ImportError:  # pragma: no cover - open3d is a dependency
        pass

    c = load_config().camera
    intr = Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    frames = {"analytic_box_10m": (analytic_frame(intr), intr, np.array([0.0, 0.0, -1.0]))}
    real = realsense_frame()
    if real is not None:
        # the floor's tilt measured by tests/terrain/test_terrain.py: pitch 64.4 deg, roll 19.0 deg
        frames["realsense_000000"] = (real[0], real[1], np.array([0.326, -0.853, -0.408]))

    results: dict[str, Any] = {
        "cv2_threads": cv2.getNumThreads(), "load_avg_start": os.getloadavg(),
        "runs": args.runs, "frames": {},
    }
    for name, (depth, k, up) in frames.items():
        by_stage = stages(depth, k, up, args.runs)
        o = open3d_normals(depth, k, args.o3d_runs)
        fresh = allocator_comparison(name, args.runs)
        results["frames"][name] = {"stages": by_stage, "open3d": o, "total_fresh_process": fresh}
        print(f"\n{name}  ({depth.shape[1]}x{depth.shape[0]}, one core)")
        print(f"  {'stage':<24} {'median ms':>10} {'min ms':>8}")
        for stage, t in by_stage.items():
            print(f"  {stage:<24} {t['median_ms']:>10.2f} {t['min_ms']:>8.2f}")
        print(f"  open3d estimate_normals over {int(o['points'])} points: knn25 {o['knn25_ms']:.0f} ms, "
              f"hybrid r=0.5 m nn30 {o['hybrid_r0.5_nn30_ms']:.0f} ms")
        for alloc, t in fresh.items():
            print(f"  compute_maps, fresh process, {alloc:<22} median {t['median_ms']:6.2f} ms, "
                  f"min {t['min_ms']:6.2f} ms, {t['page_faults_per_call']:.0f} page faults/call")
        total = by_stage["total_compute_maps"]["median_ms"]
        print(f"  four maps together: {total:.1f} ms; Open3D normals alone (knn25) take "
              f"{o['knn25_ms'] / total:.0f}x that")
    harness.write_results(args.out, results)


if __name__ == "__main__":
    main()
