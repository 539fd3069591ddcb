"""Rigid-body quadrotor (Eq. 11) with a fixed-step RK4, batched over independent runs.

Conventions inside the control code (METHOD 2.6-2.9): inertial frame NED (z along
gravity), body frame FRD (x nose, y right, z down), Z-Y-X Euler angles
``R_IB = Rz(psi) Ry(theta) Rx(phi)``. Thrust acts along -z_body:
``m v' = -U1 R e3 + m g e3 + F_d``; ``R' = R [w]x``; ``J w' = -w x J w + tau``.
The project's world is ENU z-up; ``enu_to_ned`` is the one place the two meet.

Every array carries a leading run axis N, so a Monte Carlo batch is one numpy call per
step; a single run is N = 1. The state vector is (N, 13): position, velocity,
quaternion (w, x, y, z; body -> inertial), body rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slzcli.config import ControlCfg, UavCfg
from slzcli.geometry import quat_wxyz_to_matrix

# ENU <-> NED is the same proper rotation both ways: (x, y, z) -> (y, x, -z).
ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def enu_to_ned(xyz: np.ndarray) -> np.ndarray:
    """Vectors or points from the world (ENU, z up) to the control frame (NED); self-inverse."""
    return np.asarray(xyz, np.float64) @ ENU_NED.T


ned_to_enu = enu_to_ned


def yaw_enu_to_ned(yaw_enu: np.ndarray) -> np.ndarray:
    """ENU yaw (from +x east, counter-clockwise) -> NED heading (from north, clockwise)."""
    return np.pi / 2 - np.asarray(yaw_enu, np.float64)


@dataclass(frozen=True)
class Params:
    """Bebop 2 rigid-body parameters and actuator limits (config ``uav`` + gravity)."""

    mass_kg: float
    inertia: np.ndarray          # (3,) principal moments, kg m^2
    gravity: float
    thrust_min_n: float
    thrust_max_n: float
    torque_max: np.ndarray       # (3,) N m

    @classmethod
    def from_config(cls, control: ControlCfg, u: UavCfg) -> Params:
        return cls(u.mass_kg, np.array(u.inertia_kg_m2, float), control.gravity_m_s2,
                   u.thrust_min_n, u.thrust_max_n, np.array(u.torque_max_n_m, float))


@dataclass(frozen=True, eq=False)
class State:
    """Batched rigid-body state in NED/FRD: p, v (N, 3) m, m/s; quat (N, 4) w-first; w (N, 3) rad/s."""

    p: np.ndarray
    v: np.ndarray
    quat: np.ndarray
    w: np.ndarray

    def vector(self) -> np.ndarray:
        return np.concatenate([self.p, self.v, self.quat, self.w], axis=1)

    @classmethod
    def from_vector(cls, x: np.ndarray) -> State:
        return cls(x[:, 0:3], x[:, 3:6], x[:, 6:10], x[:, 10:13])

    @classmethod
    def at_rest(cls, p_ned: np.ndarray, yaw_ned: np.ndarray) -> State:
        """Hovering start: level, still, at the given positions and headings."""
        p = np.atleast_2d(np.asarray(p_ned, float))
        n = p.shape[0]
        yaw = np.broadcast_to(np.asarray(yaw_ned, float), (n,))
        zeros = np.zeros(n)
        return cls(p.copy(), np.zeros((n, 3)), quat_from_euler(zeros, zeros, yaw), np.zeros((n, 3)))


# ----------------------------------------------------------------------------- rotations
def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z) -> (N, 3, 3) rotation matrices (body -> inertial), unnormalised."""
    return quat_wxyz_to_matrix(q)


def quat_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler (phi, theta, psi) -> (N, 4) quaternion of Rz(psi) Ry(theta) Rx(phi)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=1)


def euler_from_rot(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 3, 3) -> Z-Y-X Euler (roll phi, pitch theta, yaw psi), radians."""
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    pitch = -np.arcsin(np.clip(r[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    return roll, pitch, yaw


def rot_z(angle: np.ndarray) -> np.ndarray:
    """(N,) -> (N, 3, 3) rotations about z."""
    c, s = np.cos(angle), np.sin(angle)
    r = np.zeros((np.shape(angle)[0], 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    return r


def euler_rates(roll: np.ndarray, pitch: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Body rates (N, 3) -> Z-Y-X Euler angle rates (N, 3): (phi', theta', psi')."""
    sr, cr = np.sin(roll), np.cos(roll)
    cp, tp = np.cos(pitch), np.tan(pitch)
    p, q, r = w[:, 0], w[:, 1], w[:, 2]
    return np.stack([p + (sr * q + cr * r) * tp, cr * q - sr * r, (sr * q + cr * r) / cp], axis=1)


def tilt(r: np.ndarray) -> np.ndarray:
    """Angle between body z and gravity, radians (N,)."""
    return np.arccos(np.clip(r[:, 2, 2], -1.0, 1.0))


# ----------------------------------------------------------------------------- dynamics
def derivative(x: np.ndarray, thrust: np.ndarray, torque: np.ndarray, force_d: np.ndarray,
               params: Params) -> np.ndarray:
    """Eq. 11 for a batch: x (N, 13), thrust (N,) N, torque (N, 3) N m, F_d (N, 3) N (NED)."""
    q = x[:, 6:10]
    w = x[:, 10:13]
    r = quat_to_rot(q)
    dx = np.empty_like(x)
    dx[:, 0:3] = x[:, 3:6]
    acc = (-thrust[:, None] * r[:, :, 2] + force_d) / params.mass_kg
    acc[:, 2] += params.gravity
    dx[:, 3:6] = acc
    qw, qx, qy, qz = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    p_, q_, r_ = w[:, 0], w[:, 1], w[:, 2]
    dx[:, 6] = 0.5 * (-qx * p_ - qy * q_ - qz * r_)
    dx[:, 7] = 0.5 * (qw * p_ + qy * r_ - qz * q_)
    dx[:, 8] = 0.5 * (qw * q_ - qx * r_ + qz * p_)
    dx[:, 9] = 0.5 * (qw * r_ + qx * q_ - qy * p_)
    jw = w * params.inertia
    dx[:, 10:13] = (torque - np.cross(w, jw)) / params.inertia
    return dx


def rk4_step(x: np.ndarray, dt: float, thrust: np.ndarray, torque: np.ndarray, force_d: np.ndarray,
             params: Params) -> np.ndarray:
    """One fixed RK4 step with the inputs held (zero-order hold); the quaternion is renormalised."""
    k1 = derivative(x, thrust, torque, force_d, params)
    k2 = derivative(x + 0.5 * dt * k1, thrust, torque, force_d, params)
    k3 = derivative(x + 0.5 * dt * k2, thrust, torque, force_d, params)
    k4 = derivative(x + dt * k3, thrust, torque, force_d, params)
    out = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    out[:, 6:10] /= np.linalg.norm(out[:, 6:10], axis=1, keepdims=True)
    return out


def step(state: State, dt: float, thrust: np.ndarray, torque: np.ndarray, force_d: np.ndarray,
         params: Params) -> State:
    """The frozen-state form of ``rk4_step``."""
    return State.from_vector(rk4_step(state.vector(), dt, thrust, torque, force_d, params))


# ----------------------------------------------------------------------------- disturbance
@dataclass(frozen=True)
class Wind:
    """Constant wind plus Ornstein-Uhlenbeck gusts (horizontal), acting through linear drag."""

    mean_ned: np.ndarray         # (3,) m/s
    gust_sigma: float            # m/s, stationary std per horizontal axis
    gust_tau_s: float
    drag_kg_s: float

    @classmethod
    def from_config(cls, control: ControlCfg) -> Wind:
        w = control.wind
        return cls(enu_to_ned(np.array(w.mean_m_s, float)), w.gust_m_s, w.gust_tau_s, w.drag_kg_s)

    def initial_gust(self, z: np.ndarray) -> np.ndarray:
        """A stationary gust from (N, 2) standard normals ``z`` (horizontal axes)."""
        g = np.zeros((z.shape[0], 3))
        g[:, :2] = self.gust_sigma * z
        return g

    def next_gust(self, gust: np.ndarray, dt: float, z: np.ndarray) -> np.ndarray:
        """Exact OU update over dt driven by (N, 2) standard normals: keeps the stationary std at ``gust_sigma``."""
        a = np.exp(-dt / self.gust_tau_s)
        out = gust * a
        out[:, :2] += self.gust_sigma * np.sqrt(1 - a * a) * z
        return out

    def force(self, v_ned: np.ndarray, gust: np.ndarray) -> np.ndarray:
        """F_d = drag (wind - v), NED newtons."""
        return self.drag_kg_s * (self.mean_ned + gust - v_ned)
