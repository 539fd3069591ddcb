"""What the landing map costs in results.mcap: CPU ms and bytes per detection of /slz/landing_map.

    python benchmarks/landing_grid.py [--frames N] [--repeats R]

1. In a run: `slz detect --method fused` on a small `slz synth` recording (clear_field, gaussian sensor,
   odometry), with the two steps timed where they run (CPU time of their thread, so a busy machine
   changes little): ``landing_grid`` (the detection's cells cropped and converted, in the background writer
   when it writes them)
   and ``write_landing_grid`` (the Grid message built, serialised and handed to the MCAP writer, in the
   background writer), per detection; and the message's bytes.
2. Sizes: a synthetic grid of the square a detection judges at 10 m (347 x 347 cells of 8.2 cm) and of
   the whole 40 m window (488 x 488), each ``--repeats`` times: CPU ms of the message and its
   serialisation (median), its bytes raw and after LZ4 (results.mcap's chunk compression).

Writes benchmarks/results/landing_grid.json.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import harness
import numpy as np

from slzcli import api
from slzcli.config import load_config
from slzcli.methods import fused
from slzcli.outputs import results_mcap
from slzcli.types import LandingGrid

NAMES = ("unseen", "unsafe", "undecided", "safe")


def timed(store: list[float], fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*a: Any, **k: Any) -> Any:
        t0 = time.thread_time()
        out = fn(*a, **k)
        store.append((time.thread_time() - t0) * 1e3)
        return out
    return wrapper


def toy(n: int, seed: int = 0) -> LandingGrid:
    rng = np.random.default_rng(seed)
    verdict = rng.integers(0, 4, (n, n)).astype(np.uint8)
    f = (rng.random((n, n))).astype(np.float32)
    return LandingGrid((0.0, 0.0), 0.082, 0, 0, 0, verdict, NAMES, f, f - 8.0, f * 0.01, f * 20)


def in_run(frames: int) -> dict[str, Any]:
    crop: list[float] = []
    write: list[float] = []
    sizes: list[int] = []
    orig_grid, orig_write = fused.landing_grid, results_mcap.ResultsMcap.write_landing_grid

    def write_and_size(self: results_mcap.ResultsMcap, grid: LandingGrid) -> None:
        sizes.append(grid.shape[0] * grid.shape[1] * results_mcap.GRID_FIELDS.itemsize)
        orig_write(self, grid)

    fused.landing_grid = timed(crop, orig_grid)
    results_mcap.ResultsMcap.write_landing_grid = timed(write, write_and_size)  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory(prefix="slz-bench-") as tmp:
            rec = Path(tmp) / "clear.mcap"
            from click.testing import CliRunner

            from slzcli.cli import main
            res = CliRunner().invoke(main, ["synth", "clear_field", "-o", str(rec), "--frames", str(frames),
                                            "--set", "synth.sensor.model=gaussian"])
            assert res.exit_code == 0, res.output
            cfg = load_config(overrides=["slam.backend=odometry"])
            result = api.detect(rec, cfg, Path(tmp) / "run", method="fused")
            stage = result.summary.timings_ms
    finally:
        fused.landing_grid = orig_grid
        results_mcap.ResultsMcap.write_landing_grid = orig_write  # type: ignore[method-assign]
    return {"detections": len(crop), "landing_grid_ms_median": statistics.median(crop),
            "write_landing_grid_ms_median": statistics.median(write[:-1] or write),
            "final_write_ms": write[-1], "message_bytes_median": statistics.median(sizes),
            "stage_medians_ms": stage}


def sizes(repeats: int) -> list[dict[str, Any]]:
    import lz4.frame  # type: ignore[import-untyped]

    from slzcli.outputs.recording import RecordingWriter

    out = []
    with tempfile.TemporaryDirectory(prefix="slz-bench-") as tmp:
        w = RecordingWriter(Path(tmp) / "x.mcap", "mcap")
        results_mcap.register_foxglove(w.typestore)
        for n in (347, 488):
            grid, ms, data = toy(n), [], b""
            for _ in range(repeats):
                t0 = time.thread_time()
                msg = results_mcap.grid_message(w, grid, "map")
                data = bytes(w.typestore.serialize_cdr(msg, results_mcap.GRID))
                ms.append((time.thread_time() - t0) * 1e3)
            out.append({"cells": f"{n} x {n}", "ms_median": statistics.median(ms), "bytes": len(data),
                        "lz4_bytes": len(lz4.frame.compress(data))})
    return out


def main() -> None:
    ap = harness.parser(__doc__, "landing_grid")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    run = in_run(args.frames)
    table = sizes(args.repeats)
    print(f"in a run ({run['detections']} detections): landing_grid {run['landing_grid_ms_median']:.2f} ms, "
          f"message + write {run['write_landing_grid_ms_median']:.2f} ms (CPU, median), the run's last "
          f"{run['final_write_ms']:.2f} ms; {run['message_bytes_median'] / 1e6:.2f} MB of cells a detection")
    print("| cells | ms (CPU, median) | bytes | after LZ4 |\n|---|---|---|---|")
    for r in table:
        print(f"| {r['cells']} | {r['ms_median']:.2f} | {r['bytes']:,} | {r['lz4_bytes']:,} |")
    harness.write_results(args.out, {"run": run, "sizes": table}, indent=1)


if __name__ == "__main__":
    main()
