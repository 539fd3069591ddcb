"""The four synthetic corner points of Eq. 10: the IBVS target around the chosen site."""

from __future__ import annotations

import itertools
import math

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


def corners_problem(center_world: np.ndarray, corners_world: np.ndarray, footprint_m: tuple[float, ...],
                    tolerance: float) -> str | None:
    """Why four corners are not the Eq. 10 square of this footprint around this centre, or None.

    In ``square_corners``' order the corners must lie level with the centre, around it, with
    sides 2 L1 and 2 L2 and diagonals of equal length, each within ``tolerance`` x the shorter
    side (a turn about the vertical is allowed). Collinear, coincident or microscopic corners
    used to "land" or end as corners_lost with exit 0.
    """
    l1, l2 = float(footprint_m[0]), float(footprint_m[1])
    c = np.asarray(corners_world, np.float64).reshape(4, 3)
    centre = np.asarray(center_world, np.float64).reshape(3)
    tol_m = tolerance * 2.0 * min(l1, l2)
    off = float(np.linalg.norm(c.mean(axis=0) - centre))
    if off > tol_m:
        return f"the corners' middle is {off:.3g} m from site.center_world"
    dz = float(np.max(np.abs(c[:, 2] - centre[2])))
    if dz > tol_m:
        return f"the corners are not level with site.center_world (up to {dz:.3g} m above or below)"
    want = {(0, 1): 2 * l2, (2, 3): 2 * l2, (0, 2): 2 * l1, (1, 3): 2 * l1,
            (0, 3): 2 * math.hypot(l1, l2), (1, 2): 2 * math.hypot(l1, l2)}
    for i, j in itertools.combinations(range(4), 2):
        d = float(np.linalg.norm(c[i] - c[j]))
        if abs(d - want[i, j]) > tol_m:
            return (f"corners {i} and {j} are {d:.3g} m apart; the Eq. 10 square of uav.footprint_m = "
                    f"[{l1:g}, {l2:g}] puts them {want[i, j]:.3g} m apart")
    return None
