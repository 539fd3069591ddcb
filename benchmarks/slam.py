"""SLAM backends: accuracy (ATE, RPE), map points per keyframe and speed; vocabulary build cost.

Flights: the analytic rendered flights of tests/slam_flight.py ('line' 100 frames 480x360;
'out_back' 100 frames 320x240 with a textureless stretch) and the 10 real RealSense frames
(../shared/data/realsense_floor, no poses: tracked points and rate only). Frame rate counts
tracking only (frames already in memory). Prints a table; writes results/slam.json.
Also any `slz synth` recordings given as arguments (true poses from /ground_truth/camera_pose;
the recorded backend replays them, as a check that ATE is then 0).
Usage: .venv/bin/python benchmarks/slam.py [SYNTH.mcap ...] [--out JSON]
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np

harness.use_test_helpers()
import slam_flight  # noqa: E402

from slzcli.config import load_config  # noqa: E402
from slzcli.evaluate.slam import ate, rpe  # noqa: E402
from slzcli.slam import TrackingState, TrackResult, get_backend  # noqa: E402
from slzcli.slam.orbslam3 import available  # noqa: E402
from slzcli.slam.vocabulary import DEFAULT_VOCABULARY, frame_descriptors, train_vocabulary, vocabulary_text  # noqa: E402
from slzcli.types import Frame, Intrinsics  # noqa: E402

REALSENSE = harness.REALSENSE


def imread(path: Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise FileNotFoundError(f"{path}: missing or not an image OpenCV reads")
    return img


def realsense_frames() -> list[Frame]:
    cam = json.loads((REALSENSE / "cam_params_realsense.json").read_text())
    k = cam["intrinsic_matrix"]  # column-major
    intr = Intrinsics(k[0], k[4], k[6], k[7], cam["width"], cam["height"])
    out = []
    for i, p in enumerate(sorted((REALSENSE / "color").glob("*.png"))):
        rgb = cv2.cvtColor(imread(p), cv2.COLOR_BGR2RGB)
        d = imread(REALSENSE / "depth" / p.name, cv2.IMREAD_UNCHANGED).astype(np.float32) * 0.001
        d[d == 0] = np.nan
        out.append(Frame(i, 1_700_000_000_000_000_000 + i * 100_000_000, rgb, d, intr))
    return out


def synth_frames(path: str) -> tuple[list[Frame], list[np.ndarray | None]]:
    """Frames of a `slz synth` recording with their true poses (from the ground-truth topic)."""
    from slzcli.sources import open_recording

    config = load_config(overrides=["sources.use_ground_truth_pose=true",
                                    "sources.topics.pose=/ground_truth/camera_pose"])
    with open_recording(path, config) as rec:
        frames = list(rec.frames())
    truth = [f.T_world_camera for f in frames]
    return frames, truth


def run(backend: str, frames: list[Frame], truth: Sequence[np.ndarray | None] | None) -> dict[str, Any]:
    config = load_config(overrides=[f"slam.backend={backend}"])
    results: list[TrackResult] = []
    kf_points: list[int] = []
    with get_backend(config.slam) as b:
        t_first: float | None = None
        t0 = time.perf_counter()
        for f in frames:
            results.append(b.track(f))
            if t_first is None:
                t_first = time.perf_counter() - t0  # includes worker start / vocabulary load
            kf = b.keyframe()
            if kf is not None:
                kf_points.append(len(kf))
        total = time.perf_counter() - t0
    if t_first is None:
        raise ValueError(f"{backend}: no frames to track")
    rest = total - t_first
    row: dict[str, Any] = {
        "backend": backend, "frames": len(frames),
        "ok": sum(r.state is TrackingState.OK for r in results),
        "lost": sum(r.state is TrackingState.LOST for r in results),
        "segments": len({r.segment for r in results}),
        "keyframes": len(kf_points),
        "points_per_keyframe": float(np.mean(kf_points)) if kf_points else 0.0,
        "tracked_points_per_frame": float(np.mean([r.tracked_points for r in results])),
        "first_frame_s": t_first,
        "fps": (len(frames) - 1) / rest if rest > 0 else float("nan"),
        "ms_per_frame": 1e3 * rest / max(1, len(frames) - 1),
    }
    if truth is not None:
        poses = [r.T_world_camera for r in results]
        a, r = ate(poses, truth), rpe(poses, truth)
        row.update(ate_rmse_m=a.rmse_m, ate_max_m=a.max_m, ate_frames=a.n, rpe_trans_m=r.trans_rmse_m,
                   rpe_rot_deg=r.rot_rmse_deg)
    return row


def main() -> None:
    ap = harness.parser(__doc__, "slam")
    ap.add_argument("recordings", nargs="*", help="slz synth recordings (true poses: the recorded backend too)")
    args = ap.parse_args()
    flights: dict[str, tuple[list[Frame], Sequence[np.ndarray | None] | None]] = {
        "line_480x360": slam_flight.render_flight(100, "line", width=480, height=360, supersample=1),
        "out_back_320x240": slam_flight.render_flight(100, "out_back", width=320, height=240, supersample=1),
        "realsense_floor": (realsense_frames(), None),
    }
    backends = ["odometry"] + (["orbslam3"] if available() else [])
    rows = []
    for path in args.recordings:
        flights[f"synth:{Path(path).stem}"] = synth_frames(path)
    from dataclasses import replace
    for name, (frames, truth) in flights.items():
        for backend in backends + (["recorded"] if name.startswith("synth:") else []):
            fed = frames if backend == "recorded" else [replace(f, T_world_camera=None) for f in frames]
            row = run(backend, fed, truth)
            row["flight"] = name
            rows.append(row)
    # vocabulary build: descriptors of the line flight, the default k and L
    cfg = load_config().slam
    t0 = time.perf_counter()
    docs = frame_descriptors(flights["line_480x360"][0], cfg.orb)
    t1 = time.perf_counter()
    vocab = train_vocabulary(docs, cfg.vocab.k, cfg.vocab.levels, cfg.vocab.iterations, cfg.vocab.seed)
    t2 = time.perf_counter()
    vocab_row = {"k": cfg.vocab.k, "levels": cfg.vocab.levels, "frames": len(docs),
                 "descriptors": int(sum(len(d) for d in docs)), "words": vocab.n_words,
                 "extract_s": t1 - t0, "train_s": t2 - t1, "text_bytes": len(vocabulary_text(vocab)),
                 "default_file_bytes": DEFAULT_VOCABULARY.stat().st_size}

    head = f"{'flight':26} {'backend':9} {'ok/lost':>8} {'seg':>3} {'KFs':>4} {'pts/KF':>7} {'ATE cm':>7} " \
           f"{'RPE cm':>7} {'RPE deg':>7} {'ms/frame':>8} {'fps':>6}"
    print(head)
    print("-" * len(head))
    for r in rows:
        ate_s = f"{100 * r['ate_rmse_m']:7.2f}" if "ate_rmse_m" in r else f"{'-':>7}"
        rpe_s = f"{100 * r['rpe_trans_m']:7.2f} {r['rpe_rot_deg']:7.3f}" if "rpe_trans_m" in r else f"{'-':>7} {'-':>7}"
        print(f"{r['flight']:26} {r['backend']:9} {r['ok']:>4}/{r['lost']:<3} {r['segments']:>3} {r['keyframes']:>4} "
              f"{r['points_per_keyframe']:7.0f} {ate_s} {rpe_s} {r['ms_per_frame']:8.1f} {r['fps']:6.1f}")
    print(f"\nvocabulary k={vocab_row['k']} L={vocab_row['levels']}: {vocab_row['words']} words from "
          f"{vocab_row['descriptors']} descriptors / {vocab_row['frames']} frames; ORB {vocab_row['extract_s']:.2f} s, "
          f"training {vocab_row['train_s']:.2f} s, {vocab_row['text_bytes'] / 1024:.0f} KiB "
          f"(packaged default {vocab_row['default_file_bytes'] / 1024:.0f} KiB)")
    harness.write_results(args.out, {"rows": rows, "vocabulary": vocab_row})


if __name__ == "__main__":
    main()
