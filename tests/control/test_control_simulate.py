"""The closed loop: hover, convergence from the paper's four starts, Lyapunov, failure reasons."""

from __future__ import annotations

import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.control import montecarlo
from slzcli.control.simulate import APPROACH, DESCENT, IBVS, SCENARIOS, SimResult, Target, resolve_start, simulate
from slzcli.errors import ConfigError
from slzcli.landing.corners import square_corners

# Sites (world, ENU) in view of each paper start; the paper reports only scenario 1's site,
# (3.24, 3.32, 0.4), whose corners leave the virtual image's top edge early (see the report).
SITES = {1: (2.0, 1.5, 0.3), 2: (-1.5, 10.0, 0.0), 3: (1.5, -1.0, 0.0), 4: (-1.0, 2.0, 0.0)}


def target_at(center: tuple[float, float, float]) -> Target:
    c = np.array(center, float)
    return Target(c, square_corners(c, (0.656, 0.656)))


def test_hover_with_zero_feature_error_holds_position_and_thrust_is_mg() -> None:
    cfg = load_config(None, ["control.sim.switch_hold_s=1000", "control.sim.timeout_s=10"])
    target = target_at((0.5, -0.5, 0.2))
    start = np.array([[0.5, -0.5, 2.2, 0.0]])  # exactly the hover: 2 m above the site, square aligned
    r = simulate(target, start, cfg, log=True)
    assert r.log is not None
    assert r.reason[0] == "timeout" and r.sim_time_s == pytest.approx(10.0)
    p = r.log["p_world"][:, 0]
    assert np.abs(p - p[0]).max() < 0.01
    assert r.log["thrust"][:, 0] == pytest.approx(cfg.uav.mass_kg * cfg.control.gravity_m_s2, rel=1e-6)
    assert np.abs(r.log["e_q"]).max() < 1e-9


def paper_starts() -> np.ndarray:
    """The paper's four starts, each relative to its scenario's site (all sites moved to one target)."""
    return np.array([[*(np.array(SCENARIOS[s]) - SITES[s]), 0.0] for s in sorted(SCENARIOS)])


@pytest.fixture(scope="module")
def nominal() -> SimResult:
    """The default config's landings from the paper's four starts, in one batch: flown once, checked by two tests."""
    return simulate(target_at((0.0, 0.0, 0.0)), paper_starts(), load_config())


def test_converges_and_lands_from_the_four_paper_starts(nominal: SimResult) -> None:
    r = nominal
    assert list(r.reason) == ["touchdown"] * 4
    assert r.success.all()
    assert (r.final_feature_error_px < 1.0).all()
    assert (r.touchdown_error_m < 0.1).all()
    assert np.isfinite(r.stabilisation_time_s).all() and (r.stabilisation_time_s > 0).all()
    assert (r.stabilisation_time_s <= r.switch_time_s).all() and (r.switch_time_s < r.landing_time_s).all()
    assert (r.touchdown_speed_m_s < 1.0).all()  # a landing, not a crash


def test_lyapunov_function_does_not_increase_during_ibvs() -> None:
    """V = 1/2 (e_f'e_f + e_i'K_i e_i): non-increasing when the force is delivered as the law assumes."""
    cfg = load_config(None, ["control.sim.attitude=ideal", "control.wind.drag_kg_s=0",
                             "control.integral_zone_px=1000000", "control.sim.timeout_s=8"])
    target = target_at((0.0, 0.0, 0.0))
    r = simulate(target, np.array([[0.3, -0.2, 3.0, 0.0]]), cfg, log=True)
    assert r.log is not None
    ibvs_phase = r.log["phase"][:, 0] == 0
    v = r.log["lyapunov"][ibvs_phase, 0]
    assert v[0] > 0.01 and v[-1] < 0.05 * v[0]
    assert (np.diff(v) <= 1e-6 * v[:-1] + 1e-12).all()
    # with the real attitude loop V is not monotone at the start (the force lags): report, not assert


def test_yaw_turns_to_the_nearest_square_alignment() -> None:
    cfg = load_config(None, ["control.sim.timeout_s=6", "control.sim.switch_hold_s=1000"])
    target = target_at((0.0, 0.0, 0.0))
    r = simulate(target, np.array([[0.0, 0.0, 2.5, 30.0]]), cfg, log=True)
    assert r.log is not None
    yaw_err = np.degrees(r.log["yaw_err_true"][:, 0])
    assert abs(yaw_err[0]) == pytest.approx(30.0, abs=0.5)
    assert abs(yaw_err[-1]) < 0.5


def test_site_out_of_view_fails_with_a_reason_without_the_approach() -> None:
    cfg = load_config(None, ["control.approach.enabled=false"])
    r = simulate(target_at((0.0, 0.0, 0.0)), np.array([[15.0, 0.0, 5.0, 0.0]]), cfg)
    assert r.reason[0] == "site_not_in_view" and not r.success[0]
    m = r.metrics(0)
    assert m["reason"] == "site_not_in_view" and m["touchdown_error_m"] is None


def test_approach_flies_a_site_out_of_view_into_view_then_lands() -> None:
    """15 m beside the site at 5 m: the square is out of the image; the approach brings it in, IBVS lands."""
    cfg = load_config()
    target = target_at((0.0, 0.0, 0.0))
    r = simulate(target, np.array([[15.0, 0.0, 5.0, 0.0]]), cfg, log=True)
    assert r.log is not None
    assert r.reason[0] == "touchdown" and r.success[0] and r.touchdown_error_m[0] < 0.05
    m = r.metrics(0)
    # 15 m at <= 2 m/s: the approach lasts several seconds; then IBVS and the descent
    assert m["handover_time_s"] > 3.0 and m["phases_s"]["approach"] == pytest.approx(m["handover_time_s"], abs=0.02)
    assert m["phases_s"]["ibvs"] > 0 and m["phases_s"]["descent"] > 0
    phase = r.log["phase"][:, 0]
    assert phase[0] == APPROACH and set(np.unique(phase)) == {APPROACH, IBVS, DESCENT}
    first_ibvs = int(np.argmax(phase == IBVS))
    assert (phase[first_ibvs:] != APPROACH).all()       # no loss after the hand-over in the nominal case
    speed = np.linalg.norm(r.log["v_world"][:first_ibvs, 0, :2], axis=1)
    assert speed.max() < cfg.control.approach.speed_m_s * 1.1


def test_lost_corners_are_recovered_not_a_failure() -> None:
    """The paper's scenario-1 site from its start: Table 3 gains with the law's full initial push let the
    square leave the virtual image (METHOD); without the approach that ends the run, with it the run recovers."""
    site = (3.24, 3.32, 0.4)
    target = target_at(site)
    start = np.array([[0.0, 0.0, 10.0, 0.0]])
    sets = ["control.gain_set=paper", "control.max_tilt_cmd_deg=25"]
    off = simulate(target, start, load_config(None, [*sets, "control.approach.enabled=false"]))
    on = simulate(target, start, load_config(None, sets))
    assert off.reason[0] == "corners_lost"
    assert on.reason[0] == "touchdown" and on.success[0] and on.recoveries[0] >= 1


def test_scenario_and_offset_starts() -> None:
    cfg = load_config()
    t = target_at((1.0, 2.0, 0.5))
    assert resolve_start(t, cfg, scenario=2).tolist() == [-3.0, 12.0, 9.0, 0.0]
    # --start is absolute (as in slz synth), --offset is from the site centre; the default is the paper's
    # scenario-1 geometry: start (0, 0, 10) for its site (3.24, 3.32, 0.4)
    assert resolve_start(t, cfg, start=(0.5, 0.0, 4.0, 10.0)).tolist() == [0.5, 0.0, 4.0, 10.0]
    assert resolve_start(t, cfg, start=(0.5, 0.0, 4.0)).tolist() == [0.5, 0.0, 4.0, 0.0]
    assert resolve_start(t, cfg, offset=(0.5, 0.0, 4.0, 10.0)).tolist() == [1.5, 2.0, 4.5, 10.0]
    assert np.allclose(resolve_start(t, cfg), [1.0 - 3.24, 2.0 - 3.32, 0.5 + 9.6, 0.0])
    with pytest.raises(ConfigError, match="one of"):
        resolve_start(t, cfg, start=(0.0, 0.0, 5.0), offset=(0.0, 0.0, 5.0))


def test_montecarlo_small_batch_summary() -> None:
    cfg = load_config(None, ["control.sim.timeout_s=12"])
    target = target_at((0.0, 0.0, 0.0))
    r = montecarlo.run(target, np.array([0.0, 0.0, 3.0, 0.0]), 6, 3, cfg)
    s = montecarlo.summarise(r)
    assert s["runs"] == 6 and 0.0 <= s["success_rate"] <= 1.0
    assert sum(s["reasons"].values()) == 6
    assert s["landing_time_s"]["count"] == 6
    assert len(set(np.round(r.starts_world[:, 0], 6))) == 6  # scattered starts
    assert "success" in montecarlo.table(s)
    again = montecarlo.run(target, np.array([0.0, 0.0, 3.0, 0.0]), 6, 3, cfg)
    assert np.array_equal(r.reason, again.reason) and np.allclose(r.landing_time_s, again.landing_time_s)


def test_disturbance_observer_holds_the_hover_in_steady_wind() -> None:
    """3 m/s steady wind (0.3 N through the 0.1 kg/s drag) at the hover. Measured: with the observer the
    drift from 4 s to the end of the flight stays within 1.3 mm and d_hat = 0.300 N (the drag force); without it
    (the paper's law, the integral alone) the UAV is blown 0.148 m off. Limits: 1 cm and 0.1 m, and d_hat within
    1 %. An 8 s flight (12 s before) gives the same figures: 1.29 mm and 0.1476 m at 8 s, 1.30 mm and 0.1477 m
    at 12 s (the drift has settled), at half the CPU."""
    target = target_at((0.0, 0.0, 0.0))
    start = np.array([[0.0, 0.0, 2.0 + 0.089 / 2, 0.0]])   # body origin at the hover, 2 m above the square
    sets = ["control.sim.switch_hold_s=1000", "control.sim.timeout_s=8", "control.wind.mean_m_s=[3, 0, 0]"]
    drift = {}
    for obs in ("true", "false"):
        r = simulate(target, start, load_config(None, [*sets, f"control.disturbance.observer={obs}"]), log=True)
        assert r.log is not None and r.reason[0] == "timeout"
        drift[obs] = np.abs(r.log["p_world"][400:, 0, :2]).max()
        if obs == "true":
            assert r.log["d_hat_world"][-1, 0] == pytest.approx([0.3, 0.0, 0.0], abs=0.003)
    assert drift["true"] < 0.01 and drift["false"] > 0.1


def test_tuned_gains_converge_at_paper_speed_and_table_3_stays_available(nominal: SimResult) -> None:
    """Nominal stabilisation (< 1 px) from the paper's four starts. Measured: tuned 6.80-7.35 s (paper 7.81 s),
    Table 3 13.18-14.04 s. Limits 7.81 s (the paper's figure) and > 12 s for Table 3."""
    tuned = nominal
    paper = simulate(target_at((0.0, 0.0, 0.0)), paper_starts(), load_config(None, ["control.gain_set=paper"]))
    assert tuned.success.all() and paper.success.all()
    assert (tuned.stabilisation_time_s <= 7.81).all()
    assert (paper.stabilisation_time_s > 12.0).all()
