"""The site rule of PX4-Avoidance's waypoint generator (``runEvaluateGrid``), on one grid update.

Upstream (``safe_landing_planner/src/nodes/waypoint_generator.cpp``): after loitering, the
per-cell hysteresis is thresholded (``> can_land_thr``); a disk of radius ``smoothing_land_cell``
cells (``hypot(i - r, j - r) < r + 0.5``) must be land-able in every cell. The disk under the
vehicle (the grid's centre cell ``n / 2``) is tried first, then outwards along the 8 directions of
``exploration_pattern`` (+x, +x+y, +y, -x+y, -x, -x-y, -y, +x-y), one cell further per ring, in
that order, while the disk stays inside the grid; the first disk that passes is the goal, at
``position + offset x cell_size`` in plan (upstream's ``goal_``). None passes: upstream flies its
square spiral and looks again; a recording cannot move the vehicle, so that is "no site" here.

Pure functions of arrays; the grid comes from ``scoring/px4slp.py`` (passed as arrays, no import).
"""

from __future__ import annotations

import numpy as np

from slzcli.geometry import project, transform_points
from slzcli.landing.corners import square_corners
from slzcli.records import SITE_FROM_PX4SLP
from slzcli.types import Candidate, Selection, Site

# waypoint_generator.hpp exploration_pattern, in its order
EXPLORATION_PATTERN = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)])


def patch_disk(radius_cells: int) -> np.ndarray:
    """``initializeMask``: the (2r+1)^2 disk of cells a landing patch must have all land-able."""
    i, j = np.mgrid[0:2 * radius_cells + 1, 0:2 * radius_cells + 1]
    return np.hypot(i - radius_cells, j - radius_cells) < radius_cells + 0.5


def search_offsets(cells: int, radius_cells: int, stride: int = 1) -> np.ndarray:
    """Patch-centre offsets (cells, from the grid centre) in upstream's order: (0, 0), then ring by ring."""
    n_iterations = (1 + (cells - (2 * radius_cells + 1)) // stride) // 2
    rings = np.arange(1, max(n_iterations, 1))
    ring_offsets = (rings[:, None, None] * stride * EXPLORATION_PATTERN[None, :, :]).reshape(-1, 2)
    return np.concatenate([np.zeros((1, 2), np.int64), ring_offsets]).astype(np.int64)


def choose_patch(can_land: np.ndarray, radius_cells: int) -> tuple[int, int] | None:
    """The first patch centre offset (upstream's order) whose disk is land-able in every cell, or None."""
    n = can_land.shape[0]
    k = 2 * radius_cells + 1
    if n < k:
        return None
    disk = patch_disk(radius_cells)
    windows = np.lib.stride_tricks.sliding_window_view(can_land, (k, k))  # (n-k+1)^2 windows by upper corner
    full = (windows & disk).sum(axis=(2, 3)) == disk.sum()
    offsets = search_offsets(n, radius_cells)
    corners = n // 2 + offsets - radius_cells
    ok = np.all((corners >= 0) & (corners <= n - k), axis=1)
    hit = np.zeros(len(offsets), bool)
    hit[ok] = full[corners[ok, 0], corners[ok, 1]]
    if not hit.any():
        return None
    di, dj = offsets[int(np.argmax(hit))]
    return int(di), int(dj)


def grid_site(hysteresis: np.ndarray, mean: np.ndarray, position: np.ndarray, cell_m: float, radius_cells: int,
              can_land_thr: float, xyz_world: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray,
              mask: np.ndarray, footprint_m: tuple[float, float],
              edge_distance_m: np.ndarray | None = None) -> Selection:
    """The waypoint generator's goal as a ``Selection`` over the keyframe's map points ``xyz_world``.

    ``hysteresis`` and ``mean``: the grid update (rows along world x). The site is the goal in plan
    at the mean height of the patch's cells; its normal and normal variance come from the patch's
    cell heights (the grid's own surface; upstream keeps none). Upstream has no tilt or edge test,
    so the site is accepted as the planner would land on it; tilt and edge clearance are reported.
    Map points within the disk in plan are the site's cluster, those on the mask are ``kept``.
    """
    n = hysteresis.shape[0]
    pixels, inside = project(xyz_world, T_world_camera, K, mask.shape)
    kept = np.zeros(len(xyz_world), bool)
    iu = np.round(pixels[inside]).astype(int)
    kept[np.flatnonzero(inside)] = mask[iu[:, 1], iu[:, 0]]
    labels = np.full(len(xyz_world), -1)
    chosen = choose_patch(hysteresis > can_land_thr, radius_cells)
    if chosen is None:
        return Selection(None, f"no disk of {2 * radius_cells + 1} cells ({(2 * radius_cells + 1) * cell_m:g} m) "
                               "land-able in every cell on the planner's search rays (upstream would fly its "
                               "spiral search; a recording cannot)", (), pixels, kept, labels,
                         int(np.count_nonzero(inside)))
    offset = np.asarray(chosen)
    disk = patch_disk(radius_cells)
    centre_cell = n // 2 + offset
    rows = slice(centre_cell[0] - radius_cells, centre_cell[0] + radius_cells + 1)
    cols = slice(centre_cell[1] - radius_cells, centre_cell[1] + radius_cells + 1)
    heights = mean[rows, cols]
    goal_xy = np.asarray(position, np.float64)[:2] + offset * cell_m
    centre = np.array([goal_xy[0], goal_xy[1], float(heights[disk].mean())])
    normal, normal_var = _patch_normal(heights, disk, cell_m)
    tilt = float(np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0))))
    members = np.hypot(*(xyz_world[:, :2] - goal_xy).T) < (radius_cells + 0.5) * cell_m
    labels[members] = 0
    (uv,), (uv_inside,) = project(centre[None], T_world_camera, K, mask.shape)
    clearance = None
    if edge_distance_m is not None and uv_inside:
        clearance = float(edge_distance_m[round(float(uv[1])), round(float(uv[0]))])
    extent = (float(disk.sum(axis=0).max() * cell_m),) * 2
    score = float(hysteresis[rows, cols][disk].mean())
    site = Site(
        pixel=(float(uv[0]), float(uv[1])), center_camera=_vec3(transform_points(np.linalg.inv(T_world_camera),
                                                                                 centre)),
        center_world=_vec3(centre), corners_world=tuple(_vec3(c) for c in square_corners(centre, footprint_m)),
        normal_world=_vec3(normal), cluster_points=int(members.sum()), normal_variance=normal_var, extent_m=extent,
        score=score, tilt_deg=tilt, edge_clearance_m=clearance, accepted=True,
        acceptance_reason="passed (px4slp: every cell of the disk land-able; upstream has no tilt or edge test)",
        source=SITE_FROM_PX4SLP)
    candidate = Candidate(0, int(members.sum()), _vec3(centre), normal_var, extent, True,
                          f"disk at ({offset[0]:+d}, {offset[1]:+d}) cells from the vehicle land-able")
    return Selection(site, "", (candidate,), pixels, kept, labels, int(np.count_nonzero(inside)))


def _patch_normal(heights: np.ndarray, disk: np.ndarray, cell_m: float) -> tuple[np.ndarray, float]:
    """Mean unit normal of the patch's cells (height gradients) and ``1 - |mean n|^2`` over the disk."""
    gx, gy = np.gradient(heights, cell_m)
    normals = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)[disk]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    m = normals.mean(axis=0)
    return m / np.linalg.norm(m), float(1.0 - np.sum(m ** 2))


def _vec3(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
