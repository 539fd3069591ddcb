"""What report.html costs at the end of a ``slz detect`` run: ms against the run's wall time.

    python benchmarks/detect_report.py [--frames N] [--repeats R] [--set k=v ...]

Renders one ``slz synth`` recording (clear_field, hover, gaussian sensor, 640x480) and runs
``slz detect`` on it in this process at ``--outputs maps`` (the default) and ``summary``. Inside
each run the report builder (``run_folder.write_detect_report``) is called R times on the same
inputs (the finished run's), each timed; the page the run keeps is the last one. Prints per level
the detections, the report's median and max ms, the run's wall time without the extra calls and
the report's share of it. Writes benchmarks/results/detect_report.json.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import harness

from slzcli.config import load_config
from slzcli.outputs import run_folder
from slzcli.pipeline import RunOptions, detect_recording
from slzcli.synth.record import SynthOptions, synthesize

BASE = ("synth.sensor.model=gaussian", "slam.backend=odometry")


def run_level(rec: Path, out: Path, level: str, repeats: int, overrides: list[str]) -> dict[str, Any]:
    config = load_config(None, [*BASE, *overrides, f"output.level={level}"])
    samples: list[float] = []
    original = run_folder.write_detect_report

    def timed(*a: Any, **kw: Any) -> Path:
        path = None
        for _ in range(repeats):
            t0 = time.perf_counter()
            path = original(*a, **kw)
            samples.append(1e3 * (time.perf_counter() - t0))
        assert path is not None
        return path

    run_folder.write_detect_report = timed
    try:
        t0 = time.perf_counter()
        s = detect_recording(rec, config, out, RunOptions(force=True))
        wall = time.perf_counter() - t0 - 1e-3 * sum(samples[1:])   # the run with one report, as a user has it
    finally:
        run_folder.write_detect_report = original
    med = statistics.median(samples)
    return {"level": level, "detections": s.detections, "report_median_ms": round(med, 1),
            "report_max_ms": round(max(samples), 1), "run_wall_s": round(wall, 2),
            "report_share_pct": round(100 * med * 1e-3 / wall, 2),
            "report_bytes": (out / "report.html").stat().st_size, "samples_ms": [round(v, 1) for v in samples]}


def main() -> None:
    ap = harness.parser(__doc__, "detect_report")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5, help="report builds per run (median kept)")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "flight.mcap"
        synthesize(rec, SynthOptions("clear_field", args.frames, 10.0, "hover", 0, None),
                   load_config(None, [*BASE, *args.overrides]))
        for level in ("maps", "summary"):
            rows.append(run_level(rec, Path(tmp) / f"run_{level}", level, args.repeats, args.overrides))
    print(f"{'level':<8} {'det':>4} {'report ms (med)':>16} {'max ms':>7} {'run s':>7} {'share %':>8} {'bytes':>9}")
    for r in rows:
        print(f"{r['level']:<8} {r['detections']:>4} {r['report_median_ms']:>16.1f} {r['report_max_ms']:>7.1f} "
              f"{r['run_wall_s']:>7.2f} {r['report_share_pct']:>8.2f} {r['report_bytes']:>9,}")
    harness.write_results(args.out, {"frames": args.frames, "repeats": args.repeats, "base": list(BASE),
                                     "overrides": args.overrides, "levels": rows})


if __name__ == "__main__":
    main()
