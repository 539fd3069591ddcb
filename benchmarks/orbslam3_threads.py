"""Where ORB-SLAM3's run-to-run differences come from: the same decoded frames, tracked N times.

Run: .venv/bin/python benchmarks/orbslam3_threads.py RECORDING [--runs 8] [--pause S]
     setarch $(uname -m) -R .venv/bin/python benchmarks/orbslam3_threads.py ...   # without ASLR

The frames are decoded once and handed to a fresh ``OrbSlam3Backend`` (worker process) per run,
so slz's side is identical bit for bit; ``--pause`` sleeps after every frame so that ORB-SLAM3's
LocalMapping and LoopClosing threads are idle before the next frame is tracked. Prints a digest
of each run's poses and how many distinct ones there were (README "Reproducibility"); writes them to
benchmarks/results/orbslam3_threads.json.
"""

from __future__ import annotations

import hashlib
import time

import harness
import numpy as np

from slzcli.config import load_config
from slzcli.slam.orbslam3 import OrbSlam3Backend
from slzcli.sources import open_recording


def main() -> None:
    ap = harness.parser(__doc__, "orbslam3_threads")
    ap.add_argument("recording")
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--pause", type=float, default=0.0, help="seconds to sleep after each frame")
    args = ap.parse_args()
    cfg = load_config()
    with open_recording(args.recording, cfg) as rec:
        frames = list(rec.frames())
    digests = []
    for r in range(args.runs):
        backend = OrbSlam3Backend(cfg.slam)
        poses = []
        for f in frames:
            res = backend.track(f)
            poses.append(np.full((4, 4), np.nan) if res.T_world_camera is None else res.T_world_camera)
            if args.pause:
                time.sleep(args.pause)
        backend.close()
        digests.append(hashlib.sha256(np.asarray(poses).tobytes()).hexdigest()[:12])
        print(r, digests[-1], "last position", np.round(poses[-1][:3, 3], 6), flush=True)
    print(f"distinct pose sequences: {len(set(digests))} of {args.runs}")
    harness.write_results(args.out, {"recording": str(args.recording), "runs": args.runs, "pause_s": args.pause,
                                     "frames": len(frames), "pose_digests": digests,
                                     "distinct": len(set(digests))})


if __name__ == "__main__":
    main()
