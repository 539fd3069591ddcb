"""Mask quality against ground truth: precision, recall and IoU of fuzzy and Bayes on synth scenes.

    python benchmarks/masks.py [RECORDING.mcap ...] [--set key=value ...] [--frames N]

Without recordings it renders one short hover flight per scene with `slz synth` into a temp
folder. Per recording and method it prints micro-averaged precision / recall / IoU of the
landing mask against the ground-truth safe mask, and the safe fraction of each; writes
benchmarks/results/masks.json. Poses are not used (gravity from the mount, as on a first
frame before SLAM), so this isolates maps + fusion + mask.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import harness
import numpy as np
from flights import render  # benchmarks/flights.py (the script's folder is on sys.path)

from slzcli.config import load_config
from slzcli.evaluate.safety import mask_counts, total
from slzcli.scoring import MaskParams, get_scorer, score_frame
from slzcli.sources import open_recording
from slzcli.synth.groundtruth import load_ground_truth
from slzcli.terrain.maps import MapParams, frame_maps


def evaluate(path: Path, overrides: list[str], methods: tuple[str, ...]) -> dict[str, dict]:
    config = load_config(None, overrides)
    truth = load_ground_truth(path)
    scorers = {m: get_scorer(config.scoring, config.mask, m) for m in methods}
    counts: dict[str, list] = {m: [] for m in methods}
    safe_fraction: dict[str, list[float]] = {m: [] for m in methods}
    truth_fraction = []
    with open_recording(path, config) as rec:
        for frame in rec.frames():
            maps = frame_maps(frame, MapParams.of(config))
            gt = truth.safe_mask(frame.stamp_ns, tolerance_ns=round(config.synth.ground_truth.stamp_tolerance_ms * 1e6))
            truth_fraction.append(float(gt.mean()))
            for m, scorer in scorers.items():
                sm = score_frame(scorer, maps, frame.depth_m, frame.intrinsics, MaskParams.of(config))
                counts[m].append(mask_counts(sm.mask, gt))
                safe_fraction[m].append(float(sm.mask.mean()))
    out = {}
    for m in methods:
        out[m] = {**total(counts[m]).as_dict(), "mask_safe_fraction": float(np.mean(safe_fraction[m])),
                  "true_safe_fraction": float(np.mean(truth_fraction)), "frames": len(counts[m])}
    return out


def main() -> None:
    ap = harness.parser(__doc__, "masks")
    ap.add_argument("recordings", nargs="*", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--methods", default="fuzzy,bayes")
    args = ap.parse_args()
    methods = tuple(args.methods.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        recordings = args.recordings or render(Path(tmp), args.frames)
        results = {}
        print(f"{'recording':<18} {'method':<6} {'precision':>9} {'recall':>7} {'IoU':>6} {'mask %':>7} {'true %':>7}")
        for path in recordings:
            res = evaluate(path, args.overrides, methods)
            results[path.stem] = res
            for m, r in res.items():
                f = lambda v: "  n/a" if v is None else f"{v:.3f}"  # noqa: E731
                print(f"{path.stem:<18} {m:<6} {f(r['precision']):>9} {f(r['recall']):>7} {f(r['iou']):>6} "
                      f"{100 * r['mask_safe_fraction']:>6.1f} {100 * r['true_safe_fraction']:>6.1f}")
    harness.write_results(args.out, {"overrides": args.overrides, "results": results})


if __name__ == "__main__":
    main()
