"""ORB features as ORB-SLAM3 extracts them (same BRIEF pattern, same pyramid), via OpenCV.

Shared by the built-in odometry and the vocabulary trainer so both see the same descriptors.
"""

from __future__ import annotations

import cv2
import numpy as np


def make_orb(n_features: int, n_levels: int, scale_factor: float, fast_threshold: int) -> cv2.ORB:
    """An OpenCV ORB detector with the paper's pyramid (1000 features, 8 levels, 1.2)."""
    return cv2.ORB.create(nfeatures=n_features, scaleFactor=scale_factor, nlevels=n_levels,
                          fastThreshold=fast_threshold)


def detect(orb: cv2.ORB, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints of an RGB image: pixels (N,2) float64 and descriptors (N,32) uint8."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    kps, desc = orb.detectAndCompute(grey, None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    return np.asarray(cv2.KeyPoint.convert(kps), np.float64), desc


def ratio_matches(query: np.ndarray, train: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (query, train) of Hamming nearest neighbours that pass Lowe's ratio test.

    Two nearest neighbours per query in one OpenCV call (no Python loop over features).
    """
    if len(query) == 0 or len(train) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dist, idx = cv2.batchDistance(query, train, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
    keep = dist[:, 0] < ratio * dist[:, 1]
    return np.flatnonzero(keep), idx[keep, 0].astype(np.int64)
