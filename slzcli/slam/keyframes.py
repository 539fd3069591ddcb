"""When a tracked frame becomes a keyframe: enough motion, or too few of the keyframe's points left.

Shared by backends that do not report keyframes themselves (pyorbslam3 exposes none).
"""

from __future__ import annotations

import numpy as np


def rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def is_new_keyframe(T_last_kf: np.ndarray | None, T_now: np.ndarray, tracked: int, tracked_at_kf: int,
                    min_translation_m: float, min_rotation_deg: float, min_tracked_ratio: float) -> bool:
    """True when the camera moved or turned enough since the last keyframe, or lost too many of its points."""
    if T_last_kf is None:
        return True
    rel = np.linalg.inv(T_last_kf) @ T_now
    return bool(np.linalg.norm(rel[:3, 3]) >= min_translation_m
                or rotation_deg(rel[:3, :3]) >= min_rotation_deg
                or tracked < min_tracked_ratio * max(tracked_at_kf, 1))


def project(xyz_world: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray, width: int, height: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N,2) of world points and a mask of those in front of the camera and inside the image."""
    T_cw = np.linalg.inv(T_world_camera)
    pc = xyz_world @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([K[0, 0] * pc[:, 0] / z + K[0, 2], K[1, 1] * pc[:, 1] / z + K[1, 2]], axis=1)
    ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= height - 1)
    return uv, ok
