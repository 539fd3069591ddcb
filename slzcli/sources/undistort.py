"""Lens distortion removed before the maps and SLAM: every later stage assumes a pinhole camera.

The ROS models (sensor_msgs/distortion_models): ``plumb_bob`` (k1 k2 p1 p2 k3) and
``rational_polynomial`` (k1 k2 p1 p2 k3 k4 k5 k6) are OpenCV's own coefficient order;
``equidistant`` (k1 k2 k3 k4) is OpenCV's fisheye model. The undistorted image keeps the
size and K of the original (``cv2.initUndistortRectifyMap`` with newK = K), so the intrinsics
only lose their distortion. Colour is resampled bilinearly, depth by nearest neighbour (a
depth is never blended across an edge); pixels that map outside the source are holes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import cv2
import numpy as np

from slzcli.types import Intrinsics

PINHOLE_MODELS = ("plumb_bob", "rational_polynomial")
FISHEYE_MODELS = ("equidistant", "fisheye")
SUPPORTED = (*PINHOLE_MODELS, *FISHEYE_MODELS)
# coefficients each model takes (OpenCV accepts 4, 5, 8, 12 or 14 for the pinhole models)
N_COEFFS = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4, "fisheye": 4}


def has_distortion(k: Intrinsics) -> bool:
    return any(abs(v) > 0.0 for v in k.distortion)


def distortion_problem(k: Intrinsics) -> str | None:
    """Why slz cannot undistort this camera (None: it can, or there is nothing to undo)."""
    if not has_distortion(k):
        return None
    model = k.distortion_model.strip().lower()
    if model not in SUPPORTED:
        return (f"distortion model {k.distortion_model or '(unnamed)'!r} is not one slz can undo (plumb_bob, "
                "rational_polynomial, equidistant): images used as they are, geometry off towards the edges")
    n = N_COEFFS[model]
    extra = k.distortion[n:]
    if len(k.distortion) < n and model in FISHEYE_MODELS:
        return f"{model} needs {n} coefficients, got {len(k.distortion)}: images used as they are"
    if any(abs(v) > 0.0 for v in extra) and model in FISHEYE_MODELS:
        return f"{model} takes {n} coefficients, got {len(k.distortion)} with non-zero extras: images used as they are"
    return None


def _coeffs(k: Intrinsics) -> np.ndarray:
    model = k.distortion_model.strip().lower()
    d = np.asarray(k.distortion, dtype=np.float64)
    if model in FISHEYE_MODELS:
        return d[:4].reshape(4, 1)
    n = max(N_COEFFS[model], 4)
    out = np.zeros(n if n in (4, 5, 8) else 8)
    out[: min(d.size, out.size)] = d[: out.size]
    return out


@dataclass(frozen=True, eq=False)
class UndistortMaps:
    """``cv2.remap`` maps of one camera at one size."""

    map_x: np.ndarray
    map_y: np.ndarray
    intrinsics: Intrinsics    # the undistorted camera: same K and size, no distortion


@functools.lru_cache(maxsize=8)
def undistort_maps(k: Intrinsics) -> UndistortMaps | None:
    """The maps for ``k``, or None when there is nothing to undo or slz cannot (``distortion_problem``)."""
    if not has_distortion(k) or distortion_problem(k) is not None:
        return None
    K = k.K
    size = (int(k.width), int(k.height))
    if k.distortion_model.strip().lower() in FISHEYE_MODELS:
        mx, my = cv2.fisheye.initUndistortRectifyMap(K, _coeffs(k), np.eye(3), K, size, cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(K, _coeffs(k), None, K, size, cv2.CV_32FC1)
    return UndistortMaps(mx, my, replace(k, distortion_model="", distortion=()))


def undistort_color(rgb: np.ndarray, maps: UndistortMaps) -> np.ndarray:
    return cv2.remap(rgb, maps.map_x, maps.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def undistort_depth(depth_m: np.ndarray, maps: UndistortMaps) -> np.ndarray:
    return cv2.remap(depth_m, maps.map_x, maps.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float("nan"))


def normalised_rays(k: Intrinsics, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of a (possibly distorted) image -> undistorted normalised (x, y) with z = 1.

    Distortion slz cannot undo (``distortion_problem``) is ignored here: the caller warns.
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    if not has_distortion(k) or distortion_problem(k) is not None:
        return (u - k.cx) / k.fx, (v - k.cy) / k.fy
    pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
    if k.distortion_model.strip().lower() in FISHEYE_MODELS:
        out = cv2.fisheye.undistortPoints(pts, k.K, _coeffs(k))
    else:
        out = cv2.undistortPoints(pts, k.K, _coeffs(k))
    out = out.reshape(-1, 2)
    return out[:, 0].reshape(u.shape), out[:, 1].reshape(v.shape)
