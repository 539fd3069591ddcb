"""Image-moment features of the four landing-square corners (METHOD 2.6-2.9, Eqs. 32-37, 65-66).

Two cameras see the corners. The real camera C is fixed to the body (``R_BC`` from config:
looking down, turned by ``camera_yaw_deg`` about the down axis); its pixels decide whether
the corners are still in the image. The virtual camera V has the same position and yaw as C
but zero roll and pitch: since ``R_BC`` is a pure turn about body z, ``R_IV = Rz(psi + gamma)``
(gamma = camera yaw on the body) and every result of the paper's V-frame derivation holds
with ``psi_V' = psi'``. Virtual image coordinates are centred (no principal point):
``u = f x_V / z_V``, ``v = f y_V / z_V`` (Eq. 32), z_V along gravity.

Features (Eq. 34): ``q_z = sqrt(a_d / a)``, ``q_x = q_z u_g / f``, ``q_y = q_z v_g / f``, so
for a level square at depth Z: ``q = P_g / z*`` (centroid in V over the desired depth).
Yaw (Eq. 66): a square has mu20 = mu02 and mu11 = 0, so Eq. 65 is undefined; the feature is
the angle of the line from corner 0 to corner 1 against +u.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slzcli.config import CameraCfg, UavCfg
from slzcli.control.dynamics import rot_z


@dataclass(frozen=True)
class CameraModel:
    """Pinhole of the real camera and its pose on the body (FRD)."""

    f: float                     # px (fx; the virtual camera uses the same focal length)
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    R_BC: np.ndarray             # (3, 3) camera optical -> body
    t_BC: np.ndarray             # (3,) camera origin in the body frame, m
    yaw_on_body: float           # gamma, rad

    @classmethod
    def from_config(cls, c: CameraCfg, u: UavCfg) -> CameraModel:
        gamma = np.deg2rad(u.camera_yaw_deg)
        # Optical frame looking along body z (down): x_C = Rz(gamma) x_B, z_C = z_B.
        r_bc = rot_z(np.array([gamma]))[0]
        return cls(c.fx, c.fy, c.cx, c.cy, c.width, c.height, r_bc, np.array(u.camera_offset_m, float), gamma)


def virtual_points(corners_ned: np.ndarray, cam_pos: np.ndarray, yaw_v: np.ndarray) -> np.ndarray:
    """Corners (4, 3) inertial NED -> (N, 4, 3) in the virtual frame of cameras at cam_pos (N, 3), yaw_v (N,)."""
    rel = corners_ned[None, :, :] - cam_pos[:, None, :]
    return np.einsum("nji,nkj->nki", rot_z(yaw_v), rel)


def virtual_pixels(p_v: np.ndarray, f: float) -> np.ndarray:
    """(N, 4, 3) virtual-frame points -> (N, 4, 2) centred virtual image coordinates (Eq. 32)."""
    return f * p_v[..., :2] / p_v[..., 2:3]


def camera_pixels(corners_ned: np.ndarray, R_IC: np.ndarray, t_IC: np.ndarray,
                  cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Corners seen by the real camera: (N, 4, 2) pixels (with principal point) and (N, 4) depth."""
    rel = corners_ned[None, :, :] - t_IC[:, None, :]
    p_c = np.einsum("nji,nkj->nki", R_IC, rel)
    z = p_c[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([cam.f * p_c[..., 0] / z + cam.cx, cam.fy * p_c[..., 1] / z + cam.cy], axis=-1)
    return uv, z


def in_image(uv: np.ndarray, depth: np.ndarray, cam: CameraModel,
             margin_px: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """(N,) True when all four corners are in front of the camera and inside the image (``margin_px`` (u, v) in)."""
    mu, mv = margin_px[0], margin_px[1]
    ok: np.ndarray = ((depth > 0) & (uv[..., 0] >= mu) & (uv[..., 0] <= cam.width - mu)
                      & (uv[..., 1] >= mv) & (uv[..., 1] <= cam.height - mv))
    return np.all(ok, axis=1)


@dataclass(frozen=True)
class Moments:
    """Centroid (Eq. 35) and a = mu20 + mu02 (Eqs. 36-37) of point sets, batched (N,)."""

    ug: np.ndarray
    vg: np.ndarray
    mu20: np.ndarray
    mu02: np.ndarray
    mu11: np.ndarray

    @property
    def a(self) -> np.ndarray:
        return self.mu20 + self.mu02


def moments(uv: np.ndarray) -> Moments:
    """Point moments of (N, K, 2) image points: m_ij = sum u^i v^j, central mu_ij."""
    ug = uv[..., 0].mean(axis=1)
    vg = uv[..., 1].mean(axis=1)
    du = uv[..., 0] - ug[:, None]
    dv = uv[..., 1] - vg[:, None]
    return Moments(ug, vg, (du * du).sum(axis=1), (dv * dv).sum(axis=1), (du * dv).sum(axis=1))


def features(uv: np.ndarray, a_d: float, f: float) -> np.ndarray:
    """q = (q_x, q_y, q_z) of Eq. 34 from (N, 4, 2) virtual image points; (N, 3)."""
    m = moments(uv)
    qz = np.sqrt(a_d / m.a)
    return np.stack([qz * m.ug / f, qz * m.vg / f, qz], axis=1)


def yaw_feature(uv: np.ndarray) -> np.ndarray:
    """Angle of the corner 0 -> 1 line against +u in the virtual image, radians (N,) (Eq. 66)."""
    d = uv[:, 1, :] - uv[:, 0, :]
    return np.arctan2(d[:, 1], d[:, 0])


def desired_area(corners_ned: np.ndarray, f: float, depth_m: float) -> float:
    """a_d: the a of Eq. 37 seen from depth_m straight above the corners' centroid (yaw-invariant)."""
    cam = corners_ned.mean(axis=0) - np.array([0.0, 0.0, depth_m])
    uv = virtual_pixels(virtual_points(corners_ned, cam[None], np.zeros(1)), f)
    return float(moments(uv).a[0])


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Radians into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
