"""The independent check: slz's IBVS flown in RotorPy's multirotor lands where slz's own simulator does.

Skipped without the optional ``rotorpy`` package (``pip install 'slz[rotorpy]'``; CI does not install
it). The frame conversions are checked without it.
"""

from __future__ import annotations

import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.control import dynamics as dyn
from slzcli.control import rotorpy_check as rc
from slzcli.control.simulate import Target, simulate
from slzcli.landing.corners import square_corners


def test_state_round_trips_between_ned_frd_and_rotorpy_frames() -> None:
    """A pitched, yawed state goes to RotorPy's z-up world / FLU body and back unchanged; thrust along -z FRD is
    along +z FLU, i.e. up in the world when level."""
    quat = dyn.quat_from_euler(np.array([0.1]), np.array([-0.2]), np.array([0.7]))[0]
    x = np.concatenate([[1.0, 2.0, -3.0], [0.3, -0.1, 0.2], quat, [0.05, -0.02, 0.3]])
    rp = rc.ned_to_rotorpy(x)
    assert rp["x"].tolist() == [2.0, 1.0, 3.0]              # NED (north 1, east 2, down -3) -> ENU
    back = rc.rotorpy_to_ned(rp)
    assert np.allclose(back[:6], x[:6]) and np.allclose(back[10:], x[10:])
    assert np.allclose(dyn.quat_to_rot(back[None, 6:10]), dyn.quat_to_rot(x[None, 6:10]))
    level = rc.ned_to_rotorpy(np.concatenate([np.zeros(6), [1.0, 0, 0, 0], np.zeros(3)]))
    # level, nose north: in ENU the FLU body is turned +90 deg about up; its z (thrust) points up
    assert np.allclose(level["q"], [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])


def test_quad_params_reproduce_the_uav_thrust_range() -> None:
    cfg = load_config(None, [])
    p = rc.quad_params(cfg.uav)
    assert 4 * p["k_eta"] * p["rotor_speed_max"] ** 2 == pytest.approx(cfg.uav.thrust_max_n)
    assert 4 * p["k_eta"] * p["rotor_speed_min"] ** 2 == pytest.approx(cfg.uav.thrust_min_n)
    assert p["mass"] == cfg.uav.mass_kg and p["Izz"] == cfg.uav.inertia_kg_m2[2]


def test_rotorpy_lands_where_slz_lands_from_scenario_1() -> None:
    """Scenario 1 (start (0, 0, 10) m, site (2, 1.5, 0.3) m), RotorPy's aerodynamics on, no wind, against slz's
    default drag. Measured (benchmarks/results/ibvs_rotorpy.json): slz / RotorPy touch-down error 0.0001 / 0.0005 m,
    stabilisation 7.35 / 7.37 s, landing 12.46 / 12.37 s. Limits: the benchmark's tolerance (0.05 m; 10 % + 0.3 s)."""
    pytest.importorskip("rotorpy")
    cfg = load_config(None, [])
    c = np.array((2.0, 1.5, 0.3))
    target = Target(c, square_corners(c, (cfg.uav.footprint_m[0], cfg.uav.footprint_m[1])))
    start = np.array([[0.0, 0.0, 10.0, 0.0]])
    own = simulate(target, start, cfg).metrics(0)
    other = simulate(target, start, cfg, plant=rc.RotorPyPlant(cfg.control, cfg.uav)).metrics(0)
    assert own["reason"] == other["reason"] == "touchdown"
    assert abs(own["touchdown_error_m"] - other["touchdown_error_m"]) <= 0.05
    for key in ("stabilisation_time_s", "landing_time_s"):
        assert abs(own[key] - other[key]) <= 0.3 + 0.1 * max(own[key], other[key])


def test_an_external_plant_needs_dynamic_attitude() -> None:
    from slzcli.errors import ConfigError

    cfg = load_config(None, ["control.sim.attitude=ideal"])
    c = np.zeros(3)
    target = Target(c, square_corners(c, (cfg.uav.footprint_m[0], cfg.uav.footprint_m[1])))
    with pytest.raises(ConfigError, match=r"control\.sim\.attitude"):
        simulate(target, np.array([[0.0, 0.0, 5.0, 0.0]]), cfg, plant=lambda x, thrust, torque: x)
