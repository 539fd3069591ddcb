"""PX4-Avoidance's ``safe_landing_planner`` grid, reimplemented from its algorithm: the third method, ``px4slp``.

Upstream (BSD-3, deprecated since PX4 v1.15): github.com/PX4/PX4-Avoidance ``safe_landing_planner/``,
``grid.hpp``, ``src/nodes/safe_landing_planner.cpp``, ``waypoint_generator.cpp`` and the defaults of
``cfg/SafeLandingPlannerNode.cfg`` / ``cfg/WaypointGeneratorNode.cfg`` (read at commit c386852).
docs/PX4SLP.md says what is reproduced and what is not.

One update per detection frame, as upstream runs one per point cloud:
- the grid: ``grid_size`` m square, axes along world x and y, centred on the vehicle (here the
  camera's position), ``ceil(grid_size / cell_size)`` cells a side; every valid depth pixel, back-
  projected to the world with the frame's pose, falls in one cell (strictly inside the grid);
- per cell the count, mean and population variance of the points' heights (upstream's Welford
  recursion; here the two-pass formula, the same numbers vectorised);
- mean and variance low-passed cell by cell (by index, as upstream) with the previous update:
  ``alpha * previous + (1 - alpha) * current``; the count is this update's only;
- a cell is land-able with at least ``n_points_threshold`` points and a height std at most
  ``std_dev_threshold``; then the neighbourhood vote over ``(2 smoothing_size + 1)^2`` cells, the grid
  zero-padded: more than ``min_n_land_cells`` land-able neighbours and at most ``max_n_mean_diff_cells``
  neighbours whose mean differs by more than ``mean_diff_thr``;
- the waypoint generator's per-cell hysteresis ``beta * h + (1 - beta) * land`` (its site rule reads
  ``h > can_land_thr``: slzcli/landing/px4slp.py).

The planner has state across frames: ``Px4SlpMemory`` holds the previous update, one per recording
and method, reset at a new SLAM map segment (a new world frame). With ``warm_start`` (a project
decision) the first update of a segment is blended with itself, not with upstream's all-zero grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slzcli.config import Px4SlpCfg
from slzcli.geometry import back_project
from slzcli.types import Intrinsics

NAME = "px4slp"


@dataclass(frozen=True)
class Px4SlpParams:
    """The planner's parameters (``scoring.px4slp``), upstream's names."""

    grid_size_m: float
    cell_size_m: float
    n_points_threshold: float
    std_dev_threshold_m: float
    smoothing_size: int
    mean_diff_thr_m: float
    max_n_mean_diff_cells: int
    min_n_land_cells: int
    alpha: float
    beta: float
    can_land_thr: float
    smoothing_land_cell: int
    warm_start: bool

    @classmethod
    def from_config(cls, c: Px4SlpCfg) -> Px4SlpParams:
        return cls(c.grid_size_m, c.cell_size_m, c.n_points_threshold, c.std_dev_threshold_m, c.smoothing_size,
                   c.mean_diff_thr_m, c.max_n_mean_diff_cells, c.min_n_land_cells, c.alpha, c.beta, c.can_land_thr,
                   c.smoothing_land_cell, c.warm_start)

    @property
    def cells(self) -> int:
        """Cells a side: upstream's ``ceil(grid_size / cell_size)``."""
        return math.ceil(self.grid_size_m / self.cell_size_m)


@dataclass(frozen=True, eq=False)
class GridState:
    """One update of the grid (row index along world x, column along world y, as upstream)."""

    origin_xy: np.ndarray   # (2,) world x, y of the grid's lower corner (vehicle position - grid_size / 2), m
    position: np.ndarray    # (3,) the vehicle (camera) position the grid is centred on, world m
    counter: np.ndarray     # (n, n) int: this update's points per cell
    mean: np.ndarray        # (n, n) low-passed mean height (world z), m; 0 where never seen
    variance: np.ndarray    # (n, n) low-passed height variance, m^2
    land: np.ndarray        # (n, n) bool: land-able after the neighbourhood vote (the node's output)
    hysteresis: np.ndarray  # (n, n) float in [0, 1]: the waypoint generator's smoothed land value
    segment: int            # SLAM map segment of the pose


class Px4SlpMemory:
    """The planner's state across the detection frames of one recording: the previous grid update.

    Mutable on purpose (upstream's ``previous_grid_``); owned by one ``methods.px4slp.GridMethod``, so every
    recording and every method of ``slz compare`` has its own. A new map segment starts afresh.
    """

    def __init__(self) -> None:
        self.previous: GridState | None = None


def cell_index(xy: np.ndarray, origin_xy: np.ndarray, p: Px4SlpParams) -> tuple[np.ndarray, np.ndarray]:
    """Flat cell index (row * n + col) of world points (N, 2) and whether each lies strictly inside the grid."""
    n = p.cells
    rel = xy - origin_xy
    with np.errstate(invalid="ignore"):
        inside = np.all((rel > 0.0) & (rel < p.grid_size_m), axis=1)
    ij = np.clip(np.floor(np.where(inside[:, None], rel, 0.0) / p.cell_size_m).astype(np.int64), 0, n - 1)
    return ij[:, 0] * n + ij[:, 1], inside


def cell_statistics(xyz_world: np.ndarray, origin_xy: np.ndarray,
                    p: Px4SlpParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell: count, mean and population variance (M2 / n, upstream's) of the heights of the points inside."""
    ok = np.isfinite(xyz_world).all(axis=1)
    pts = xyz_world[ok]
    flat, inside = cell_index(pts[:, :2], origin_xy, p)
    return binned_statistics(flat[inside], pts[inside, 2], p.cells)


def binned_statistics(flat: np.ndarray, z: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count, mean and population variance of ``z`` per flat cell index, as (n, n) arrays (two passes)."""
    count = np.bincount(flat, minlength=n * n)
    safe = np.maximum(count, 1)
    mean = np.bincount(flat, weights=z, minlength=n * n) / safe
    var = np.bincount(flat, weights=(z - mean[flat]) ** 2, minlength=n * n) / safe
    return count.reshape(n, n), mean.reshape(n, n), var.reshape(n, n)


def landable(counter: np.ndarray, mean: np.ndarray, variance: np.ndarray, p: Px4SlpParams) -> np.ndarray:
    """``isLandingPossible``: the per-cell test, then (``smoothing_size`` > 0) the neighbourhood vote."""
    land = (counter >= p.n_points_threshold) & ~(np.sqrt(variance) > p.std_dev_threshold_m)
    s = p.smoothing_size
    if s <= 0:
        return land
    k, n = 2 * s + 1, land.shape[0]
    pad_land, pad_mean = np.pad(land.astype(np.int32), s), np.pad(mean, s)  # padding: mean 0, as upstream
    n_land = np.zeros(land.shape, np.int64)
    n_diff = np.zeros(land.shape, np.int64)
    for dk in range(k):  # one row of the window at a time: n x n x k values, not n x n x k x k (s is up to 100)
        n_land += np.lib.stride_tricks.sliding_window_view(pad_land[dk:dk + n], k, axis=1).sum(axis=2)
        row = np.lib.stride_tricks.sliding_window_view(pad_mean[dk:dk + n], k, axis=1)
        n_diff += (np.abs(mean[:, :, None] - row) > p.mean_diff_thr_m).sum(axis=2)
    return (n_land > p.min_n_land_cells) & (n_diff <= p.max_n_mean_diff_cells)


def update(previous: GridState | None, xyz_world: np.ndarray, position: np.ndarray, segment: int,
           p: Px4SlpParams) -> GridState:
    """One planner update on world points (N, 3): bin, low-pass with ``previous``, land-able cells, hysteresis.

    ``previous`` of another map segment is ignored (its world frame is unrelated). Without a previous
    update the grid is blended with itself (``warm_start``) or with upstream's all-zero grid.
    """
    position = np.asarray(position, np.float64)
    origin = position[:2] - p.grid_size_m / 2.0
    counter, mean, var = cell_statistics(xyz_world, origin, p)
    return blend(previous, counter, mean, var, origin, position, segment, p)


def blend(previous: GridState | None, counter: np.ndarray, mean: np.ndarray, var: np.ndarray, origin: np.ndarray,
          position: np.ndarray, segment: int, p: Px4SlpParams) -> GridState:
    """This update's cell statistics low-passed with ``previous`` (see ``update``), land-able cells, hysteresis."""
    fresh = previous is None or previous.segment != segment
    if fresh:
        prev_mean, prev_var = (mean, var) if p.warm_start else (np.zeros_like(mean), np.zeros_like(var))
    else:
        assert previous is not None
        prev_mean, prev_var = previous.mean, previous.variance
    mean = p.alpha * prev_mean + (1.0 - p.alpha) * mean
    var = p.alpha * prev_var + (1.0 - p.alpha) * var
    land = landable(counter, mean, var, p)
    if fresh:
        prev_h = land.astype(np.float64) if p.warm_start else np.zeros(land.shape)
    else:
        assert previous is not None
        prev_h = previous.hysteresis
    hysteresis = p.beta * prev_h + (1.0 - p.beta) * land
    return GridState(origin, position, counter, mean, var, land, hysteresis, segment)


@dataclass(frozen=True)
class Px4SlpPlanner:
    """The grid method as a detection method: depth + pose -> grid update -> pixel score and mask."""

    params: Px4SlpParams
    name: str = NAME

    @classmethod
    def from_config(cls, cfg: Px4SlpCfg) -> Px4SlpPlanner:
        return cls(Px4SlpParams.from_config(cfg))

    def step(self, memory: Px4SlpMemory, depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray,
             segment: int) -> tuple[GridState, np.ndarray]:
        """Update the grid with a frame's depth points; returns the update and each pixel's flat cell index
        (-1: no depth, or outside the grid). float32 points, as upstream's PCL clouds."""
        p = self.params
        pts = back_project(depth_m, intrinsics).reshape(-1, 3)
        valid = np.flatnonzero(np.isfinite(pts[:, 2]))
        xyz = _to_world(T_world_camera, pts[valid])
        position = np.asarray(T_world_camera[:3, 3], np.float64)
        origin = position[:2] - p.grid_size_m / 2.0
        flat, inside = cell_index(xyz[:, :2], origin.astype(np.float32), p)
        stats = binned_statistics(flat[inside], xyz[inside, 2].astype(np.float64), p.cells)
        state = blend(memory.previous, *stats, origin, position, segment, p)
        memory.previous = state
        cells = np.full(pts.shape[0], -1, np.int64)
        cells[valid[inside]] = flat[inside]
        return state, cells.reshape(depth_m.shape)

    def pixels(self, state: GridState, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Back to the image: each pixel's cell's hysteresis (score, float32) and land-able flag (mask, bool).

        Pixels without depth or outside the grid (``cells`` -1) score 0 and are not land-able.
        """
        ok = cells >= 0
        idx = np.where(ok, cells, 0)
        score = np.where(ok, state.hysteresis.astype(np.float32).ravel()[idx], np.float32(0.0))
        mask = ok & state.land.ravel()[idx]
        return score, mask


def _to_world(T: np.ndarray, pc: np.ndarray) -> np.ndarray:
    """``R p + t`` on (N, 3) float32 camera points, column by column: nine multiply-adds per point and no
    BLAS call (a (N, 3) x (3, 3) product is memory-bound; BLAS threads only contend on a busy machine)."""
    R, t = T[:3, :3].astype(np.float32), T[:3, 3].astype(np.float32)
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    out = np.empty_like(pc)
    for k in range(3):  # the three world axes, not points
        np.multiply(x, R[k, 0], out=out[:, k])
        out[:, k] += y * R[k, 1]
        out[:, k] += z * R[k, 2]
        out[:, k] += t[k]
    return out
