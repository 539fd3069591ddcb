"""Per-frame cost of putting a frame in the colour camera's geometry (sources/color_camera.py).

Medians over repeated runs, in one process, of: the nearest-neighbour resize slz used to do
(the reference), depth registration of an 848x480 depth image into a 640x480 colour camera
(a D435's raw streams; registration.py), and undistortion of a 640x480 colour image and its
aligned depth (undistort.py, maps cached per camera). Ratios are against the resize, so the
numbers compare across machines. Prints a table and writes benchmarks/results/cameras.json.
Usage:
    .venv/bin/python benchmarks/cameras.py [--runs 15]
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import harness
import numpy as np

from slzcli.sources import decode
from slzcli.sources.registration import depth_rays, register_depth
from slzcli.sources.undistort import undistort_color, undistort_depth, undistort_maps
from slzcli.types import Intrinsics

K_DEPTH = Intrinsics(424.0, 424.0, 423.5, 239.5, 848, 480)
K_COLOR = Intrinsics(615.0, 615.5, 319.5, 239.5, 640, 480)
K_DISTORTED = Intrinsics(615.0, 615.5, 319.5, 239.5, 640, 480, "plumb_bob", (0.12, -0.25, 0.001, -0.0005, 0.1))


def scene() -> np.ndarray:
    """848x480 depth: a floor 2-4 m away with a box and 10 % holes."""
    v = np.mgrid[0:480, 0:848][0]
    depth = (2.0 + 0.004 * v).astype(np.float32)
    depth[150:300, 300:500] -= 0.6
    depth[np.random.default_rng(0).random(depth.shape) < 0.1] = np.nan
    return depth


def median_ms(fn: Callable[[], object], runs: int) -> float:
    fn()  # warm: caches (rays, maps) and the allocator
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def main() -> None:
    ap = harness.parser(__doc__, "cameras")
    ap.add_argument("--runs", type=int, default=15)
    args = ap.parse_args()
    depth = scene()
    rgb = np.random.default_rng(1).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    T = np.eye(4)
    T[0, 3] = -0.015
    maps = undistort_maps(K_DISTORTED)
    assert maps is not None
    aligned = decode.match_depth_to_color(depth, (480, 640))
    cases = {
        "resize 848x480 -> 640x480 (reference, the old behaviour)": lambda: decode.match_depth_to_color(depth,
                                                                                                       (480, 640)),
        "register 848x480 depth -> 640x480 colour": lambda: register_depth(depth, K_DEPTH, T, K_COLOR),
        "undistort 640x480 colour + aligned depth": lambda: (undistort_color(rgb, maps),
                                                             undistort_depth(aligned, maps)),
    }
    t = time.perf_counter()
    depth_rays.cache_clear()
    depth_rays(K_DEPTH)
    once_ms = (time.perf_counter() - t) * 1e3
    rows = {name: median_ms(fn, args.runs) for name, fn in cases.items()}
    ref = next(iter(rows.values()))
    print(f"{'case':58s} {'median ms':>10s} {'x resize':>9s}")
    for name, ms in rows.items():
        print(f"{name:58s} {ms:10.2f} {ms / ref:9.1f}")
    print(f"{'depth rays of the 848x480 camera (once per recording)':58s} {once_ms:10.2f}")
    out = {"runs": args.runs,
           "median_ms": {k: round(v, 3) for k, v in rows.items()},
           "ratio_to_resize": {k: round(v / ref, 2) for k, v in rows.items()},
           "depth_rays_once_ms": round(once_ms, 2)}
    harness.write_results(args.out, out)


if __name__ == "__main__":
    main()
