"""`slz detect` on every synth scene: per-stage time, and the site against ground truth.

    python benchmarks/detect.py [RECORDING.mcap ...] [--frames N] [--method fuzzy|bayes] [--set k=v ...]

Without recordings it renders one hover flight per scene with `slz synth` into a temp
folder. Per scene: frames, detections, median ms per stage (maps, score, mask, slam, select;
PNG writing is timed apart as `write`), mask precision / recall / IoU, whether the committed
site is truly safe, its clearance to the nearest hazard, and its distance to the centre of
the largest truly safe area in view. Writes benchmarks/results/detect.json.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import harness
from flights import render  # benchmarks/flights.py (the script's folder is on sys.path)

from slzcli.config import load_config
from slzcli.outputs.summary_json import summary_json
from slzcli.pipeline import RunOptions, detect_recording


def main() -> None:
    ap = harness.parser(__doc__, "detect")
    ap.add_argument("recordings", nargs="*", type=Path)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--method", default="fuzzy")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    config = load_config(None, args.overrides)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        recordings = args.recordings or render(Path(tmp), args.frames)
        head = (f"{'scene':<14} {'frames':>6} {'det':>4} {'maps':>6} {'score':>6} {'mask':>5} {'slam':>6} "
                f"{'select':>6} {'write':>6}  {'prec':>5} {'rec':>5}  {'site':<12} {'safe':>5} {'clear m':>7} "
                f"{'to best m':>9}")
        print(head)
        for path in recordings:
            run = Path(tmp) / f"run_{path.stem}"
            result = detect_recording(path, config, run, RunOptions(force=True, method=args.method))
            s: dict[str, Any] = summary_json(result)
            timing = json.loads((run / "run.json").read_text())["timings"]
            gt = s.get("ground_truth") or {}
            mask, site = gt.get("mask") or {}, gt.get("site") or {}
            t = s["timings_ms"]
            write = timing.get("write", {}).get("median_ms", float("nan"))
            rows[path.stem] = {**s, "write_median_ms": write}
            f = lambda v, p=3: "  n/a" if v is None else f"{v:.{p}f}"  # noqa: E731
            print(f"{path.stem:<14} {s['frames']:>6} {s['detections']:>4} {t['maps']:>6.1f} {t[args.method]:>6.1f} "
                  f"{t['mask']:>5.1f} {t['slam']:>6.1f} {t['select']:>6.1f} {write:>6.1f}  "
                  f"{f(mask.get('precision'), 2):>5} {f(mask.get('recall'), 2):>5}  {s['status']:<12} "
                  f"{site.get('safe', '-')!s:>5} {f(site.get('clearance_m'), 2):>7} "
                  f"{f(site.get('to_best_centre_m'), 2):>9}")
    harness.write_results(args.out, {"method": args.method, "overrides": args.overrides, "runs": rows})


if __name__ == "__main__":
    main()
