"""The four synthetic corner points of Eq. 10: the IBVS target around the chosen site."""

from __future__ import annotations

import numpy as np


def square_corners(center_world: np.ndarray, footprint_m: tuple[float, float]) -> np.ndarray:
    """``P* = P~ + (+-L1, +-L2, 0)`` in the paper's order (++, +-, -+, --); (4, 3) world metres.

    The offsets are along the world x and y axes (z up), so the square is level whatever the
    ground's small tilt; the paper adds the points to the SLAM map the same way.
    """
    l1, l2 = footprint_m
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.float64)
    corners = np.repeat(np.asarray(center_world, np.float64)[None], 4, axis=0)
    corners[:, :2] += signs * np.array([l1, l2])
    return corners
