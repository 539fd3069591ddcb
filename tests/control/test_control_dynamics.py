"""Rigid-body model (Eq. 11) and the control-law pieces: physics first, then the sign decisions."""

from __future__ import annotations

import numpy as np
import pytest

from slzcli.config import load_config
from slzcli.control import dynamics as dyn
from slzcli.control import ibvs


@pytest.fixture(scope="module")
def params() -> dyn.Params:
    config = load_config()
    return dyn.Params.from_config(config.control, config.uav)


def test_enu_ned_is_a_proper_self_inverse_rotation() -> None:
    assert np.linalg.det(dyn.ENU_NED) == pytest.approx(1.0)
    p = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(dyn.ned_to_enu(dyn.enu_to_ned(p)), p)
    assert np.allclose(dyn.enu_to_ned(np.array([0.0, 0.0, 5.0])), [0.0, 0.0, -5.0])  # up is -z_NED
    assert dyn.yaw_enu_to_ned(np.array(0.0)) == pytest.approx(np.pi / 2)  # east = heading 90 deg


def test_hover_thrust_mg_holds_the_state_for_10_s(params: dyn.Params) -> None:
    x = dyn.State.at_rest(np.array([[0.0, 0.0, -5.0]]), np.array([0.3])).vector()
    thrust = np.array([params.mass_kg * params.gravity])
    for _ in range(5000):  # 10 s at 500 Hz
        x = dyn.rk4_step(x, 0.002, thrust, np.zeros((1, 3)), np.zeros((1, 3)), params)
    assert np.abs(x[0, 0:3] - [0.0, 0.0, -5.0]).max() < 1e-9
    assert np.abs(x[0, 3:6]).max() < 1e-9


def test_free_fall_and_constant_torque_match_closed_form(params: dyn.Params) -> None:
    x = dyn.State.at_rest(np.zeros((1, 3)), np.zeros(1)).vector()
    tau = np.array([[0.0, 0.0, 0.01]])
    for _ in range(500):  # 1 s, no thrust, pure yaw torque (w x Jw = 0 about a principal axis)
        x = dyn.rk4_step(x, 0.002, np.zeros(1), tau, np.zeros((1, 3)), params)
    assert x[0, 2] == pytest.approx(0.5 * params.gravity, rel=1e-9)  # falls along +z (NED down)
    r = dyn.quat_to_rot(x[:, 6:10])
    yaw = dyn.euler_from_rot(r)[2][0]
    assert yaw == pytest.approx(0.5 * 0.01 / params.inertia[2], rel=1e-6)


def test_tilt_forward_accelerates_forward(params: dyn.Params) -> None:
    """Nose down (negative pitch, FRD) + hover thrust pushes the vehicle along its nose."""
    q = dyn.quat_from_euler(np.zeros(1), np.array([-0.1]), np.zeros(1))
    x = np.concatenate([np.zeros((1, 6)), q, np.zeros((1, 3))], axis=1)
    dx = dyn.derivative(x, np.array([params.mass_kg * params.gravity]), np.zeros((1, 3)), np.zeros((1, 3)), params)
    assert dx[0, 3] > 0.5  # +x_NED (north = nose at yaw 0)


def test_euler_rotation_round_trip() -> None:
    rng = np.random.default_rng(0)
    roll, pitch, yaw = rng.uniform(-1, 1, 5), rng.uniform(-1, 1, 5), rng.uniform(-3, 3, 5)
    r = dyn.quat_to_rot(dyn.quat_from_euler(roll, pitch, yaw))
    back = dyn.euler_from_rot(r)
    assert np.allclose(back, (roll, pitch, yaw))
    expected = dyn.rot_z(yaw) @ np.stack([np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
                                          for p in pitch])
    rot_x = np.stack([np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]) for a in roll])
    assert np.allclose(r[:, :, 2], (expected @ rot_x)[:, :, 2])


def test_thrust_attitude_extraction_inverts_the_force(params: dyn.Params) -> None:
    """T b3 = m g e3 - F: the commanded net force comes back out of R e3 and T (no limits hit)."""
    force = np.array([[0.3, -0.2, 0.5], [0.0, 0.0, 0.0]])
    thrust, roll_d, pitch_d, sat = ibvs.thrust_attitude(force, 0.0, params.mass_kg, params.gravity, 0.0, 100.0,
                                                        np.radians(80))
    r = dyn.quat_to_rot(dyn.quat_from_euler(roll_d, pitch_d, np.zeros(2)))
    net = -thrust[:, None] * r[:, :, 2] + params.mass_kg * params.gravity * np.array([0.0, 0.0, 1.0])
    assert np.allclose(net, force)
    assert thrust[1] == pytest.approx(params.mass_kg * params.gravity)  # hover: T = m g
    assert not sat.any()


def test_tilt_limit_saturates_and_reports_it(params: dyn.Params) -> None:
    _, roll_d, pitch_d, sat = ibvs.thrust_attitude(np.array([[5.0, 0.0, 0.0]]), 0.0, params.mass_kg, params.gravity,
                                                   0.0, 100.0, np.radians(20))
    tilt = dyn.tilt(dyn.quat_to_rot(dyn.quat_from_euler(roll_d, pitch_d, np.zeros(1))))
    assert np.degrees(tilt[0]) == pytest.approx(20.0)
    assert sat[0]


def test_control_law_closes_ef_dynamics() -> None:
    """Substituting F into e_f' = (K_e - 2S) e' - (S' + S^2) e - F/(m z*) gives -K_p e_f - K_i e_i."""
    gains = ibvs.Gains.from_config(load_config().control)
    rng = np.random.default_rng(1)
    e, e_dot, e_i = rng.normal(size=(3, 4, 3))
    psi_rate, psi_acc = rng.normal(size=(2, 4))
    m = 0.4
    force, e_f = ibvs.control_force(e, e_dot, e_i, psi_rate, psi_acc, m, gains)
    s_edot = ibvs.skew_z(psi_rate, e_dot)
    ef_dot = (gains.K_e * e_dot - 2 * s_edot - ibvs.skew_z(psi_acc, e) - ibvs.skew_z(psi_rate, ibvs.skew_z(psi_rate, e))
              - force / (m * gains.depth_m))
    assert np.allclose(ef_dot, -gains.K_p * e_f - gains.K_i * e_i)
