"""Camera paths for synthetic flights: hover with drift, a slow descent, or a straight survey transect;
smooth and seeded.

The camera looks straight down with image "up" towards world +y at yaw 0:
optical z = world -z, optical x = world +x, optical y = world -y. Small roll/pitch
wobbles and an optional yaw rate are added on top. Poses are ``T_world_camera``.

``transect`` flies a straight line at ``speed_m_s`` towards compass ``heading_deg`` (0 = north = world +y,
90 = east = +x) at constant altitude, the way a survey or a search for a landing site crosses ground; the
drift and wobbles stay on top. Unlike a hover it gives a monocular camera parallax from the first frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from slzcli.config import FlightCfg
from slzcli.terrain.gravity import mount_rotation

PathKind = Literal["hover", "descent", "transect"]

#: Rotation camera optical frame -> world for a camera looking straight down at yaw 0.
R_WORLD_CAMERA_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True, eq=False)
class Flight:
    stamps_ns: np.ndarray       # (N,) int64
    T_world_camera: np.ndarray  # (N, 4, 4) float64


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotations about a world axis, one per angle: (N, 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((len(angle), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[:, axis, axis] = 1.0
    R[:, i, i] = c
    R[:, j, j] = c
    R[:, i, j] = -s
    R[:, j, i] = s
    return R


def make_flight(start_m: tuple[float, float, float], frames: int, rate_hz: float, path: PathKind,
                cfg: FlightCfg, seed: int, start_stamp_ns: int) -> Flight:
    """Poses and stamps for ``frames`` frames at ``rate_hz`` from ``start_m`` (world ENU, metres)."""
    t = np.arange(frames) / rate_hz
    T = poses_at(t, start_m, path, cfg, seed)
    stamps = start_stamp_ns + np.round(t * 1e9).astype(np.int64)
    return Flight(stamps, T)


def poses_at(t: np.ndarray, start_m: tuple[float, float, float], path: PathKind, cfg: FlightCfg,
             seed: int) -> np.ndarray:
    """``T_world_camera`` (N, 4, 4) of the flight at times ``t`` (s after frame 0): a smooth function of time,
    so that an IMU can be sampled from it at its own rate (``synth.imu``). The camera sits on the vehicle
    at ``mount_pitch_deg``/``mount_roll_deg`` (``camera.mount``'s convention) and is not told to the recording."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0.0, 2 * np.pi, 6)
    w_drift = 2 * np.pi / cfg.drift_period_s
    w_tilt = 2 * np.pi / cfg.tilt_period_s
    # Drift starts at the start point (sin(0 + ph) - sin(ph)) so frame 0 is exactly the preset.
    dx = cfg.drift_m * (np.sin(w_drift * t + ph[0]) - np.sin(ph[0]))
    dy = cfg.drift_m * (np.sin(0.73 * w_drift * t + ph[1]) - np.sin(ph[1]))
    dz = cfg.altitude_wobble_m * (np.sin(1.31 * w_drift * t + ph[2]) - np.sin(ph[2]))
    z = start_m[2] + dz
    if path == "transect":
        heading = np.deg2rad(cfg.heading_deg)
        dx = dx + cfg.speed_m_s * t * np.sin(heading)
        dy = dy + cfg.speed_m_s * t * np.cos(heading)
    if path == "descent":
        z = np.maximum(start_m[2] - cfg.descent_m_s * t, cfg.min_altitude_m) + dz
    pos = np.stack([start_m[0] + dx, start_m[1] + dy, z], axis=1)
    roll = np.deg2rad(cfg.tilt_deg) * np.sin(w_tilt * t + ph[3])
    pitch = np.deg2rad(cfg.tilt_deg) * np.sin(0.87 * w_tilt * t + ph[4])
    yaw = np.deg2rad(cfg.yaw_deg + cfg.yaw_rate_deg_s * t)
    mount = mount_rotation(cfg.mount_pitch_deg, cfg.mount_roll_deg)
    R = _rot(2, yaw) @ _rot(1, roll) @ _rot(0, pitch) @ R_WORLD_CAMERA_DOWN @ mount
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = pos
    return T
