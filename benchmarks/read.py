"""Reading speed and memory of slz's recording readers (sources/).

1. frames/s reading + decoding 640x480 RGB-D from every format (median of several
   runs over one recording of N frames written with RecordingWriter in a temp dir);
2. peak resident memory (ru_maxrss of a fresh subprocess) reading 100 vs 1,000
   frames of one format: the readers stream, so it must not grow with length.

Prints a table and writes benchmarks/results/read.json. Usage:
    .venv/bin/python benchmarks/read.py [--frames 150] [--runs 3]
"""

from __future__ import annotations

import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness
import numpy as np

from slzcli.config import load_config
from slzcli.outputs.recording import RecordingWriter
from slzcli.sources import open_recording
from slzcli.types import Frame, Intrinsics

W, H = 640, 480
INTR = Intrinsics(617.25, 617.55, 317.39, 245.98, W, H)
CASES = [  # (format, colour encoding, depth encoding)
    ("mcap", "rgb8", "16UC1"),
    ("mcap-ros1", "rgb8", "16UC1"),
    ("ros1", "rgb8", "16UC1"),
    ("ros2-sqlite", "rgb8", "16UC1"),
    ("ros2-mcap", "rgb8", "16UC1"),
    ("mcap", "jpeg", "compressedDepth"),
    ("mcap", "bgr8", "32FC1"),
]
SUFFIX = {"mcap": ".mcap", "mcap-ros1": ".mcap", "ros1": ".bag", "ros2-sqlite": "", "ros2-mcap": ""}


def synthetic_frame(i: int) -> Frame:
    """A textured but compressible 640x480 frame (a sloped floor with a box), distinct per index."""
    v, u = np.mgrid[0:H, 0:W]
    rgb = np.stack([(u + 3 * i) % 256, (v + i) % 256, ((u // 8 + v // 8) * 9) % 256], -1).astype(np.uint8)
    depth = (3.0 + 0.002 * v + 0.01 * i).astype(np.float32)
    depth[200:280, 300:400] -= 0.5
    depth[::37, ::41] = np.nan
    return Frame(i, 1_700_000_000_000_000_000 + i * 33_333_333, rgb, depth, INTR)


def write(path: Path, fmt: str, color: str, depth: str, n: int) -> None:
    with RecordingWriter(path, fmt, color_encoding=color, depth_encoding=depth) as w:
        for i in range(n):
            w.write_frame(synthetic_frame(i))


def read_fps(path: Path, runs: int) -> tuple[float, int]:
    cfg = load_config()
    times, count = [], 0
    for _ in range(runs):
        t0 = time.perf_counter()
        with open_recording(path, cfg) as rec:
            count = sum(1 for _ in rec.frames())
        times.append(time.perf_counter() - t0)
    return count / statistics.median(times), count


def size_of(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size


def child_peak_rss(path: Path) -> tuple[int, int]:
    """(frames read, peak RSS in MiB) of a fresh interpreter reading every frame of ``path``."""
    code = ("import sys, resource\n"
            "from slzcli.config import load_config\nfrom slzcli.sources import open_recording\n"
            "with open_recording(sys.argv[1], load_config()) as rec:\n"
            "    n = sum(1 for _ in rec.frames())\n"
            "print(n, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    out = subprocess.run([sys.executable, "-c", code, str(path)], check=True, capture_output=True, text=True)
    n, kib = out.stdout.split()
    return int(n), int(kib) // 1024


def main() -> None:
    ap = harness.parser(__doc__, "read")
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--memory-format", default="mcap")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="slz-read-bench-"))
    rows = []
    try:
        for fmt, color, depth in CASES:
            path = tmp / f"{fmt}-{color}-{depth}{SUFFIX[fmt]}"
            write(path, fmt, color, depth, args.frames)
            fps, n = read_fps(path, args.runs)
            rows.append({"format": fmt, "color": color, "depth": depth, "frames": n,
                         "size_mb": round(size_of(path) / 2**20, 1), "fps": round(fps, 1)})
            print(f"{fmt:12s} {color:5s} {depth:16s} {n:5d} frames {rows[-1]['size_mb']:8.1f} MB {fps:8.1f} frames/s",
                  flush=True)
            shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink()
        memory = []
        for n in (100, 1000):
            path = tmp / f"mem-{n}{SUFFIX[args.memory_format]}"
            write(path, args.memory_format, "rgb8", "16UC1", n)
            got, peak = child_peak_rss(path)
            memory.append({"format": args.memory_format, "frames": got, "size_mb": round(size_of(path) / 2**20, 1),
                           "peak_rss_mib": peak})
            print(f"memory: {args.memory_format} {got} frames ({memory[-1]['size_mb']} MB on disk): "
                  f"peak RSS {peak} MiB", flush=True)
            shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"\nformat        colour depth              frames   MB on disk   frames/s (median of {args.runs:d})")
    for r in rows:
        print(f"{r['format']:13s} {r['color']:6s} {r['depth']:18s} {r['frames']:6d} {r['size_mb']:12.1f} "
              f"{r['fps']:10.1f}")
    print("\npeak RSS of a reader process: "
          + ", ".join(f"{m['frames']} frames {m['peak_rss_mib']} MiB" for m in memory))
    result = {"benchmark": "read", "resolution": [W, H], "runs": args.runs, "read": rows, "memory": memory,
              "self_peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}
    harness.write_results(args.out, result)


if __name__ == "__main__":
    main()
