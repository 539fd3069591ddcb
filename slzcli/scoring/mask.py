"""The landing mask (METHOD 2.4): a safety-margin minimum filter of the score, then a global threshold.

``mask.clearance: plan`` (the default) takes the minimum in plan view: every pixel is placed
on the ground plane (back-projected, then projected along gravity) in cells of
``footprint / mask.plan_cells_per_footprint``, each cell keeps the worst score that falls in it,
and a pixel is safe when every cell of the footprint square around its own cell is observed and
good. The image-space window below is wrong exactly where it matters: seen obliquely, the ground
under a tree's canopy or beside a tall object lies far from it in the image but inside the
footprint in plan (measured on the synth playground at 5 m: mask precision 0.74 in image space).
Unobserved cells (occlusion shadows, beyond the view) count as unsafe; a cell missed between
observed neighbours (sparse far-field sampling) takes the worst of them.

``mask.clearance: image`` is the paper's minimum filter in the image:

The window is square, of side ``margin_factor x max(L1, L2)`` metres (the UAV footprint;
the larger side, since the yaw at touch-down is not known), converted to pixels at the
frame's median valid depth (``side_m x fx / depth`` wide, ``side_m x fy / depth`` high): one
window per frame, as the paper's minimum filter is one image operation; on a steep oblique view
the near part of the image gets a slightly small margin and the far part a large one. The side is rounded up to an
odd pixel count so the window is centred. Outside the image counts as 0 (unknown is
unsafe): a site must fit inside the view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.terrain.geometry import fit_intrinsics, median_depth_m, pixel_rays, valid_depth, window_px
from slzcli.types import Intrinsics, ScoreMap

_GAP_NEIGHBOURS = 5        # an unobserved cell with at least this many observed 8-neighbours is a sampling gap
MAX_PLAN_CELLS = 4 << 20   # cells of the plan raster; coarser cells beyond (a view of 80 m at 4 cm)


def min_filter(score: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """Minimum of the score over a width x height window (cv2.erode; outside the image = 0).

    A window wider or taller than the image reaches outside it from every pixel, so the result
    is 0 everywhere: returned without building the kernel (``uav.footprint_m=[1000, 1000]`` made
    a 5 GB one, ``[1e6, 1e6]`` asked for 414 TiB).
    """
    if width_px <= 1 and height_px <= 1:
        return score.copy()
    if width_px > score.shape[1] or height_px > score.shape[0]:
        return np.zeros_like(score)
    kernel = np.ones((height_px, width_px), np.uint8)
    return cv2.erode(score, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)


def smooth(score: np.ndarray, sigma_x_px: float, sigma_y_px: float) -> np.ndarray:
    """Gaussian blur whose kernel is cut at the image's own size.

    OpenCV sizes a float kernel at 8 sigma + 1: ``mask.smooth_m=1000`` made a 616,000-tap
    kernel and minutes of work per frame. A tap further away than the image is wide only sees
    the border's reflection, so the kernel stops at 2 x the image side + 1 (the same result up
    to those reflected taps, and always when the blur is narrower than the image).
    """
    h, w = score.shape[:2]

    def ksize(sigma: float, side: int) -> int:
        full = round(sigma * 8 + 1) | 1
        return min(full, 2 * side + 1)

    return cv2.GaussianBlur(score, (ksize(sigma_x_px, w), ksize(sigma_y_px, h)), sigmaX=sigma_x_px,
                            sigmaY=sigma_y_px)


def landing_mask(method: str, score: np.ndarray, depth_m: np.ndarray, fx: float, fy: float,
                 footprint_m: tuple[float, ...], margin_factor: float, threshold: float,
                 smooth_m: float = 0.0, *, plan: tuple[Intrinsics, np.ndarray, float] | None = None,
                 margin_m: float = 0.0, points: CameraPoints | None = None) -> ScoreMap:
    """ScoreMap(method, score, mask): mask = min-filtered score > threshold (all False without depth).

    ``plan``: (intrinsics, world up in the camera frame, cells per footprint side) takes the minimum
    in plan view (``plan_min_filter``); None, the paper's square window in the image. ``points``: the
    frame's ``camera_points``, when already made (the plan filter needs them).

    ``smooth_m`` > 0 first blurs the score with a Gaussian of that sigma on the ground: the
    minimum over a footprint of ~1000 pixels is otherwise the worst single pixel, which at
    range is sensor noise rather than terrain (measured on synth: the fuzzy mask goes from
    empty to precision 0.95-0.98).
    """
    depth = median_depth_m(depth_m)
    if depth is None:
        return ScoreMap(method, score, np.zeros(score.shape, bool))
    if smooth_m > 0:
        score_in = smooth(score, smooth_m * fx / depth, smooth_m * fy / depth)
    else:
        score_in = score
    side_m = margin_factor * max(footprint_m) + 2.0 * margin_m
    if plan is not None:   # (intrinsics, world up in the camera, cells per footprint side)
        filtered = plan_min_filter(score_in, depth_m, plan[0], plan[1], side_m, plan[2], points=points)
    else:
        filtered = min_filter(score_in, window_px(side_m, fx, depth), window_px(side_m, fy, depth))
    return ScoreMap(method, score, filtered > threshold)


@dataclass(frozen=True, eq=False)
class CameraPoints:
    """Eq. 1 as three float32 planes (X, Y, Z; NaN where no depth) and the validity: the column rule
    and the plan filter both need them, so ``mask_score`` back-projects once (planes, not an
    H x W x 3 image: every use below is per coordinate)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    valid: np.ndarray


def camera_points(depth_m: np.ndarray, intrinsics: Intrinsics) -> CameraPoints:
    """The same values as ``back_project`` (z rx, z ry, z in float32), one plane per coordinate."""
    depth = np.asarray(depth_m)
    intr = fit_intrinsics(intrinsics, depth.shape)
    rx, ry = pixel_rays(intr)
    valid = valid_depth(depth)
    z = np.where(valid, depth, np.float32(np.nan)).astype(np.float32, copy=False)
    return CameraPoints(np.multiply(z, rx), np.multiply(z, ry), z, valid)


def column_in_view(depth_m: np.ndarray, intrinsics: Intrinsics, up_camera: np.ndarray, height_m: float, *,
                   points: CameraPoints | None = None, among: np.ndarray | None = None) -> np.ndarray:
    """Pixels whose column up to ``height_m`` above them projects into the image.

    The UAV comes down that column in its final descent; what stands in it is only known where
    the camera saw it. Near the image border the column leaves the view (from 5 m, a point 60 % of
    the way to the border has its 2 m column outside): a tree crown out of the frame can overhang
    ground that looks open (synth playground at 5 m: mask precision 0.77 without this, 0.96 with).
    The footprint's clearance around the column is the plan filter's business, not repeated here.
    ``points``: ``camera_points`` of the frame, when already made. ``among``: only these pixels are
    tested (the rest are False), e.g. the ones the mask still calls safe.
    """
    p = camera_points(depth_m, intrinsics) if points is None else points
    if among is None:
        x, y, z, valid = p.x, p.y, p.z, p.valid
    else:
        idx = np.flatnonzero(among)
        x, y, z, valid = (a.reshape(-1)[idx] for a in (p.x, p.y, p.z, p.valid))
    u = np.asarray(up_camera, dtype=np.float32) / np.float32(np.linalg.norm(up_camera))
    lift = np.float32(height_m) * u
    with np.errstate(invalid="ignore", divide="ignore"):
        z = z + lift[2]
        cu = intrinsics.fx * (x + lift[0]) / z + intrinsics.cx
        cv_ = intrinsics.fy * (y + lift[1]) / z + intrinsics.cy
        inside = ((z > 0) & (cu >= -0.5) & (cu <= intrinsics.width - 0.5)
                  & (cv_ >= -0.5) & (cv_ <= intrinsics.height - 0.5))
    inside &= valid
    if among is None:
        return inside
    out = np.zeros(p.valid.shape, bool)
    out.reshape(-1)[idx] = inside
    return out


def plan_axes(up_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the ground plane (orthogonal to world up), the first along the camera's x."""
    u = np.asarray(up_camera, dtype=np.float64)
    u = u / np.linalg.norm(u)
    for ref in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])):
        e1 = ref - (ref @ u) * u
        if np.linalg.norm(e1) > 1e-6:
            break
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def plan_min_filter(score: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics, up_camera: np.ndarray,
                    side_m: float, cells_per_side: float, *, points: CameraPoints | None = None) -> np.ndarray:
    """Per pixel: the worst score within the side_m square around it in plan view (0 where unknown).

    Whole-frame arrays throughout (pixels without depth go to one spare cell that reads 0) rather
    than gathering the valid points: the gathers and the N x 3 float64 copy were most of its time.
    """
    p = camera_points(depth_m, intrinsics) if points is None else points
    ok = p.valid
    if not ok.any():
        return np.zeros(score.shape, np.float32)
    e1, e2 = plan_axes(up_camera)
    x, y = _along(p, e1), _along(p, e2)             # plan coordinates, NaN where no depth
    x0, y0 = float(np.fmin.reduce(x, axis=None)), float(np.fmin.reduce(y, axis=None))   # fmin skips the NaN
    span = max(float(np.fmax.reduce(x, axis=None)) - x0, float(np.fmax.reduce(y, axis=None)) - y0)
    cell = side_m / cells_per_side
    cell = max(cell, span / math.sqrt(MAX_PLAN_CELLS))
    ix, iy = _cell_index(x, x0, cell, ok), _cell_index(y, y0, cell, ok)
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    spare = ny * nx                                  # the cell of every pixel without depth
    flat = iy
    flat *= nx
    flat += ix
    np.copyto(flat, spare, where=~ok)
    worst = np.full(spare + 1, np.inf, np.float32)
    np.minimum.at(worst, flat.reshape(-1), np.ascontiguousarray(score, np.float32).reshape(-1))
    raster = worst[:spare].reshape(ny, nx)
    seen = np.isfinite(raster)
    seen_u8 = seen.view(np.uint8)
    neighbours = cv2.boxFilter(seen_u8, cv2.CV_16U, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    gap = ~seen & (neighbours >= _GAP_NEIGHBOURS)
    big = np.float32(np.finfo(np.float32).max)
    nearby_worst = cv2.erode(np.where(seen, raster, big), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                             borderValue=float(big))
    raster = np.where(seen, raster, np.where(gap, nearby_worst, np.float32(0)))
    n = max(1, 2 * math.ceil((side_m / cell - 1) / 2) + 1)
    cleared = np.zeros(spare + 1, np.float32)        # the spare cell stays 0: no depth is unsafe
    cleared[:spare] = min_filter(raster.astype(np.float32), n, n).reshape(-1)
    return np.take(cleared, flat)


def _along(p: CameraPoints, axis: np.ndarray) -> np.ndarray:
    """The points' float32 coordinate along a unit ``axis`` (NaN where no depth): two OpenCV passes.

    float32 is ample: at 50 m its rounding is ~4 um against cells of centimetres (the float64 version
    took a third of the mask's time; the masks of benchmarks/stages.py's 46 frames are unchanged).
    """
    a = [float(c) for c in np.asarray(axis, dtype=np.float64)]
    out = cv2.addWeighted(p.x, a[0], p.y, a[1], 0.0)
    return cv2.scaleAdd(p.z, a[2], out, dst=out)


def _cell_index(coord: np.ndarray, origin: float, cell: float, ok: np.ndarray) -> np.ndarray:
    """int32 cell of each coordinate from ``origin`` (0 where not ``ok``); overwrites ``coord``.

    Clipped to the raster's side: depths near float32's limit (3e38 m) overflow the difference to
    inf, which would cast to a negative index."""
    coord -= np.float32(origin)
    coord *= np.float32(1.0 / cell)
    np.clip(coord, 0.0, math.ceil(math.sqrt(MAX_PLAN_CELLS)), out=coord)
    np.copyto(coord, 0.0, where=~ok)
    return coord.astype(np.int32)
