"""Writers for SLAM results: trajectory.tum (``t x y z qx qy qz qw``) and keyframes.npz.

Frames without a pose are left out of the TUM file (the format has no "unknown" row).
keyframes.npz holds flat arrays: per keyframe (``kf_*``) and per observed map point
(``point_*``, with ``point_kf`` the row of its keyframe), so a reader needs only numpy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from slzcli.outputs.files import write_npz, write_text
from slzcli.slam.base import MapPoints


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), w >= 0, of rotation matrices (N,3,3) (Shepperd's method, vectorised)."""
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    which = np.argmax(np.concatenate([tr[:, None], diag], 1), axis=1)
    q = np.zeros((len(R), 4))
    s = np.sqrt(np.maximum(1.0 + tr, 1e-12)) * 2  # which == 0
    q0 = np.stack([(R[:, 2, 1] - R[:, 1, 2]) / s, (R[:, 0, 2] - R[:, 2, 0]) / s, (R[:, 1, 0] - R[:, 0, 1]) / s, s / 4], 1)
    s1 = np.sqrt(np.maximum(1.0 + R[:, 0, 0] - R[:, 1, 1] - R[:, 2, 2], 1e-12)) * 2
    q1 = np.stack([s1 / 4, (R[:, 0, 1] + R[:, 1, 0]) / s1, (R[:, 0, 2] + R[:, 2, 0]) / s1, (R[:, 2, 1] - R[:, 1, 2]) / s1], 1)
    s2 = np.sqrt(np.maximum(1.0 + R[:, 1, 1] - R[:, 0, 0] - R[:, 2, 2], 1e-12)) * 2
    q2 = np.stack([(R[:, 0, 1] + R[:, 1, 0]) / s2, s2 / 4, (R[:, 1, 2] + R[:, 2, 1]) / s2, (R[:, 0, 2] - R[:, 2, 0]) / s2], 1)
    s3 = np.sqrt(np.maximum(1.0 + R[:, 2, 2] - R[:, 0, 0] - R[:, 1, 1], 1e-12)) * 2
    q3 = np.stack([(R[:, 0, 2] + R[:, 2, 0]) / s3, (R[:, 1, 2] + R[:, 2, 1]) / s3, s3 / 4, (R[:, 1, 0] - R[:, 0, 1]) / s3], 1)
    q = np.choose(which[:, None], [q0, q1, q2, q3])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, 3:4] < 0, -q, q)


def tum_text(stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> str:
    """TUM trajectory text of the frames that have a pose (seconds with nanosecond digits)."""
    rows = [(t, p) for t, p in zip(stamps_ns, poses) if p is not None]
    if not rows:
        return "# timestamp tx ty tz qx qy qz qw\n"
    T = np.stack([np.asarray(p, np.float64) for _, p in rows])
    q = _quat_xyzw(T[:, :3, :3])
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for (t, _), xyz, qq in zip(rows, T[:, :3, 3], q):
        lines.append(f"{t // 1_000_000_000}.{t % 1_000_000_000:09d} " + " ".join(f"{v:.9f}" for v in (*xyz, *qq)))
    return "\n".join(lines) + "\n"


def parse_tum(text: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_ns (N,), poses (N,4,4)) from TUM trajectory text (the inverse of ``tum_text``)."""
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    stamps = np.array([int(round(float(r[0]) * 1e9)) if "." not in r[0] else
                       int(r[0].split(".")[0]) * 1_000_000_000 + int(r[0].split(".")[1].ljust(9, "0")[:9]) for r in rows],
                      dtype=np.int64)
    v = np.array([[float(x) for x in r[1:8]] for r in rows]).reshape(-1, 7)
    x, y, z, w = v[:, 3], v[:, 4], v[:, 5], v[:, 6]
    T = np.tile(np.eye(4), (len(v), 1, 1))
    T[:, :3, :3] = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    T[:, :3, 3] = v[:, :3]
    return stamps, T


def write_tum(path: Path, stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> None:
    write_text(Path(path), tum_text(stamps_ns, poses))


def keyframe_arrays(keyframes: Sequence[MapPoints]) -> dict[str, np.ndarray]:
    """The flat arrays of keyframes.npz."""
    counts = np.array([len(k) for k in keyframes], dtype=np.int64)
    return {
        "kf_index": np.array([k.keyframe_index for k in keyframes], dtype=np.int64),
        "kf_stamp_ns": np.array([k.stamp_ns for k in keyframes], dtype=np.int64),
        "kf_T_world_camera": np.stack([k.T_world_camera for k in keyframes]) if keyframes else np.zeros((0, 4, 4)),
        "point_kf": np.repeat(np.arange(len(keyframes)), counts),
        "point_ids": np.concatenate([k.ids for k in keyframes]).astype(np.int64) if keyframes else np.zeros(0, np.int64),
        "point_xyz_world": np.concatenate([k.xyz_world for k in keyframes]).reshape(-1, 3) if keyframes else np.zeros((0, 3)),
        "point_pixels": np.concatenate([k.pixels for k in keyframes]).reshape(-1, 2) if keyframes else np.zeros((0, 2)),
    }


def write_keyframes(path: Path, keyframes: Sequence[MapPoints]) -> None:
    write_npz(Path(path), **keyframe_arrays(keyframes))
