"""Batch throughput: N recordings through `slz detect` with 1 and 2 local workers (and Dask).

Run: .venv/bin/python benchmarks/batch.py [--recordings 8] [--frames 10] [--workers 1,2] [--no-dask]
Prints a table and writes benchmarks/results/batch.json.

Each configuration is one `slz detect 'DIR/*.mcap' --json` subprocess into a fresh folder, so
the numbers include what a user waits for (interpreter start, worker spawn, ORB-SLAM3 start per
recording). `--workers 1` runs in-process (that is what the CLI does with one worker); 2 uses the
spawn process pool; "dask" is a `LocalCluster` of 2 single-threaded worker processes started
here and reached with --scheduler. Parallel efficiency = speed-up over 1 worker / workers.
Peak memory is each worker's peak RSS (ru_maxrss) and, separately, the largest ORB-SLAM3
child's. "cores busy" = CPU seconds of the CLI and all its descendants / wall seconds: how much
of the machine one configuration used (ORB-SLAM3 and OpenCV run threads of their own). The
machine's cores are shared with other jobs: the load average is recorded.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness

REPO = harness.REPO
SCENES = ("clear_field", "parking_lot", "playground", "office", "slopes", "no_site")


def slz(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "slzcli.cli", *args], cwd=REPO, capture_output=True, text=True,
                          check=False)


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def make_recordings(folder: Path, count: int, frames: int) -> list[Path]:
    paths = []
    for i in range(count):
        scene = SCENES[i % len(SCENES)]
        path = folder / f"{i:02d}_{scene}.mcap"
        res = slz("synth", scene, "-o", str(path), "--frames", str(frames), "--seed", str(i))
        if res.returncode != 0:
            raise SystemExit(f"synth failed: {res.stderr}")
        paths.append(path)
    return paths


def run(label: str, folder: Path, out: Path, *extra: str) -> dict:
    load = os.getloadavg()
    cpu0 = _children_cpu_s()
    t0 = time.perf_counter()
    res = slz("detect", str(folder / "*.mcap"), "-o", str(out), "--json", *extra)
    wall = time.perf_counter() - t0
    cpu = _children_cpu_s() - cpu0  # the CLI and every process it waited for (pool workers, ORB-SLAM3)
    if res.returncode != 0:
        raise SystemExit(f"{label}: detect failed: {res.stderr}")
    summary = json.loads(res.stdout)
    t, rows = summary["batch"], summary["runs"]
    per_worker: dict[str, float] = {}
    for r in rows:
        per_worker[r["worker"]] = max(per_worker.get(r["worker"], 0.0), r["peak_rss_mb"] or 0.0)
    return {"label": label, "engine": t["engine"], "workers": t["workers"], "recordings": t["processed"],
            "frames": t["frames"], "batch_wall_s": t["wall_s"], "process_wall_s": round(wall, 3),
            "recordings_per_min": t["recordings_per_min"], "frames_per_s": t["frames_per_s"],
            "recordings_per_min_incl_startup": round(60 * t["processed"] / wall, 3),
            "cpu_s": None if t["engine"] == "dask" else round(cpu, 1),  # Dask workers are not the CLI's children
            "cores_busy": None if t["engine"] == "dask" else round(cpu / wall, 2),
            "peak_rss_mb_per_worker": sorted(per_worker.values()),
            "peak_orbslam3_rss_mb": max((r.get("peak_child_rss_mb") or 0.0) for r in rows),
            "load_avg_before": [round(v, 2) for v in load], "load_avg_after": [round(v, 2) for v in os.getloadavg()],
            "statuses": [r["status"] for r in rows]}


def main() -> None:
    ap = harness.parser(__doc__, "batch")
    ap.add_argument("--recordings", type=int, default=8)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--workers", default="1,2", help="comma-separated local worker counts")
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask LocalCluster run")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="slz-bench-batch-") as tmp:
        folder = Path(tmp) / "flights"
        folder.mkdir()
        t0 = time.perf_counter()
        make_recordings(folder, args.recordings, args.frames)
        synth_s = time.perf_counter() - t0
        rows = [run(f"local x{n}", folder, Path(tmp) / f"local{n}", "--workers", str(n))
                for n in (int(w) for w in args.workers.split(","))]
        if not args.no_dask:
            try:
                from distributed import LocalCluster
            except ImportError:
                print("dask not installed: skipping the Dask run")
            else:
                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
                    rows.append(run("dask x2", folder, Path(tmp) / "dask", "--scheduler", c.scheduler_address))

    base = next((r for r in rows if r["workers"] == 1), None)
    for r in rows:
        if base is not None and r["batch_wall_s"] > 0:
            speedup = base["batch_wall_s"] / r["batch_wall_s"]
            r["speedup"] = round(speedup, 3)
            r["parallel_efficiency"] = round(speedup / r["workers"], 3)

    head = f"{'run':<10}{'workers':>8}{'rec/min':>9}{'frames/s':>10}{'wall s':>8}{'+start s':>9}" \
           f"{'speed-up':>9}{'effic.':>8}{'cores busy':>11}{'worker RSS MiB':>18}{'SLAM RSS':>10}"
    print(f"{args.recordings} recordings x {args.frames} frames; {os.cpu_count()} cores shared with other jobs")
    print(head)
    for r in rows:
        rss = "/".join(f"{v:.0f}" for v in r["peak_rss_mb_per_worker"])
        print(f"{r['label']:<10}{r['workers']:>8}{r['recordings_per_min']:>9.1f}{r['frames_per_s']:>10.2f}"
              f"{r['batch_wall_s']:>8.1f}{r['process_wall_s']:>9.1f}{r.get('speedup', float('nan')):>9.2f}"
              f"{r.get('parallel_efficiency', float('nan')):>8.2f}"
              f"{'n/a' if r['cores_busy'] is None else format(r['cores_busy'], '.2f'):>11}{rss:>18}"
              f"{r['peak_orbslam3_rss_mb']:>10.0f}")
    harness.write_results(args.out, {
        "what": "slz detect over a batch of synthetic recordings (benchmarks/batch.py)",
        "recordings": args.recordings, "frames_each": args.frames, "synth_s": round(synth_s, 1), "runs": rows})


if __name__ == "__main__":
    main()
