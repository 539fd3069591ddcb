"""Monte Carlo over start positions, pose noise and gusts: batched simulations in chunks, one summary."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any

import numpy as np

from slzcli import bounds
from slzcli.config import Config, ControlCfg
from slzcli.control.simulate import SimResult, Target, sample_starts, simulate

PERCENTILES = (5, 50, 95)
SUMMARY_FIELDS = ("stabilisation_time_s", "settling_time_s", "switch_time_s", "final_feature_error_px",
                  "touchdown_error_m", "landing_time_s", "max_tilt_deg", "approach_time_s", "recoveries")


def batch_control(c: ControlCfg) -> ControlCfg:
    """The ``control`` section with its noise, wind.gust_m_s and the switch threshold from its montecarlo block."""
    mc = c.montecarlo
    noise = replace(c.noise, position_sigma_m=mc.position_sigma_m, attitude_sigma_deg=mc.attitude_sigma_deg,
                    velocity_sigma_m_s=mc.velocity_sigma_m_s, position_drift_m_sqrt_s=mc.position_drift_m_sqrt_s,
                    yaw_drift_deg_sqrt_s=mc.yaw_drift_deg_sqrt_s)
    return replace(c, noise=noise, wind=replace(c.wind, gust_m_s=mc.gust_m_s),
                   sim=replace(c.sim, switch_error_px=mc.switch_error_px))


def run(target: Target, base_start_world: np.ndarray, runs: int, seed: int, config: Config, *,
        first_run: int = 0) -> SimResult:
    """Runs ``first_run`` .. ``first_run + runs - 1`` of the batch ``seed`` around ``base_start_world``.

    Starts are scattered and flown under the batch noise and gusts. Run i depends only on
    (seed, i), so a batch run in chunks (``first_run`` = 0, 250, 500, ...) equals it run at once.
    """
    starts = sample_starts(base_start_world, runs, config.control.montecarlo, seed, first_run)
    batch = replace(config, control=batch_control(config.control))
    return simulate(target, starts, batch, log=False, seed=seed, first_run=first_run)


ChunkSink = Callable[[SimResult, int], None]
Progress = Callable[[int, int, int], None]


def run_chunked(target: Target, base_start_world: np.ndarray, runs: int, seed: int, config: Config, *,
                on_chunk: ChunkSink | None = None, progress: Progress | None = None) -> SimResult:
    """All ``runs`` in chunks of ``control.montecarlo.chunk_runs``, after the batch's size passed its bounds.

    Memory is one chunk's state and noise block (the whole batch at once needed runs x 256 steps
    x 15 normals x 8 B: 6 GB for 100,000 runs) plus each run's outcome (~0.2 KB, no per-step
    data). ``on_chunk(result, first_run)`` gets each chunk as it finishes (the CSV rows are written
    there), ``progress(done, runs, successes)`` after it. Chunking does not change a run: run i
    depends only on (seed, i).
    """
    bounds.check(bounds.simulation_sizes(config, runs))
    chunk = config.control.montecarlo.chunk_runs
    parts: list[SimResult] = []
    successes = 0
    for first in range(0, runs, chunk):
        part = run(target, base_start_world, min(chunk, runs - first), seed, config, first_run=first)
        if on_chunk is not None:
            on_chunk(part, first)
        parts.append(part)
        successes += int(part.success.sum())
        if progress is not None:
            progress(first + len(part.reason), runs, successes)
    return concatenate(parts)


def concatenate(parts: list[SimResult]) -> SimResult:
    """The per-run arrays of consecutive chunks as one result (no per-step log)."""
    per_run = [f.name for f in fields(SimResult) if f.name not in ("sim_time_s", "log")]
    joined = {name: np.concatenate([getattr(p, name) for p in parts]) for name in per_run}
    return SimResult(**joined, sim_time_s=max((p.sim_time_s for p in parts), default=0.0), log=None)


def summarise(result: SimResult) -> dict[str, Any]:
    """Success rate, reasons, and percentiles (over finished values) of the per-run metrics."""
    n = len(result.reason)
    out: dict[str, Any] = {"runs": n, "success_rate": float(result.success.mean()) if n else math.nan,
                           "successes": int(result.success.sum()),
                           "reasons": dict(Counter(str(r) for r in result.reason)),
                           "failures": dict(Counter(str(r) for r, ok in zip(result.reason, result.success, strict=True)
                                                    if not ok))}
    for name in SUMMARY_FIELDS:
        vals = np.asarray(getattr(result, name), float)
        vals = vals[np.isfinite(vals)]
        out[name] = {"count": int(vals.size), "mean": float(vals.mean()) if vals.size else None,
                     **{f"p{p}": (float(np.percentile(vals, p)) if vals.size else None) for p in PERCENTILES}}
    # Where the UAV really touches down around the site (every touch-down, inside the radius or not):
    # `slz detect --set uav.touchdown_dispersion_m=<this>` adds it to the site's clearance (README, METHOD 2.4.3).
    out["landing_dispersion_p95_m"] = out["touchdown_error_m"]["p95"]
    return out


def table(summary: dict[str, Any]) -> str:
    """The aggregate as a small fixed-width text table."""
    lines = [f"runs {summary['runs']}  success {summary['successes']} ({100 * summary['success_rate']:.1f} %)  "
             f"failures {summary['failures'] or 'none'}",
             f"{'metric':<24}{'n':>6}{'mean':>10}" + "".join(f"{'p' + str(p):>10}" for p in PERCENTILES)]
    for name in SUMMARY_FIELDS:
        s = summary[name]
        cells = [s["mean"], *(s[f"p{p}"] for p in PERCENTILES)]
        lines.append(f"{name:<24}{s['count']:>6}" + "".join(f"{'-' if v is None else format(v, '.3f'):>10}"
                                                             for v in cells))
    p95 = summary.get("landing_dispersion_p95_m")
    if p95 is not None:
        margin = math.ceil(p95 * 100) / 100
        lines.append(f"landing dispersion p95 {p95:.3f} m: `slz detect --set uav.touchdown_dispersion_m={margin:g}` "
                     "adds that much to uav.margin_m around a site")
    return "\n".join(lines)
