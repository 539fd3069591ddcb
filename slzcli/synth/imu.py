"""The IMU of a synthetic flight: specific force and angular rate in the camera's optical frame, with noise.

Sampled from the flight's smooth pose function (``flight.poses_at``) at ``synth.imu.rate_hz`` by
central differences: the specific force is ``R_world_camera^T (a_world + g z)`` (what an
accelerometer reads: the vehicle's own acceleration included), the angular rate the rotation
between neighbouring instants. Noise: a constant bias per axis and white noise (sensor noise
and the motors' vibration together), both seeded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slzcli.config import FlightCfg, SynthImuCfg
from slzcli.synth.flight import PathKind, poses_at
from slzcli.terrain.gravity import STANDARD_GRAVITY_M_S2

_STEP_S = 1e-3  # s; central-difference step on the analytic path (its fastest term has a 4 s period)


@dataclass(frozen=True, eq=False)
class ImuTrack:
    stamps_ns: np.ndarray   # (N,) int64
    accel: np.ndarray       # (N, 3) m/s^2, camera optical frame
    gyro: np.ndarray        # (N, 3) rad/s, camera optical frame


def imu_track(start_m: tuple[float, float, float], path: PathKind, flight: FlightCfg, seed: int,
              duration_s: float, start_stamp_ns: int, cfg: SynthImuCfg, rng: np.random.Generator) -> ImuTrack:
    """IMU samples from frame 0's time to ``duration_s`` after it."""
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / cfg.rate_hz)
    h = _STEP_S
    before, now, after = (poses_at(t + dt, start_m, path, flight, seed) for dt in (-h, 0.0, h))
    accel_world = (after[:, :3, 3] - 2 * now[:, :3, 3] + before[:, :3, 3]) / h**2
    accel_world[:, 2] += STANDARD_GRAVITY_M_S2
    R = now[:, :3, :3]
    force = np.einsum("nji,nj->ni", R, accel_world)  # R^T (a + g z)
    rel = np.einsum("nji,njk->nik", R, after[:, :3, :3]) - np.einsum("nji,njk->nik", R, before[:, :3, :3])
    omega_x = (rel - np.transpose(rel, (0, 2, 1))) / (4 * h)  # skew part of R^T dR/dt
    gyro = np.stack([omega_x[:, 2, 1], omega_x[:, 0, 2], omega_x[:, 1, 0]], axis=1)
    white = float(np.hypot(cfg.accel_noise_m_s2, cfg.vibration_m_s2))
    force = force + rng.normal(0.0, cfg.accel_bias_m_s2, 3) + rng.normal(0.0, white, force.shape)
    gyro = gyro + rng.normal(0.0, cfg.gyro_bias_rad_s, 3) + rng.normal(0.0, cfg.gyro_noise_rad_s, gyro.shape)
    stamps = start_stamp_ns + np.round(t * 1e9).astype(np.int64)
    return ImuTrack(stamps, force, gyro)
