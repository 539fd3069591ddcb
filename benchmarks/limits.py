"""Limits before allocation (issue 15): what a frame costs by its size, how fast SIGTERM acts, Monte Carlo memory.

Run: .venv/bin/python benchmarks/limits.py [--sizes 640x480,2048x1536,4096x4096] [--skip-sigterm] [--skip-mc]
Prints the numbers and writes benchmarks/results/limits.json.

- Memory by frame size: `slz detect` (odometry SLAM, a detection on every frame) on a 2-frame
  recording of flat textured ground at each size; the peak RSS of the CLI process from
  getrusage(RUSAGE_CHILDREN). Bytes a pixel = (peak - peak at the smallest size) / pixels: the
  basis of ``sources.max_image_px``.
- SIGTERM: the same run on the largest size, signalled after several delays (so inside
  different stages, the 20 s Gaussian blur of the mask among them); latency = signal -> exit.
- Monte Carlo: peak RSS of `slz land simulate --runs N` (short flights) for two N: chunked, the
  peak does not follow N (the whole batch at once held N x 256 x 15 x 8 B of noise).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import harness
import numpy as np

harness.use_test_helpers()
import bad_inputs as B  # noqa: E402
from landing_file import write_landing  # noqa: E402

REPO = harness.REPO

DETECT = ["--set", "slam.backend=odometry", "--set", "landing.detect_on=every_nth"]


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "slzcli.cli", *args]


def child_peak_mib(cmd: list[str]) -> tuple[float, float, int]:
    """(peak RSS MiB, wall s, exit code) of one command, run in a fresh grandchild so RUSAGE_CHILDREN is its own."""
    probe = ("import resource, subprocess, sys, time, json; t = time.perf_counter(); "
             "rc = subprocess.run(sys.argv[1:], capture_output=True).returncode; "
             "print(json.dumps([resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, "
             "time.perf_counter() - t, rc]))")
    out = subprocess.run([sys.executable, "-c", probe, *cmd], cwd=REPO, capture_output=True, text=True, check=True)
    peak, wall, rc = json.loads(out.stdout)
    return peak, wall, rc


def flat_recording(folder: Path, w: int, h: int, frames: int = 2) -> Path:
    block = 8 if w >= 1024 else 2
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (h // block, w // block, 3), dtype=np.uint8).repeat(block, 0).repeat(block, 1)
    path = folder / f"flat_{w}x{h}.mcap"
    B._write(path, [B.textured_frame(i, w=w, h=h, rgb=np.roll(rgb, 2 * block * i, axis=1)) for i in range(frames)])
    return path


def memory_by_size(folder: Path, sizes: list[tuple[int, int]]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for w, h in sizes:
        rec = flat_recording(folder, w, h)
        peak, wall, rc = child_peak_mib(cli("detect", str(rec), "-o", str(folder / f"run_{w}"), "--force", *DETECT))
        rows.append({"size": f"{w}x{h}", "pixels": w * h, "peak_rss_mib": round(peak, 1), "wall_s": round(wall, 1),
                     "exit": rc})
        print(rows[-1], flush=True)
    base = rows[0]
    for r in rows[1:]:
        r["bytes_per_px_over_smallest"] = round((r["peak_rss_mib"] - base["peak_rss_mib"]) * 2**20
                                                / (r["pixels"] - base["pixels"]), 1)
    return rows


def sigterm_latency(rec: Path, folder: Path, delays: list[float]) -> list[dict[str, object]]:
    rows = []
    for d in delays:
        run = folder / "run_sigterm"
        p = subprocess.Popen(cli("detect", str(rec), "-o", str(run), "--force", *DETECT), cwd=REPO,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        time.sleep(d)
        t0 = time.perf_counter()
        p.send_signal(signal.SIGTERM)
        try:
            _, err = p.communicate(timeout=300)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
        left = sorted(x.name for x in folder.iterdir() if x.name.startswith((".run_sigterm", "run_sigterm")))
        rows.append({"signal_after_s": d, "latency_s": round(time.perf_counter() - t0, 2), "exit": p.returncode,
                     "left_behind": left, "last_line": (err.strip().splitlines() or [""])[-1]})
        print(rows[-1], flush=True)
    return rows


def montecarlo_memory(folder: Path, runs_list: list[int]) -> list[dict[str, Any]]:
    run = folder / "RUN"
    write_landing(run)
    rows = []
    for n in runs_list:
        peak, wall, rc = child_peak_mib(cli("land", "simulate", str(run), "--start", "0,0,3", "--runs", str(n),
                                            "--set", "control.sim.timeout_s=2"))
        rows.append({"runs": n, "peak_rss_mib": round(peak, 1), "wall_s": round(wall, 1), "exit": rc})
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = harness.parser(__doc__, "limits")
    ap.add_argument("--sizes", default="640x480,2048x1536,4096x4096")
    ap.add_argument("--delays", default="5,15,25,35")
    ap.add_argument("--runs", default="1024,8192")
    ap.add_argument("--skip-sigterm", action="store_true")
    ap.add_argument("--skip-mc", action="store_true")
    args = ap.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    out: dict[str, object] = {"date": time.strftime("%Y-%m-%d")}
    with tempfile.TemporaryDirectory(prefix="slz_limits_") as tmp:
        folder = Path(tmp)
        out["memory_by_frame_size"] = memory_by_size(folder, sizes)  # type: ignore[arg-type]
        if not args.skip_sigterm:
            w, h = sizes[-1]
            out["sigterm_latency"] = sigterm_latency(flat_recording(folder, w, h, frames=3), folder,
                                                     [float(d) for d in args.delays.split(",")])
        if not args.skip_mc:
            out["montecarlo_memory"] = montecarlo_memory(folder, [int(n) for n in args.runs.split(",")])
    harness.write_results(args.out, out)


if __name__ == "__main__":
    main()
