"""Run-to-run spread of `slz detect`: the same recording and config, run N times (issue 15).

Run: .venv/bin/python benchmarks/reproducibility.py [--runs 8] [--frames 20] [--scenes parking_lot,...] [--out F]
Prints a table and writes benchmarks/results/reproducibility.json.

Each run is a fresh `python -m slzcli.cli detect --json` process (as a user runs it), per SLAM
backend: ORB-SLAM3 (`--runs` times), the built-in odometry and the recorded ground-truth poses
(3 times each). Reported per scene and backend: how many distinct trajectory.tum / sites.csv /
landing.json (without its timings) byte strings the runs gave, the SLAM ATE (min, max), the
committed site's status and its largest distance from the runs' median site, and the mask
precision / recall range. The odometry and recorded backends must give one of each.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import harness
import numpy as np


def slz(*args: str) -> subprocess.CompletedProcess:
    return harness.slz(*args, check=False)


def digest(path: Path, drop: str | None = None) -> str:
    """sha256 of a file; of a JSON file without one top-level key (landing.json's timings)."""
    if drop is None:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    doc = json.loads(path.read_text())
    doc.pop(drop, None)
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def one_run(rec: Path, run: Path, backend: str) -> dict:
    extra = ["--set", "sources.use_ground_truth_pose=true"] if backend == "recorded" else []
    res = slz("detect", str(rec), "-o", str(run), "--json", "--force", "--set", f"slam.backend={backend}", *extra)
    if res.returncode != 0:
        raise SystemExit(f"slz detect failed: {res.stderr}")
    s = json.loads(res.stdout)
    gt = s.get("ground_truth") or {}
    mask = gt.get("mask") or {}
    return {"status": s["status"], "site_world": s.get("site_world"), "keyframes": s["keyframes"],
            "detections": s["detections"], "ate_m": gt.get("slam_ate_rmse_m"), "precision": mask.get("precision"),
            "recall": mask.get("recall"), "trajectory": digest(run / "trajectory.tum"),
            "sites": digest(run / "sites.csv"), "landing": digest(run / "landing.json", drop="timings_ms")}


def spread(runs: list[dict]) -> dict:
    def rng(key: str) -> list[float] | None:
        v = [r[key] for r in runs if r[key] is not None]
        return [round(min(v), 5), round(max(v), 5)] if v else None

    sites = np.array([r["site_world"] for r in runs if r["site_world"] is not None], float).reshape(-1, 3)
    far = float(np.max(np.linalg.norm(sites - np.median(sites, axis=0), axis=1))) if len(sites) else None
    return {"runs": len(runs), "distinct_trajectory": len({r["trajectory"] for r in runs}),
            "distinct_sites_csv": len({r["sites"] for r in runs}),
            "distinct_landing": len({r["landing"] for r in runs}),
            "status": sorted({r["status"] for r in runs}), "with_site": len(sites),
            "site_max_from_median_m": None if far is None else round(far, 4), "ate_m": rng("ate_m"),
            "precision": rng("precision"), "recall": rng("recall"), "keyframes": rng("keyframes"),
            "detections": rng("detections")}


def main() -> None:
    ap = harness.parser(__doc__, "reproducibility")
    ap.add_argument("--runs", type=int, default=8, help="ORB-SLAM3 runs per scene (odometry, recorded: 3)")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--scenes", default="parking_lot,playground,office")
    args = ap.parse_args()
    out: dict = {"command": " ".join(sys.argv), "frames": args.frames, "scenes": {}}
    with tempfile.TemporaryDirectory(prefix="slz-repro-") as tmp:
        for scene in args.scenes.split(","):
            rec = Path(tmp) / f"{scene}.mcap"
            res = slz("synth", scene, "-o", str(rec), "--frames", str(args.frames))
            if res.returncode != 0:
                raise SystemExit(res.stderr)
            out["scenes"][scene] = {}
            for backend, n in (("orbslam3", args.runs), ("odometry", 3), ("recorded", 3)):
                runs = [one_run(rec, Path(tmp) / f"{scene}_{backend}", backend) for _ in range(n)]
                out["scenes"][scene][backend] = {"spread": spread(runs), "runs": runs}
                s = out["scenes"][scene][backend]["spread"]
                print(f"{scene:12s} {backend:9s} runs {s['runs']}: distinct trajectory/sites/landing "
                      f"{s['distinct_trajectory']}/{s['distinct_sites_csv']}/{s['distinct_landing']}, "
                      f"ATE {s['ate_m']} m, site max from median {s['site_max_from_median_m']} m "
                      f"({s['with_site']} with a site), recall {s['recall']}", flush=True)
    harness.write_results(args.out, out, indent=1)


if __name__ == "__main__":
    main()
