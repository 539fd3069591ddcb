"""Depth registered to the colour camera: each depth pixel reprojected, z-buffered, holes kept.

A depth camera that is not the colour camera (a RealSense's left imager, 848x480, 15-60 mm
beside the colour sensor) sees the scene from elsewhere and through other intrinsics: resizing
its image to the colour size puts every depth on the wrong colour pixel. Here each valid depth
pixel is a small square patch at its depth: its centre is back-projected (through the depth
camera's distortion), moved by ``T_color_depth`` and projected into the colour camera (pinhole:
the colour image is undistorted first), its size scaled with it. Every colour pixel whose centre lies inside
the patch's projected bounding box gets the patch's depth (as librealsense's align does), so a
coarser depth grid leaves no sampling gaps; where patches overlap the nearest wins (z-buffer,
``np.minimum.at``). A colour pixel no valid depth patch covers (a hole in the depth, or a part
of the scene the depth camera cannot see) stays NaN.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from slzcli.sources.undistort import normalised_rays
from slzcli.types import Intrinsics

# A patch covers at most this many colour pixels across (the colour grid being up to this much finer
# than the depth grid); a larger bounding box is a patch seen edge-on at a depth discontinuity, and is
# clipped around its centre rather than smeared over the image. Project decision: a 1280x720 colour
# stream over a 424x240 depth stream is a ratio of 3.
MAX_FOOTPRINT_PX = 4


@dataclass(frozen=True, eq=False)
class DepthRays:
    """Per depth pixel: the undistorted normalised ray through its centre (x, y; z = 1) and its size
    (the spacing of the rays through its corners, sx across and sy down), float32, h x w flattened."""

    x: np.ndarray
    y: np.ndarray
    sx: np.ndarray
    sy: np.ndarray


@functools.lru_cache(maxsize=4)
def depth_rays(k: Intrinsics) -> DepthRays:
    """The rays of every pixel of camera ``k`` (computed once per camera: undistortion is iterative)."""
    v, u = np.mgrid[0:k.height + 1, 0:k.width + 1].astype(np.float64) - 0.5
    cx, cy = normalised_rays(k, u, v)                 # corners (u - 0.5, v - 0.5)
    x, y = normalised_rays(k, u[:-1, :-1] + 0.5, v[:-1, :-1] + 0.5)
    sx = 0.5 * ((cx[:-1, 1:] - cx[:-1, :-1]) + (cx[1:, 1:] - cx[1:, :-1]))
    sy = 0.5 * ((cy[1:, :-1] - cy[:-1, :-1]) + (cy[1:, 1:] - cy[:-1, 1:]))
    f32 = np.float32
    return DepthRays(*(a.astype(f32).ravel() for a in (x, y, np.abs(sx), np.abs(sy))))


def register_depth(depth_m: np.ndarray, k_depth: Intrinsics, T_color_depth: np.ndarray,
                   k_color: Intrinsics) -> np.ndarray:
    """``depth_m`` (the depth camera's image, metres, NaN = none) as seen by the colour camera.

    ``k_depth`` must describe ``depth_m``'s size (scale it first); ``k_color`` is the pinhole
    colour camera (after undistortion) and sets the output size. Returns float32 metres, NaN = none.
    The patch of a depth pixel is its ray spacing at its depth, projected with the colour camera's
    focal lengths at the transformed depth (exact for a translation; a rotation of a few degrees, as
    between the sensors of one camera, changes a patch's size by well under a pixel).
    """
    rays = depth_rays(k_depth)
    H, W = int(k_color.height), int(k_color.width)
    out = np.full(H * W, np.inf, dtype=np.float32)
    z = np.where(depth_m > 0, depth_m, np.float32(np.nan)).astype(np.float32, copy=False).ravel()
    T = np.asarray(T_color_depth, dtype=np.float32)
    R, t = T[:3, :3], T[:3, 3]
    # Whole-grid arithmetic (no gathers): holes are NaN and drop out below.
    x, y = rays.x * z, rays.y * z
    Z = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.float32(1.0) / Z
        uc = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]) * inv * np.float32(k_color.fx) + np.float32(k_color.cx)
        vc = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]) * inv * np.float32(k_color.fy) + np.float32(k_color.cy)
        scale = z * inv
        ok = np.flatnonzero((Z > 0) & (uc > -W) & (uc < 2 * W) & (vc > -H) & (vc < 2 * H))
    if ok.size:
        Z, uc, vc, scale = Z[ok], uc[ok], vc[ok], scale[ok]
        hu = np.float32(0.5 * k_color.fx) * rays.sx[ok] * scale
        hv = np.float32(0.5 * k_color.fy) * rays.sy[ok] * scale
        c0, c1 = _cover(uc - hu, uc + hu, uc)
        r0, r1 = _cover(vc - hv, vc + hv, vc)
        np.maximum(c0, 0, out=c0)
        np.minimum(c1, W - 1, out=c1)
        np.maximum(r0, 0, out=r0)
        np.minimum(r1, H - 1, out=r1)
        nc, nr = c1 - c0, r1 - r0                       # the footprint's extent - 1 (negative: off the image)
        inside = (nc >= 0) & (nr >= 0)
        if not inside.all():
            c0, r0, nc, nr, Z = c0[inside], r0[inside], nc[inside], nr[inside], Z[inside]
        if Z.size:
            base = r0 * W + c0
            for dr in range(int(nr.max()) + 1):
                for dc in range(int(nc.max()) + 1):
                    if dr == dc == 0:
                        np.minimum.at(out, base, Z)
                        continue
                    m = (nr >= dr) & (nc >= dc)
                    np.minimum.at(out, base[m] + (dr * W + dc), Z[m])
    out[out == np.inf] = np.nan
    return out.reshape(H, W)


def _cover(lo: np.ndarray, hi: np.ndarray, mid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last pixel index whose centre lies in [lo, hi); the nearest pixel to ``mid`` when none does.

    Boxes wider than MAX_FOOTPRINT_PX are cut to that width around their middle.
    """
    first = np.ceil(lo).astype(np.int32)
    last = np.ceil(hi).astype(np.int32) - 1
    nearest = np.rint(mid).astype(np.int32)
    np.copyto(first, nearest, where=last < first)
    np.maximum(last, first, out=last)
    wide = last - first + 1 > MAX_FOOTPRINT_PX
    if wide.any():
        first[wide] = nearest[wide] - MAX_FOOTPRINT_PX // 2
        last[wide] = first[wide] + MAX_FOOTPRINT_PX - 1
    return first, last
