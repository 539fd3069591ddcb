"""The fused terrain of one run: a grid per map segment, fed every tracked frame, asked for its verdict.

This is the state the fusion keeps across frames; everything it does is in ``measure``, ``grid``,
``verdict`` and ``advice``. Only the current map segment's grid is kept: a new segment's poses are in
another frame, so its cells start empty (``slam/segments.py``), and the memory stays one window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from slzcli.config import Config
from slzcli.fusion import kernels
from slzcli.fusion.advice import Advice, advise
from slzcli.fusion.grid import FusedGrid, FuseStats, fuse, region, region_around
from slzcli.fusion.measure import FusionParams, measure_frame
from slzcli.fusion.verdict import SAFE, FusedMaps, FusedSite, best_site, fused_maps
from slzcli.geometry import fit_intrinsics, pixel_rays
from slzcli.terrain.geometry import median_depth_m
from slzcli.terrain.noise import DepthNoise
from slzcli.types import Intrinsics

_RECENT = 15                 # frames the motion and the gate's scale are taken over (1 s at 15 Hz)
_CHI2_1_MEDIAN = 0.454936   # median of a chi-square variable of one degree of freedom


@dataclass
class FusedTerrain:
    """The run's fused terrain (mutable: it is the state of a stateful method)."""

    config: Config
    scorer: object
    params: FusionParams = field(init=False)
    segment: int | None = None
    grid: FusedGrid | None = None
    frames: int = 0
    last: FuseStats | None = None
    shifts: list[float] = field(default_factory=list)     # recent median image shifts per frame
    depth_m: float = math.nan
    focal_px: float = math.nan
    noise: DepthNoise | None = None
    camera_m: np.ndarray | None = None
    nis: list[float] = field(default_factory=list)         # recent frames' median innovation scale (chi-square 1: 1)
    view: tuple[int, int, int, int] | None = None          # (x0, y0, x1, y1): the last frame's cells, inclusive

    def __post_init__(self) -> None:
        self.params = FusionParams.from_config(self.config)
        kernels.warm_up()     # the compiled loops ready before the run's first (timed) frame

    def add(self, depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray | None,
            noise: DepthNoise, segment: int, frame_index: int) -> FuseStats | None:
        """Fuse one tracked frame (no pose: nothing to fuse)."""
        if T_world_camera is None:
            return None
        if segment != self.segment or self.grid is None:
            self.segment, self.grid = segment, FusedGrid.empty(self.params)
            self.shifts.clear()
            self.nis.clear()
        cells = measure_frame(depth_m, intrinsics, T_world_camera, noise, self.config, self.params)
        stats = None
        if cells is not None:
            stats = fuse(self.grid, cells, frame_index, self.gate_scale())
            if math.isfinite(stats.nis_median):
                self.nis = [*self.nis, stats.nis_median / _CHI2_1_MEDIAN][-_RECENT:]
            self.last = stats
            if math.isfinite(stats.median_shift_px):
                self.shifts = [*self.shifts, stats.median_shift_px][-_RECENT:]
            self.depth_m = cells.depth_m
            self.focal_px = 0.5 * (cells.intrinsics.fx + cells.intrinsics.fy)
            self.noise = noise
            self.camera_m = cells.camera_m
            self.view = (int(cells.ix.min()), int(cells.iy.min()), int(cells.ix.max()), int(cells.iy.max()))
        self.frames += 1
        return stats

    def gate_scale(self) -> float:
        """How much the gate widens the innovations' stated variance (>= 1): the running median over the recent
        frames of their normalised squares over chi-square's median. For the gate only (outliers are beyond what
        the ground measures, and the noise estimate can read low: synth D435 on asphalt 0.091 m estimated per cell
        against 0.145 m; real D435 frames at 0.9 m); what the map states is scaled where the ground is
        (``grid.noise_scale``), not by the frame's median, which a parking lot's cars set for its asphalt too."""
        return max(1.0, float(np.median(self.nis))) if self.nis else 1.0

    def shift_per_frame_px(self) -> float:
        return float(np.median(self.shifts)) if self.shifts else 0.0

    def maps_around(self, x_m: float, y_m: float, side_m: float) -> FusedMaps | None:
        if self.grid is None:
            return None
        return fused_maps(region_around(self.grid, x_m, y_m, side_m), self.config, self.params, self.scorer)

    def maps_in_view(self) -> FusedMaps | None:
        """The fused maps of the cells the last frame saw and two landing squares around them (the verdict's
        windows reach 1.3 m; beyond, the flatness saturates), within a square around the camera of 2.5 times
        its depth (at most the window). Not the whole square: a D435's view covers 1.9 x 1.1 times the depth,
        a quarter of it, and the maps cost by the cell."""
        if self.grid is None or self.camera_m is None or self.view is None or not math.isfinite(self.depth_m):
            return None
        cm = self.params.cell_m
        side = min(self.config.terrain.fusion.window_m, 2.5 * self.depth_m + 4 * self.params.square_m)
        n = min(self.params.side_cells, max(1, math.ceil(side / cm)))
        sx, sy = math.floor(self.camera_m[0] / cm) - n // 2, math.floor(self.camera_m[1] / cm) - n // 2
        pad = math.ceil(2 * self.params.square_m / cm)
        x0, y0 = max(sx, self.view[0] - pad), max(sy, self.view[1] - pad)
        x1, y1 = min(sx + n - 1, self.view[2] + pad), min(sy + n - 1, self.view[3] + pad)
        if x1 < x0 or y1 < y0:
            return None
        return fused_maps(region(self.grid, x0, y0, x1 - x0 + 1, y1 - y0 + 1), self.config, self.params, self.scorer)

    def site(self, fm: FusedMaps) -> FusedSite | None:
        return best_site(fm)

    def advice(self, fm: FusedMaps, hover: bool | None = None) -> Advice | None:
        """What would decide the best undecided ground (``advise``; ``hover``: the UAV holds position)."""
        if self.noise is None or not math.isfinite(self.depth_m):
            return None
        from slzcli.terrain.limits import working_scale

        work = working_scale(self.noise, self.depth_m, self.focal_px, self.config.terrain, self.config.uav)
        return advise(fm, self.params, self.shift_per_frame_px(), self.depth_m, self.focal_px, work.step_min_m,
                      math.tan(math.radians(work.slope_min_deg)), hover)


def pixel_cells(fm: FusedMaps, depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray) -> np.ndarray:
    """Per pixel of a frame: the flat index (row j, column i: j nx + i) of its cell in the region (its point on
    the ground, by its depth); the region's size where it has no depth or falls outside (``cells_in_frame``)."""
    depth = kernels.readonly(np.asarray(depth_m), np.float32)
    intr = fit_intrinsics(intrinsics, depth.shape)
    rx, ry = pixel_rays(intr)
    T = np.asarray(T_world_camera, dtype=np.float64)
    t = T[:3, 3]
    reg = fm.region
    ox, oy = reg.origin_m
    ny, nx = reg.shape
    # the cell's column and row in float32 (whole numbers, exact below 2^24), one compiled pass
    f32 = np.float32
    return kernels.pixel_cells(depth, kernels.readonly(rx.reshape(-1), f32), kernels.readonly(ry.reshape(-1), f32),
                               np.array(T[:3, :3], f32), f32(t[0] - ox), f32(t[1] - oy), f32(1.0 / reg.cell_m), nx, ny)


def cells_in_frame(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """A per-cell map of the region at every pixel of a frame (``pixel_cells``; 0 / False where no cell)."""
    flat = values.reshape(-1)
    return np.append(flat, np.zeros(1, flat.dtype))[index]


def render_in_frame(values: np.ndarray, fm: FusedMaps, depth_m: np.ndarray, intrinsics: Intrinsics,
                    T_world_camera: np.ndarray) -> np.ndarray:
    """A per-cell float map of the region at every pixel of a frame (0 where no depth or outside)."""
    return cells_in_frame(values.astype(np.float32), pixel_cells(fm, depth_m, intrinsics, T_world_camera))


def verdict_in_frame(fm: FusedMaps, depth_m: np.ndarray, intrinsics: Intrinsics,
                     T_world_camera: np.ndarray) -> np.ndarray:
    """Per pixel of a frame: its cell's verdict is SAFE (the fused mask rendered into the frame's pixels)."""
    return cells_in_frame(fm.verdict == SAFE, pixel_cells(fm, depth_m, intrinsics, T_world_camera))


def frame_depth_m(depth_m: np.ndarray) -> float | None:
    return median_depth_m(np.asarray(depth_m))
