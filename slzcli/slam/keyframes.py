"""When a tracked frame becomes a keyframe: enough motion, or too few of the keyframe's points left.

Shared by backends that do not report keyframes themselves (pyorbslam3 exposes none).
"""

from __future__ import annotations

import numpy as np

from slzcli import geometry


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
    """``slzcli.geometry.project`` in its old (width, height) form: odometry.py of revisions before
    geometry.py imports it from here, and benchmarks/slam_robustness.py --baseline runs those."""
    return geometry.project(xyz_world, T_world_camera, K, (height, width))
