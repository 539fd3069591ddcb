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

import cv2
import numpy as np

from slzcli.terrain.geometry import back_project, median_depth_m, window_px
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
                 margin_m: float = 0.0) -> ScoreMap:
    """ScoreMap(method, score, mask): mask = min-filtered score > threshold (all False without depth).

    ``plan``: (intrinsics, world up in the camera frame, cells per footprint side) takes the minimum
    in plan view (``plan_min_filter``); None, the paper's square window in the image.

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
        filtered = plan_min_filter(score_in, depth_m, plan[0], plan[1], side_m, plan[2])
    else:
        filtered = min_filter(score_in, window_px(side_m, fx, depth), window_px(side_m, fy, depth))
    return ScoreMap(method, score, filtered > threshold)


def column_in_view(depth_m: np.ndarray, intrinsics: Intrinsics, up_camera: np.ndarray, height_m: float) -> np.ndarray:
    """Pixels whose column up to ``height_m`` above them projects into the image.

    The UAV comes down that column in its final descent; what stands in it is only known where
    the camera saw it. Near the image border the column leaves the view (from 5 m, a point 60 % of
    the way to the border has its 2 m column outside): a tree crown out of the frame can overhang
    ground that looks open (synth playground at 5 m: mask precision 0.77 without this, 0.96 with).
    The footprint's clearance around the column is the plan filter's business, not repeated here.
    """
    pts = back_project(depth_m, intrinsics)
    u = np.asarray(up_camera, dtype=np.float32) / np.float32(np.linalg.norm(up_camera))
    top = pts + np.float32(height_m) * u
    with np.errstate(invalid="ignore", divide="ignore"):
        z = top[..., 2]
        cu = intrinsics.fx * top[..., 0] / z + intrinsics.cx
        cv_ = intrinsics.fy * top[..., 1] / z + intrinsics.cy
        inside = ((z > 0) & (cu >= -0.5) & (cu <= intrinsics.width - 0.5)
                  & (cv_ >= -0.5) & (cv_ <= intrinsics.height - 0.5))
    return inside & np.isfinite(pts[..., 2])


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
                    side_m: float, cells_per_side: float) -> np.ndarray:
    """Per pixel: the worst score within the side_m square around it in plan view (0 where unknown)."""
    pts = back_project(depth_m, intrinsics).reshape(-1, 3)
    ok = np.isfinite(pts[:, 2])
    out = np.zeros(score.size, np.float32)
    if not ok.any():
        return out.reshape(score.shape)
    e1, e2 = plan_axes(up_camera)
    p = pts[ok].astype(np.float64)
    x, y = p @ e1, p @ e2
    x0, y0 = float(x.min()), float(y.min())
    cell = side_m / cells_per_side
    span = max(float(x.max()) - x0, float(y.max()) - y0)
    cell = max(cell, span / math.sqrt(MAX_PLAN_CELLS))
    ix = ((x - x0) / cell).astype(np.int64)
    iy = ((y - y0) / cell).astype(np.int64)
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    worst = np.full(ny * nx, np.inf, np.float32)
    flat = iy * nx + ix
    np.minimum.at(worst, flat, score.reshape(-1)[ok].astype(np.float32))
    raster = worst.reshape(ny, nx)
    seen = np.isfinite(raster)
    seen_u8 = seen.view(np.uint8)
    neighbours = cv2.boxFilter(seen_u8, cv2.CV_16U, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    gap = ~seen & (neighbours >= _GAP_NEIGHBOURS)
    big = np.float32(np.finfo(np.float32).max)
    nearby_worst = cv2.erode(np.where(seen, raster, big), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                             borderValue=float(big))
    raster = np.where(seen, raster, np.where(gap, nearby_worst, np.float32(0)))
    n = max(1, 2 * math.ceil((side_m / cell - 1) / 2) + 1)
    cleared = min_filter(raster.astype(np.float32), n, n)
    out[ok] = cleared.reshape(-1)[flat]
    return out.reshape(score.shape)
