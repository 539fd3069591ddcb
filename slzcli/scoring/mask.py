"""The landing mask (METHOD 2.4): a safety-margin minimum filter of the score, then a global threshold.

The window is square, of side ``margin_factor x max(L1, L2)`` metres (the UAV footprint;
the larger side, since the yaw at touch-down is not known), converted to pixels at the
frame's median valid depth (``side_m x fx / depth`` wide, ``side_m x fy / depth`` high): one window per frame, as the paper's
minimum filter is one image operation; on a steep oblique view the near part of the image
gets a slightly small margin and the far part a large one. The side is rounded up to an
odd pixel count so the window is centred. Outside the image counts as 0 (unknown is
unsafe): a site must fit inside the view.
"""

from __future__ import annotations


import cv2
import numpy as np

from slzcli.terrain.geometry import median_depth_m, window_px  # noqa: F401 (re-exported for tests)
from slzcli.types import ScoreMap


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
                 smooth_m: float = 0.0) -> ScoreMap:
    """ScoreMap(method, score, mask): mask = min-filtered score > threshold (all False without depth).

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
    side_m = margin_factor * max(footprint_m)
    filtered = min_filter(score_in, window_px(side_m, fx, depth), window_px(side_m, fy, depth))
    return ScoreMap(method, score, filtered > threshold)
