"""The filtered-error image-moment IBVS law (Eq. 56 in METHOD's consistent form) and its inner loops.

Sign decisions (METHOD "A consistent derivation"; the paper's signs are not all consistent):

- Error ``e = q - q_d`` (the paper's Eq. 39 writes q_d - q); ``q_d = (0, 0, q_z*)``, q_z* = 1
  at the hover because a_d is measured at the desired depth.
- Feature kinematics in V (NED, z down): ``q' = -S q - v_V / z*`` with ``S = sk(psi' e3)``;
  the camera velocity ``v_V = Rz(psi_V)^T v_I``. Because ``S q_d = 0``, ``e' = -S e - v_V / z* - q_d'``.
- Second derivative: ``e'' = -(S' + S^2) e - 2 S e' - F / (m z*)`` where F is the net force on
  the vehicle (thrust + gravity) expressed in V.
- Filtered error ``e_f = e' + K_e e`` and the force
  ``F = m z* ((K_e - 2S)(e_f - K_e e) - (S' + S^2) e + K_p e_f + K_i e_i)``, ``e_i = int e_f``,
  give ``e_f' = -K_p e_f - K_i e_i``, so ``V = 1/2 (e_f'e_f + e_i'K_i e_i)`` has
  ``V' = -e_f' K_p e_f <= 0`` (the paper's Theorem 1). The paper's Eq. 56 is this with the
  opposite error sign folded into u.
- Thrust and attitude: thrust acts along -z_body, so ``m v' = -T b3 + m g e3 + F_d`` and the
  wanted net force F needs ``T b3 = m g e3 - F``: ``T = |m g e3 - F|``, ``b3 = (m g e3 - F) / T``
  (gravity compensation is inside, u_z ~ m g at hover). With ``R_IB = Rz(psi) Ry(theta) Rx(phi)``
  the yaw-frame direction ``n = Rz(psi)^T b3 = (s_th c_ph, -s_ph, c_th c_ph)`` gives
  ``theta_d = atan2(n_x, n_z)``, ``phi_d = atan2(-n_y, hypot(n_x, n_z))`` (Eq. 48 with its sign
  fixed by this rotation convention). F is turned from V to the body's yaw frame by the camera
  yaw on the body (gamma): ``n = Rz(gamma) n_V``.
- Limits (project): the tilt of b3 is clipped to ``max_tilt_cmd_deg`` and its vertical part is
  kept at least the idle thrust; T is clipped to [thrust_min, thrust_max]; while a limit is
  active the integral is frozen (anti-windup), since the law's guarantee only holds unsaturated.
- Attitude PD (Eqs. 50-51): roll with beta, pitch with mu (config: Table 3 text pairs beta with
  roll; the values are equal anyway): ``tau_x = b1 (phi_d - phi) + b2 (phi_d' - phi')``,
  ``tau_y = m1 (theta_d - theta) + m2 (theta_d' - theta')``.
- Yaw (Eq. 67): with ``e_psi = q_psi - q_psi_d`` (wrapped), a body yaw turn of +d turns V by +d
  about the down axis, so image lines turn by -d: ``q_psi' = -psi'``. Hence
  ``tau_z = +k_psi e_psi`` drives e_psi to zero; ``- k_psi_d psi'`` adds the damping a pure
  P torque lacks (project; the paper's yaw law commands a rate in its ROS code).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slzcli.config import ControlCfg


@dataclass(frozen=True)
class Gains:
    """Table 3 (or control.tuned) gains plus the project's yaw damping and tilt limit."""

    K_e: np.ndarray
    K_i: np.ndarray
    K_p: np.ndarray
    k_psi: float
    k_psi_d: float
    roll_pd: tuple[float, float]
    pitch_pd: tuple[float, float]
    depth_m: float
    max_tilt_rad: float

    @classmethod
    def from_config(cls, c: ControlCfg) -> Gains:
        g = c.tuned if c.gain_set == "tuned" else c   # control.gain_set: the project's tuned gains or paper T3
        return cls(np.array(g.K_e, float), np.array(g.K_i, float), np.array(g.K_p, float), c.k_psi, c.k_psi_d,
                   (c.beta[0], c.beta[1]), (c.mu[0], c.mu[1]), c.desired_depth_m, np.deg2rad(c.max_tilt_cmd_deg))


def skew_z(rate: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """sk(rate e3) @ vec for batches: rate (N,), vec (N, 3)."""
    out = np.zeros_like(vec)
    out[:, 0] = -rate * vec[:, 1]
    out[:, 1] = rate * vec[:, 0]
    return out


def error_rate(q: np.ndarray, q_d_rate: np.ndarray, v_v: np.ndarray, psi_rate: np.ndarray,
               depth_m: float) -> np.ndarray:
    """e' = q' - q_d' with q' = -S q - v_V / z* (Eq. 38)."""
    return -skew_z(psi_rate, q) - v_v / depth_m - q_d_rate


def control_force(e: np.ndarray, e_dot: np.ndarray, e_i: np.ndarray, psi_rate: np.ndarray,
                  psi_acc: np.ndarray, mass_kg: float, gains: Gains) -> tuple[np.ndarray, np.ndarray]:
    """Net force F in V (N, 3) of the consistent Eq. 56, and the filtered error e_f."""
    e_f = e_dot + gains.K_e * e
    x = e_f - gains.K_e * e
    term = gains.K_e * x - 2.0 * skew_z(psi_rate, x)                       # (K_e - 2S) x
    s2e = skew_z(psi_rate, skew_z(psi_rate, e))                            # S^2 e
    term = term - skew_z(psi_acc, e) - s2e + gains.K_p * e_f + gains.K_i * e_i
    return mass_kg * gains.depth_m * term, e_f


def lyapunov(e_f: np.ndarray, e_i: np.ndarray, K_i: np.ndarray) -> np.ndarray:
    """V = 1/2 (e_f' e_f + e_i' K_i e_i) (Eq. 58), (N,)."""
    return 0.5 * ((e_f * e_f).sum(axis=1) + (e_i * K_i * e_i).sum(axis=1))


def thrust_attitude(force_v: np.ndarray, gamma: float, mass_kg: float, gravity: float, thrust_min: float,
                    thrust_max: float, max_tilt_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Net force in V -> (thrust T, roll_d, pitch_d, saturated) via ``T b3 = m g e3 - F``."""
    c, s = np.cos(gamma), np.sin(gamma)
    fx = c * force_v[:, 0] - s * force_v[:, 1]            # Rz(gamma): V -> body yaw frame
    fy = s * force_v[:, 0] + c * force_v[:, 1]
    tx, ty, tz = -fx, -fy, mass_kg * gravity - force_v[:, 2]
    sat = tz < thrust_min
    tz = np.maximum(tz, thrust_min)
    horiz = np.hypot(tx, ty)
    limit = np.tan(max_tilt_rad) * tz
    over = horiz > limit
    scale = np.where(over, limit / np.maximum(horiz, 1e-12), 1.0)
    tx, ty = tx * scale, ty * scale
    thrust = np.sqrt(tx * tx + ty * ty + tz * tz)
    sat |= over | (thrust > thrust_max) | (thrust < thrust_min)
    thrust = np.clip(thrust, thrust_min, thrust_max)
    pitch_d = np.arctan2(tx, tz)
    roll_d = np.arctan2(-ty, np.hypot(tx, tz))
    return thrust, roll_d, pitch_d, sat


def attitude_torque(roll_err: np.ndarray, roll_rate_err: np.ndarray, pitch_err: np.ndarray,
                    pitch_rate_err: np.ndarray, yaw_err: np.ndarray, yaw_rate: np.ndarray, gains: Gains,
                    torque_max: np.ndarray) -> np.ndarray:
    """PD roll/pitch (Eqs. 50-51) and yaw ``tau_z = k_psi e_psi - k_psi_d psi'`` (Eq. 67 + damping), clipped."""
    tau = np.stack([gains.roll_pd[0] * roll_err + gains.roll_pd[1] * roll_rate_err,
                    gains.pitch_pd[0] * pitch_err + gains.pitch_pd[1] * pitch_rate_err,
                    gains.k_psi * yaw_err - gains.k_psi_d * yaw_rate], axis=1)
    return np.clip(tau, -torque_max, torque_max)
