"""Rigid poses, quaternions, the pinhole projection and its inverse (Eq. 1), in one place.

Conventions (every caller relies on them):

- A 4x4 ``T_a_b`` maps points of frame b into frame a: ``x_a = R x_b + t``.
- Quaternions are ROS / TUM order (x, y, z, w); ``as_quat`` returns the sign with w >= 0.
  The control model stores (w, x, y, z); ``quat_wxyz_to_matrix`` takes that order, unnormalised.
- Rotations are scipy's ``Rotation`` (already a dependency; its quaternion <-> matrix code is the
  hand-written Shepperd method this module replaces, tested against it).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from slzcli.types import Intrinsics


@dataclass(frozen=True)
class Pose:
    """A rigid transform (or a stack of N): rotation plus translation (3,) or (N, 3), metres."""

    rotation: Rotation
    translation: np.ndarray

    @classmethod
    def from_matrix(cls, T: np.ndarray) -> Pose:
        """From a 4x4 (or (N, 4, 4)) homogeneous matrix; the rotation block is orthonormalised by scipy."""
        m = np.asarray(T, dtype=np.float64)
        return cls(Rotation.from_matrix(m[..., :3, :3]), m[..., :3, 3].copy())

    @classmethod
    def from_quat(cls, xyzw: np.ndarray, translation: np.ndarray) -> Pose:
        """From quaternion(s) in (x, y, z, w) order (normalised here; a zero quaternion raises ValueError)."""
        q = np.asarray(xyzw, dtype=np.float64)
        n = np.linalg.norm(q, axis=-1)
        if not np.all(np.isfinite(n)) or np.any(n == 0):
            raise ValueError(f"invalid quaternion {q.tolist()}")
        return cls(Rotation.from_quat(q), np.asarray(translation, dtype=np.float64).copy())

    @classmethod
    def identity(cls) -> Pose:
        return cls(Rotation.identity(), np.zeros(3))

    def as_matrix(self) -> np.ndarray:
        """4x4 (or (N, 4, 4)) homogeneous matrix."""
        r = self.rotation.as_matrix()
        T = np.zeros((*r.shape[:-2], 4, 4))
        T[..., :3, :3] = r
        T[..., :3, 3] = self.translation
        T[..., 3, 3] = 1.0
        return T

    def as_quat(self) -> np.ndarray:
        """Unit quaternion(s) (x, y, z, w) with w >= 0 (the sign TUM files and ROS messages get)."""
        q = self.rotation.as_quat()
        return np.where(q[..., 3:4] < 0, -q, q)

    def compose(self, other: Pose) -> Pose:
        """``self * other``: T_a_c from T_a_b (self) and T_b_c (other)."""
        return Pose(self.rotation * other.rotation, self.rotation.apply(other.translation) + self.translation)

    def inverse(self) -> Pose:
        inv = self.rotation.inv()
        return Pose(inv, -inv.apply(self.translation))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points (3,) or (N, 3) of the child frame in the parent frame (vectorised)."""
        return self.rotation.apply(np.asarray(points, dtype=np.float64)) + self.translation


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform without a general matrix inverse."""
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``R x + t`` of a 4x4 on points (..., 3): one matrix product, no Rotation built (hot paths)."""
    return points @ T[:3, :3].T + T[:3, 3]


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z) -> (N, 3, 3) rotation matrices, NOT normalised first.

    The control model's RK4 stages evaluate slightly non-unit quaternions (norm 1 + O(dt^2)) and its
    results are defined by this formula on them; scipy's ``from_quat`` normalises first, which would
    change every simulated trajectory (not by float rounding). Not a speed matter: scipy 1.17 measured
    25 us vs 34 us for this at N = 50.
    """
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    r = np.empty((q.shape[0], 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - w * z)
    r[:, 0, 2] = 2 * (x * z + w * y)
    r[:, 1, 0] = 2 * (x * y + w * z)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - w * x)
    r[:, 2, 0] = 2 * (x * z - w * y)
    r[:, 2, 1] = 2 * (y * z + w * x)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def project(xyz_world: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray,
            shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of world points in a pinhole camera, and which are in front (z > 0) and inside.

    ``shape`` is the image (height, width); inside means 0 <= u <= width - 1 and the same for v
    (pixel centres). Points behind the camera or at z = 0 get whatever the division gives (inf/NaN
    or a mirrored pixel) and ``inside`` False.
    """
    pc = transform_points(np.linalg.inv(T_world_camera), xyz_world)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * pc[:, 0] / z + K[0, 2]
        v = K[1, 1] * pc[:, 1] / z + K[1, 2]
    h, w = shape
    inside = (z > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    return np.stack([u, v], axis=1), inside


# ----------------------------------------------------------------------------- depth image -> points (Eq. 1)
def valid_depth(depth_m: np.ndarray) -> np.ndarray:
    """Pixels with a usable measurement (finite and positive)."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth_m) & (depth_m > 0)


@functools.lru_cache(maxsize=8)
def pixel_rays(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel ``(u - cx) / fx`` (1 x W) and ``(v - cy) / fy`` (H x 1), float32; cached per camera."""
    u = np.arange(intrinsics.width, dtype=np.float64)
    v = np.arange(intrinsics.height, dtype=np.float64)
    rx = ((u - intrinsics.cx) / intrinsics.fx).astype(np.float32)[None, :]
    ry = ((v - intrinsics.cy) / intrinsics.fy).astype(np.float32)[:, None]
    rx.setflags(write=False)
    ry.setflags(write=False)
    return rx, ry


def fit_intrinsics(intrinsics: Intrinsics, shape: tuple[int, int]) -> Intrinsics:
    """The intrinsics for an image of ``shape`` (H, W): unchanged, or rescaled if the size differs."""
    h, w = shape
    if (intrinsics.width, intrinsics.height) == (w, h):
        return intrinsics
    return intrinsics.scaled(w, h)


def back_project_every(depth_m: np.ndarray, intrinsics: Intrinsics, stride_px: int) -> np.ndarray:
    """``back_project(depth_m, intrinsics)[::stride_px, ::stride_px]``, without computing the pixels it drops."""
    intr = fit_intrinsics(intrinsics, depth_m.shape)
    sub = depth_m[::stride_px, ::stride_px]
    s = float(stride_px)  # pixel u' of the strided grid is pixel s u' of the image: exact, not a resize
    return back_project(sub, Intrinsics(intr.fx / s, intr.fy / s, intr.cx / s, intr.cy / s, sub.shape[1],
                                        sub.shape[0], intr.distortion_model, intr.distortion))


def back_project(depth_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Eq. 1: the organised point image (H x W x 3, float32, camera frame), NaN where no depth."""
    intr = fit_intrinsics(intrinsics, depth_m.shape)
    rx, ry = pixel_rays(intr)
    z = np.where(valid_depth(depth_m), depth_m, np.nan).astype(np.float32, copy=False)
    points = np.empty((*depth_m.shape, 3), dtype=np.float32)
    np.multiply(z, rx, out=points[..., 0])
    np.multiply(z, ry, out=points[..., 1])
    points[..., 2] = z
    return points
