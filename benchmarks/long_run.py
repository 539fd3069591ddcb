"""Long recordings: peak memory of `slz detect` over 1,000 vs 10,000 frames.

Run: .venv/bin/python benchmarks/long_run.py [--lengths 1000,10000] [--method fused] [--modes keyframes,every]
                                             [--size 640x480] [--keep DIR]
Prints a table and writes benchmarks/results/long_run.json.

``--method`` (default ``fused``: the stateful method that fuses every tracked frame into a grid that
follows the UAV, the one whose state could grow with the flight) is the detect method of every run.

``--fusion-only N``: the fused method's own state over N frames, in this process and without SLAM or
recording (minutes instead of hours on a loaded machine): a camera flying straight and level at 7.5 m,
0.1 m a frame (1 km over 10,000 frames: the window moves on 25 times), each frame a 320 x 240 view of
level ground with 2 cm of depth noise, every frame fused and every 25th given the verdict of the cells in
view (``FusedMethod.observe`` and ``detect``'s fused maps); the process's RSS at 10/50/90 % of the frames.

Rendering 10,000 frames would take the renderer ~45 min, so a short hover (`--seed-frames`,
rendered by `slz synth`) is played forwards and backwards (tests/long_recording.py: the camera
motion stays continuous, SLAM keeps tracking) and written at 20 Hz as JPEG colour +
compressedDepth PNG, as a RealSense ROS driver records it. Each length runs twice through the
real CLI (`python -m slzcli.cli detect --json`): with the default keyframe detections, and
with a detection every `--every` frames, so that detections and their written frames grow
with the length too. Memory is sampled from /proc every 0.2 s for the CLI process and,
separately, its children (the ORB-SLAM3 worker); the exact peak of the largest process comes
from getrusage(RUSAGE_CHILDREN). "rss at 10/50/90 %" are the CLI's resident MiB at those
fractions of the run's wall time: flat means memory does not grow with the frames read.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness

harness.use_test_helpers()
from long_recording import write_ping_pong  # noqa: E402

REPO = harness.REPO
SAMPLE_S = 0.2
RATE_HZ = 20.0


def render_seed(folder: Path, frames: int, size: str) -> Path:
    path = folder / "seed.mcap"
    harness.slz("synth", "parking_lot", "-o", str(path), "--frames", str(frames), *harness.size_overrides(size))
    return path


def write_long(seed: Path, out: Path, length: int) -> float:
    """``length`` frames of ``seed`` in ping-pong order, JPEG + compressedDepth; returns MB written."""
    from slzcli.config import load_config

    write_ping_pong(seed, out, length, load_config(), rate_hz=RATE_HZ, color_encoding="jpeg",
                    depth_encoding="compressedDepth")
    return out.stat().st_size / 1e6


def _rss_kib(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):  # the task ended while we looked
            kids += [int(k) for k in (task / "children").read_text().split()]
    return kids


def detect(recording: Path, out: Path, method: str, *sets: str) -> dict:
    """One `slz detect --method METHOD` run with memory sampled while it runs."""
    cmd = [sys.executable, "-m", "slzcli.cli", "detect", str(recording), "-o", str(out), "--json", "--force",
           "--method", method]
    for s in sets:
        cmd += ["--set", s]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    samples: list[tuple[float, int, int]] = []
    while proc.poll() is None:
        kids = _children(proc.pid)
        samples.append((time.perf_counter() - t0, _rss_kib(proc.pid), sum(_rss_kib(k) for k in kids)))
        time.sleep(SAMPLE_S)
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"detect {recording.name} failed: {stderr.strip()}")
    summary = json.loads(stdout)
    main = [s[1] for s in samples if s[1] > 0]

    def at(frac: float) -> float:
        pick = [s[1] for s in samples if s[0] >= frac * wall and s[1] > 0]
        return round(pick[0] / 1024, 1) if pick else float("nan")

    timings = json.loads((out / "run.json").read_text())["timings"]
    fuse = timings.get("fuse")
    return {"method": method, "frames": summary["frames"], "detections": summary["detections"],
            "keyframes": summary["keyframes"],
            "status": summary["status"], "wall_s": round(wall, 1),
            "ms_per_frame": round(1e3 * wall / max(summary["frames"], 1), 2),
            "peak_rss_mb": round(max(main) / 1024, 1),
            "peak_orbslam3_rss_mb": round(max(s[2] for s in samples) / 1024, 1),
            "rss_mb_at_10_50_90_pct": [at(0.1), at(0.5), at(0.9)],
            "fuse_cpu_ms": None if fuse is None else {k: round(fuse[k], 2) for k in ("median_ms", "mean_ms", "count")},
            "run_folder_mb": round(sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6, 1)}


def fusion_only(frames: int) -> dict:
    """RSS of this process while the fused terrain flies ``frames`` frames (see the module docstring)."""
    import numpy as np

    from slzcli.config import load_config
    from slzcli.fusion.session import FusedTerrain, pixel_cells
    from slzcli.scoring import get_scorer
    from slzcli.synth.flight import R_WORLD_CAMERA_DOWN
    from slzcli.types import DepthNoise, Intrinsics

    cfg = load_config()
    intr = Intrinsics(231.0, 231.0, 159.5, 119.5, 320, 240)
    terrain = FusedTerrain(cfg, get_scorer(cfg.scoring, cfg.mask, "fuzzy"))
    noise = DepthNoise.white(0.002, "known")
    rng = np.random.default_rng(0)
    rss: list[tuple[int, float]] = []
    t0 = time.perf_counter()
    for i in range(frames):
        T = np.eye(4)
        T[:3, :3] = R_WORLD_CAMERA_DOWN
        T[:3, 3] = (0.1 * i, 0.0, 7.5)
        depth = (7.5 + rng.normal(0.0, 0.02, (intr.height, intr.width))).astype(np.float32)
        terrain.add(depth, intr, T, noise, 0, i)
        if i % 25 == 24:
            fm = terrain.maps_in_view()
            assert fm is not None
            pixel_cells(fm, depth, intr, T)
        if i % max(1, frames // 100) == 0:
            rss.append((i, _rss_kib(os.getpid()) / 1024))

    def at(frac: float) -> float:
        return round(next(r for i, r in rss if i >= frac * frames), 1)

    grid = terrain.grid
    return {"mode": "fusion only", "frames": frames, "wall_s": round(time.perf_counter() - t0, 1),
            "rss_mb_at_10_50_90_pct": [at(0.1), at(0.5), at(0.9)], "peak_rss_mb": round(max(r for _, r in rss), 1),
            "grid_mb": None if grid is None else round(grid.nbytes() / 1e6, 1)}


def main() -> None:
    ap = harness.parser(__doc__, "long_run")
    ap.add_argument("--lengths", default="1000,10000")
    ap.add_argument("--size", default="640x480", help="WxH of the rendered frames")
    ap.add_argument("--seed-frames", type=int, default=100)
    ap.add_argument("--every", type=int, default=25, help="detection period of the every_nth runs (frames)")
    ap.add_argument("--method", default="fused", help="slz detect --method of every run")
    ap.add_argument("--modes", default="keyframes,every", help="keyframes (the default detections), every "
                    "(a detection every --every frames)")
    ap.add_argument("--keep", type=Path, help="work folder to keep (default: a temporary one)")
    ap.add_argument("--fusion-only", type=int, metavar="N", help="only the fused method's state over N frames, "
                    "in this process (no recording, no SLAM)")
    args = ap.parse_args()
    if args.fusion_only:
        row = fusion_only(args.fusion_only)
        print(json.dumps(row))
        harness.write_results(args.out, {"fusion_only": row})
        return
    lengths = [int(x) for x in args.lengths.split(",")]
    width, height = (int(v) for v in args.size.lower().split("x"))
    work = args.keep or Path(tempfile.mkdtemp(prefix="slz_long_"))
    work.mkdir(parents=True, exist_ok=True)
    seed = render_seed(work, args.seed_frames, args.size)
    all_modes = {"keyframes": [], "every": ["landing.detect_on=every_nth", f"landing.every_nth_frame={args.every}"]}
    modes = {m if m != "every" else f"every_{args.every}": all_modes[m] for m in args.modes.split(",")}
    rows = []
    for n in lengths:
        rec = work / f"long_{n}.mcap"
        t0 = time.perf_counter()
        mb = write_long(seed, rec, n)
        write_s = time.perf_counter() - t0
        for mode, sets in modes.items():
            row = {"length": n, "mode": mode, "recording_mb": round(mb, 1), "write_s": round(write_s, 1),
                   **detect(rec, work / f"run_{n}_{mode}", args.method, *sets)}
            rows.append(row)
            print(json.dumps(row), flush=True)
        if args.keep is None:
            rec.unlink()
    largest = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"\n{'frames':>7} {'mode':>10} {'detections':>10} {'ms/frame':>9} {'peak MiB':>9} {'ORB MiB':>8} "
          f"{'rss 10/50/90 %':>20} {'run MB':>7}")
    for r in rows:
        print(f"{r['frames']:>7} {r['mode']:>10} {r['detections']:>10} {r['ms_per_frame']:>9} {r['peak_rss_mb']:>9} "
              f"{r['peak_orbslam3_rss_mb']:>8} {r['rss_mb_at_10_50_90_pct']!s:>20} {r['run_folder_mb']:>7}")
    ratios = {}
    for mode in modes:
        by_n = {r["length"]: r for r in rows if r["mode"] == mode}
        if len(by_n) >= 2:
            lo, hi = by_n[min(by_n)], by_n[max(by_n)]
            ratios[mode] = {"peak_rss_ratio": round(hi["peak_rss_mb"] / lo["peak_rss_mb"], 3),
                            "peak_rss_delta_mb": round(hi["peak_rss_mb"] - lo["peak_rss_mb"], 1),
                            "orbslam3_rss_ratio": round(hi["peak_orbslam3_rss_mb"]
                                                        / max(lo["peak_orbslam3_rss_mb"], 1e-9), 3)}
            print(f"{mode}: peak RSS {max(by_n)} vs {min(by_n)} frames = x{ratios[mode]['peak_rss_ratio']} "
                  f"({ratios[mode]['peak_rss_delta_mb']:+} MiB); "
                  f"ORB-SLAM3 worker x{ratios[mode]['orbslam3_rss_ratio']}")
    harness.write_results(args.out, {
        "method": args.method, "size": [width, height], "seed_frames": args.seed_frames, "rows": rows, "ratios": ratios,
        "largest_process_peak_mb": round(largest, 1), "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
        indent=1)
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)  # the run folders: ~5 GB at 10,000 frames


if __name__ == "__main__":
    main()
