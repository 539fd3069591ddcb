"""IBVS landing robustness: the Monte Carlo targets, each add-on against the paper's law, a gust x noise sweep.

Run: .venv/bin/python benchmarks/ibvs_robustness.py [--runs 100] [--sweep-runs 100] [--seed 7]
Prints tables, writes benchmarks/results/ibvs_robustness.json (``--out``) and, with the sweep, the plot
beside it (same name, .png). The committed results: ibvs_robustness.json (nominal, targets, ablation;
``--sections nominal,targets,ablation``) and ibvs_sweep.json / ibvs_sweep.png (``--sections sweep
--out benchmarks/results/ibvs_sweep.json``).

1. Targets (issue 20): success within ``control.sim.success_radius_m`` from the default start
   (``control.sim.start_offset_m``, the paper's scenario-1 geometry) and from each paper scenario
   start with the start scatter, at the ``control.montecarlo`` noise and 2 m/s gusts; nominal
   stabilisation from the four paper starts with the tuned and the paper's Table 3 gains.
2. Ablation: the paper's law alone (Table 3 gains, no approach, no disturbance observer) and each
   add-on switched on by itself, from the default start.
3. Sweep: gust std 0-4 m/s x pose-noise scale (0.5, 1, 2, 4 x the montecarlo defaults).
Each Monte Carlo cell is runs 0..N-1 of one seed (run i depends only on (seed, i)).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import harness  # noqa: E402
import numpy as np  # noqa: E402

from slzcli.config import Config, load_config  # noqa: E402
from slzcli.control import montecarlo  # noqa: E402
from slzcli.control.simulate import SCENARIOS, Target, simulate, start_from_offsets  # noqa: E402
from slzcli.landing.corners import square_corners  # noqa: E402

# Sites for the paper's starts (benchmarks/ibvs.py, tests/control/test_control_simulate.py): only scenario 1's
# site (3.24, 3.32, 0.4) is published; the others are chosen in view of each start (project).
SITES = {1: (2.0, 1.5, 0.3), 2: (-1.5, 10.0, 0.0), 3: (1.5, -1.0, 0.0), 4: (-1.0, 2.0, 0.0)}
PAPER_SITE_1 = (3.24, 3.32, 0.4)
GUSTS = (0.0, 1.0, 2.0, 3.0, 4.0)
NOISE_SCALES = (0.5, 1.0, 2.0, 4.0)


def target_at(center: tuple[float, ...], config: Config) -> Target:
    c = np.array(center, float)
    l1, l2 = config.uav.footprint_m  # the config's (L1, L2)
    return Target(c, square_corners(c, (l1, l2)))


def with_sets(config: Config, sets: list[str]) -> Config:
    return load_config(None, sets) if sets else config


def mc(config: Config, site: tuple[float, ...], base: np.ndarray, runs: int, seed: int) -> dict[str, Any]:
    target = target_at(site, config)
    w0 = time.perf_counter()
    r = montecarlo.run(target, base, runs, seed, config)
    s = montecarlo.summarise(r)
    return {"success_rate": s["success_rate"], "failures": s["failures"],
            "touchdown_error_p50_m": s["touchdown_error_m"]["p50"],
            "touchdown_error_p95_m": s["touchdown_error_m"]["p95"],
            "touchdown_error_max_m": float(np.nanmax(r.touchdown_error_m)) if np.isfinite(r.touchdown_error_m).any()
            else None,
            "landing_time_p50_s": s["landing_time_s"]["p50"], "approach_runs": int((r.approach_time_s > 0).sum()),
            "recoveries": int(r.recoveries.sum()), "switch_error_p95_px": s["final_feature_error_px"]["p95"],
            "wall_s": time.perf_counter() - w0}


def starts_of(config: Config) -> list[tuple[str, tuple[float, ...], np.ndarray]]:
    """(name, site, base start) for the default start and the paper's starts."""
    t1 = target_at(PAPER_SITE_1, config)
    default = start_from_offsets(t1, np.array(config.control.sim.start_offset_m))[0]
    out: list[tuple[str, tuple[float, ...], np.ndarray]] = [("default (scenario-1 geometry)", PAPER_SITE_1, default)]
    out += [(f"scenario {s}", SITES[s], np.array([*SCENARIOS[s], 0.0])) for s in sorted(SCENARIOS)]
    return out


def nominal(sets: list[str]) -> list[dict[str, Any]]:
    cfg = load_config(None, sets)
    rows = []
    for s in sorted(SCENARIOS):
        r = simulate(target_at(SITES[s], cfg), np.array([[*SCENARIOS[s], 0.0]]), cfg)
        m = r.metrics(0)
        rows.append({"scenario": s, **{k: m[k] for k in ("reason", "stabilisation_time_s", "settling_time_s",
                                                           "landing_time_s", "final_feature_error_px",
                                                           "touchdown_error_m", "max_tilt_deg")}})
    return rows


def noise_sets(scale: float, gust: float, config: Config) -> list[str]:
    m = config.control.montecarlo
    return [f"control.montecarlo.position_sigma_m={m.position_sigma_m * scale}",
            f"control.montecarlo.attitude_sigma_deg={m.attitude_sigma_deg * scale}",
            f"control.montecarlo.velocity_sigma_m_s={m.velocity_sigma_m_s * scale}",
            f"control.montecarlo.position_drift_m_sqrt_s={m.position_drift_m_sqrt_s * scale}",
            f"control.montecarlo.yaw_drift_deg_sqrt_s={m.yaw_drift_deg_sqrt_s * scale}",
            f"control.montecarlo.gust_m_s={gust}"]


ABLATION = {
    "paper law (T3 gains, no approach, no observer)": ["control.gain_set=paper", "control.approach.enabled=false",
                                                       "control.disturbance.observer=false"],
    "+ approach": ["control.gain_set=paper", "control.disturbance.observer=false"],
    "+ disturbance observer": ["control.gain_set=paper", "control.approach.enabled=false"],
    "+ tuned gains": ["control.approach.enabled=false", "control.disturbance.observer=false"],
    "approach + observer (T3 gains)": ["control.gain_set=paper"],
    "all (default)": [],
}


def plot(sweep: list[dict[str, Any]], radius: float, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for scale in NOISE_SCALES:
        cells = [c for c in sweep if c["noise_scale"] == scale]
        g = [c["gust_m_s"] for c in cells]
        a1.plot(g, [100 * c["success_rate"] for c in cells], "o-", label=f"noise x{scale:g}")
        a2.plot(g, [c["touchdown_error_p95_m"] or np.nan for c in cells], "o-", label=f"noise x{scale:g}")
    a1.axhline(99, color="k", ls=":", lw=1)
    a1.set_xlabel("gust std per horizontal axis (m/s)")
    a1.set_ylabel(f"landed within {radius:g} m (%)")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    a2.axhline(radius, color="k", ls=":", lw=1)
    a2.set_xlabel("gust std per horizontal axis (m/s)")
    a2.set_ylabel("touch-down error p95 (m)")
    a2.grid(alpha=0.3)
    fig.suptitle("IBVS landing, default start (scenario-1 geometry) with scatter; noise x1 = 2 cm / 1 deg")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    print(f"plot -> {path}")


def main() -> None:
    ap = harness.parser(__doc__, "ibvs_robustness")
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per target / ablation cell")
    ap.add_argument("--sweep-runs", type=int, default=100, help="runs per sweep cell (0: no sweep)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--sections", default="nominal,targets,ablation,sweep",
                    help="comma-separated subset of nominal,targets,ablation,sweep")
    args = ap.parse_args()
    sections = set(args.sections.split(","))
    config = load_config()
    report: dict[str, Any] = {"runs": args.runs, "seed": args.seed, "loadavg_start": os.getloadavg()}

    if "nominal" in sections:
        nominal_section(report)
    if "targets" in sections:
        targets_section(report, config, args.runs, args.seed)
    name0, site0, base0 = starts_of(config)[0]
    if "ablation" in sections:
        report["ablation"] = []
        print(f"\nAblation from the {name0} start ({args.runs} runs, seed {args.seed}):")
        for name, sets in ABLATION.items():
            row = {"variant": name, "sets": sets, **mc(with_sets(config, sets), site0, base0, args.runs, args.seed)}
            report["ablation"].append(row)
            p95 = row["touchdown_error_p95_m"]
            print(f"  {name:<48}{100 * row['success_rate']:>6.1f}%  td p95 {'-' if p95 is None else f'{p95:.3f}'} m"
                  f"  {row['failures']}", flush=True)

    if "sweep" in sections and args.sweep_runs:
        report["sweep"] = []
        print(f"\nSweep ({args.sweep_runs} runs a cell): success % (td p95 m)")
        print(f"{'noise':>6}" + "".join(f"{f'gust {g:g}':>16}" for g in GUSTS))
        for scale in NOISE_SCALES:
            line = f"{f'x{scale:g}':>6}"
            for gust in GUSTS:
                cfg = load_config(None, noise_sets(scale, gust, config))
                cell = {"noise_scale": scale, "gust_m_s": gust, **mc(cfg, site0, base0, args.sweep_runs, args.seed)}
                report["sweep"].append(cell)
                p95 = cell["touchdown_error_p95_m"]
                line += f"{100 * cell['success_rate']:>8.1f} ({'-' if p95 is None else f'{p95:.2f}'})"
            print(line, flush=True)
        plot(report["sweep"], config.control.sim.success_radius_m, args.out.with_suffix(".png"))

    report["loadavg_end"] = os.getloadavg()
    harness.write_results(args.out, json.loads(json.dumps(report, default=float)))


def nominal_section(report: dict[str, Any]) -> None:
    report["nominal"] = {"tuned": nominal([]), "paper_T3": nominal(["control.gain_set=paper"])}
    print("Nominal (no noise, no wind) from the paper's four starts: stabilisation (< 1 px) s, paper 7.81 s")
    for name, rows in report["nominal"].items():
        st = [r["stabilisation_time_s"] for r in rows]
        print(f"  {name:<9} " + "  ".join(f"s{r['scenario']} {r['stabilisation_time_s']} s "
                                          f"(tilt {r['max_tilt_deg']:.1f} deg, {r['reason']})" for r in rows)
              + f"  mean {np.mean(st):.2f} s", flush=True)


def targets_section(report: dict[str, Any], config: Config, runs: int, seed: int) -> None:
    report["targets"] = []
    print(f"\nTargets: {runs} runs each, seed {seed}, montecarlo noise and "
          f"{config.control.montecarlo.gust_m_s} m/s gusts, start scatter")
    print(f"{'start':<32}{'success':>9}{'td p50':>8}{'td p95':>8}{'td max':>8}{'approach':>9}{'recov':>6}  failures")
    for name, site, base in starts_of(config):
        row = {"start": name, "site_world": list(site), "base_start_world": base.tolist(),
               **mc(config, site, base, runs, seed)}
        report["targets"].append(row)
        mx = row["touchdown_error_max_m"]
        print(f"{name:<32}{100 * row['success_rate']:>8.1f}%{row['touchdown_error_p50_m']:>8.3f}"
              f"{row['touchdown_error_p95_m']:>8.3f}{'-' if mx is None else f'{mx:.3f}':>8}{row['approach_runs']:>9}"
              f"{row['recoveries']:>6}  {row['failures']}", flush=True)


if __name__ == "__main__":
    main()
