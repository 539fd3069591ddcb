"""The fused grid: world-fixed, gravity-aligned cells of one map segment, and the per-cell Kalman update.

Cells. Cell (ix, iy) covers world x in [ix c, (ix + 1) c), y likewise, c = ``FusionParams.cell_m`` (the
footprint / ``cells_per_footprint``): fixed in the map frame, so a cell means the same ground in every
frame (a grid centred on the vehicle and blended index by index, as PX4's safe_landing_planner does,
mixes ground whenever the vehicle moves). Memory is a window of ``side_cells`` x ``side_cells`` slots
that follows the UAV: cell (ix, iy) lives in slot (iy mod side, ix mod side) with its indices as the
slot's owner; a cell that comes into view where an older one, ``side_cells`` away, still sits takes the
slot over. Memory is fixed (38 MB at the defaults) however long the flight.

State per cell. The measurement of a frame (``measure.FrameCells``) is ``y = h + c + w``: the height h,
an error c that the frame's stereo pattern shares with the next frames as long as the cell stays where
it was in the image, and an error w new in every frame. c is an Ornstein-Uhlenbeck process in the cell's
image position: between two looks that moved the cell by d pixels in the image, ``c' = rho c + e`` with
``rho = exp(-d / decorrelation_px)`` (measured, METHOD 2.3.6). A two-state Kalman filter per cell on (h, c)
is then the exact least-squares estimate under that model: hovering, c never decorrelates and the
height's variance stops at var(c); flying, every decorrelation length adds a look. The update is
vectorised over the frame's cells.

Gating. A measurement is rejected when its innovation exceeds ``gate_sigma`` times the std of the
innovation, which holds the cell's variance *and* the measurement's (and the pose's): a new cell's
variance is its first measurement's, so nothing is wiped for being noisy (ETH elevation_mapping's
variance clamp sets cells above 0.03^2 m^2 to infinity, every D435 cell at 8 m). A cell whose frames are
rejected more than ``two_heights_fraction`` of the time holds two heights (an overhang seen from two
sides, a pole, something moving): it is refused, never safe.

Noise scale. Every look also adds its normalised innovation squared to the cell; what a region reports is
scaled by their mean over the landing footprint around each cell (``noise_scale``): the ground's own excess
over the stated noise, where it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.fusion import kernels
from slzcli.fusion.measure import FrameCells, FusionParams

_EMPTY = np.iinfo(np.int64).min      # owner of a slot no cell has used yet
_RHO_MAX = 1.0 - 1e-9               # guards 1 - rho^2 against round-off


def cell_key(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """One int64 per cell (indices within +-2^31 cells: +-176,000 km at 8 cm)."""
    return (np.asarray(ix, np.int64) << 32) ^ (np.asarray(iy, np.int64) & 0xFFFFFFFF)


@dataclass(frozen=True, eq=False)
class FusedGrid:
    """The cells of one map segment (arrays updated in place by ``fuse``; the dataclass itself never changes).

    Slot k = (iy mod side) side + (ix mod side). ``state[k]`` holds the float fields (H, C: the height and
    the shared error; PHH, PHC, PCC: their covariance; SIGC, SIG1: the shared error's std and one frame's
    std at the last look; U, V: the cell's image position then; SPREAD: the largest within-cell height
    std of an accepted frame; POSEV: the smallest pose variance; STEPR, TANR: the last look's limit ratios;
    NISS, NISN: the sum of its looks' normalised innovations squared and their number).
    """

    params: FusionParams
    owner: np.ndarray       # int64 (side^2,): cell_key of the cell in each slot (_EMPTY: none)
    state: np.ndarray       # float64 (side^2, kernels.FIELDS)
    frames: np.ndarray      # int32 frames that measured the cell
    rejected: np.ndarray    # int32 of them rejected by the gate
    column: np.ndarray      # uint64: the levels of the column above the cell some frame saw free (kernels.update_cells)
    blocked: np.ndarray     # uint64: the levels some frame had in view with something at or in front of them
    last_frame: np.ndarray  # int64 index of the last frame that measured it
    swept_at: np.ndarray    # int64 (2,): the camera's cell at the last sweep of cells left behind

    @classmethod
    def empty(cls, params: FusionParams) -> FusedGrid:
        n = params.side_cells * params.side_cells
        return cls(params, np.full(n, _EMPTY, np.int64), np.zeros((n, kernels.FIELDS), np.float64),
                   np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(n, np.uint64), np.zeros(n, np.uint64),
                   np.full(n, -1, np.int64), np.array([_EMPTY, _EMPTY], np.int64))

    def nbytes(self) -> int:
        return sum(getattr(self, f).nbytes for f in self.__dataclass_fields__ if f != "params")

    def slots(self, ix: np.ndarray, iy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(slot, owned) of cells: their slot, and whether it holds that cell (else: unseen there)."""
        s = self.params.side_cells
        k = np.mod(iy, s) * s + np.mod(ix, s)
        return k, self.owner[k] == cell_key(ix, iy)


@dataclass(frozen=True)
class FuseStats:
    """What one frame did to the grid."""

    cells: int           # cells it measured
    new: int             # of them seen for the first time (or taking over a slot)
    rejected: int        # measurements the gate rejected
    median_shift_px: float   # median image shift of its cells since their last look
    nis_median: float        # median normalised innovation squared of its cells seen before (chi-square 1: 0.455)


def fuse(grid: FusedGrid, m: FrameCells, frame_index: int, gate_scale: float = 1.0) -> FuseStats:
    """Add one frame's measurements to the grid (in place): two compiled loops over the frame's cells
    (``kernels``), the decorrelation's ``exp`` between them.

    Per cell: predict the shared error by the cell's image shift since its last look (the cell's centre at its
    estimated height projected into the frame: the mean pixel of its samples jitters with the depth noise, which
    moves samples across cell borders, and a hover would seem to move); gate the innovation on the cell's
    variance, the measurement's and the pose's, the innovation's variance widened by ``gate_scale`` (how much the
    frame's innovations exceed the stated noise, ``FusedTerrain.gate_scale``: the gate is for outliers, and a noise
    estimate that reads low would otherwise reject good looks and refuse their cells as holding two heights);
    update accepted looks, start new cells at h = y, c = 0 with the
    covariance of a flat prior, keep rejected ones. The update proper leaves the pose out: a frame's pose error
    is common to its cells (a height offset, a tilt over the view), not terrain; it widens the gate and the
    reported variance only."""
    p = grid.params
    intr = m.intrinsics
    T = np.asarray(m.T_world_camera, dtype=np.float64)
    r, t = np.ascontiguousarray(T[:3, :3]), np.array(T[:3, 3])
    cam = np.array([intr.fx, intr.fy, intr.cx, intr.cy], np.float64)
    ix, iy = np.ascontiguousarray(m.ix, np.int64), np.ascontiguousarray(m.iy, np.int64)
    y = np.ascontiguousarray(m.height_m, np.float64)
    k, owned, u_px, v_px, shift = kernels.cell_shifts(grid.owner, grid.state, ix, iy, y, p.side_cells, p.cell_m, r,
                                                      t, cam)
    rho = np.exp(-shift / p.decorrelation_px)
    np.minimum(rho, _RHO_MAX, out=rho)

    def f64(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, np.float64)

    new, rejected, nis = kernels.update_cells(
        grid.owner, grid.state, grid.frames, grid.rejected, grid.column, grid.blocked, grid.last_frame, k, owned, u_px,
        v_px, rho, ix, iy, y, f64(m.sigma_w_m), f64(m.sigma_c_m), f64(m.spread_m), f64(m.pose_var_m2),
        p.gate_sigma ** 2, float(gate_scale), max(1.0 - p.fixed_fraction, 1e-9), float(m.step_per_sigma),
        float(m.tan_slope_per_sigma), int(frame_index), float(p.column_m), float(p.column_step_m), float(p.cell_m), r,
        t, cam, m.depth_image,
        float(m.pixel_a), float(p.confidence_sigma), _nadir_in_view(r, cam, intr.width, intr.height))
    _sweep(grid, m)
    med = float(kernels.median_inplace(shift[owned]))
    return FuseStats(len(m), int(new), int(rejected), med, float(kernels.median_inplace(nis)))


def _nadir_in_view(r: np.ndarray, cam: np.ndarray, width: int, height: int) -> bool:
    """The image of the point straight below the camera (the vanishing point of vertical lines) lies in the view."""
    dz = -r[2, 2]                  # the world's down in camera coordinates: -(R's third row)
    if dz <= 0:
        return False
    u = cam[0] * -r[2, 0] / dz + cam[2]
    v = cam[1] * -r[2, 1] / dz + cam[3]
    return bool(-0.5 <= u < width - 0.5 and -0.5 <= v < height - 0.5)


def sweep_due(grid: FusedGrid, m: FrameCells) -> tuple[int, int] | None:
    """The camera's cell when a sweep is due (it has moved an eighth of a window since the last), recorded as
    the last sweep's; None: not yet."""
    s = grid.params.side_cells
    cx = int(np.floor(m.camera_m[0] / grid.params.cell_m))
    cy = int(np.floor(m.camera_m[1] / grid.params.cell_m))
    last = grid.swept_at
    if last[0] != _EMPTY and max(abs(cx - int(last[0])), abs(cy - int(last[1]))) < max(1, s // 8):
        return None
    grid.swept_at[:] = (cx, cy)
    return cx, cy


def _sweep(grid: FusedGrid, m: FrameCells) -> None:
    """Forget the cells more than half a window from the camera (in x or y), each time it has moved an
    eighth of a window: the window holds the ground around the UAV, nothing it left behind."""
    due = sweep_due(grid, m)
    if due is not None:
        kernels.sweep(grid.owner, due[0], due[1], grid.params.side_cells // 2, int(_EMPTY))


@dataclass(frozen=True, eq=False)
class Region:
    """A rectangle of cells copied out of the window: row j, column i is cell (x0 + i, y0 + j)."""

    x0: int
    y0: int
    cell_m: float
    seen: np.ndarray        # bool: the slot holds this cell
    h: np.ndarray           # float64 (NaN unseen)
    var: np.ndarray         # float64 height variance of the terrain estimate (NaN unseen)
    pose_var: np.ndarray    # float64
    looks: np.ndarray       # float32 independent looks: one frame's variance / the fused one
    frames: np.ndarray      # int32
    rejected: np.ndarray    # int32
    spread: np.ndarray      # float32
    step_ratio: np.ndarray  # float32
    tan_ratio: np.ndarray   # float32
    column: np.ndarray      # bool: the descent column above the cell clear (kernels.column_clear)
    p_hc: np.ndarray        # float64 the Kalman state's other covariances (for ``advice``)
    p_cc: np.ndarray
    sigma_c: np.ndarray     # float64 std of the shared error at the last look
    sigma_1: np.ndarray     # float64 std of one frame's measurement at the last look

    @property
    def shape(self) -> tuple[int, int]:
        return self.seen.shape

    @property
    def origin_m(self) -> tuple[float, float]:
        return self.x0 * self.cell_m, self.y0 * self.cell_m


def region(grid: FusedGrid, x0: int, y0: int, nx: int, ny: int) -> Region:
    """Cells x0..x0+nx-1, y0..y0+ny-1 as dense arrays (``nx``, ``ny`` at most the window's side), gathered by one
    compiled pass (``kernels.region_cells``). The terrain's variance adds the part fixed to the ground, which
    never averages (``fixed_fraction`` of one frame's variance); its looks are one frame's variance over it; every
    variance is scaled by the ground's own noise scale (``noise_scale``)."""
    s = grid.params.side_cells
    nx, ny = min(nx, s), min(ny, s)
    seen, f64, looks, frames, rejected, f32, column, nis = kernels.region_cells(
        grid.owner, grid.state, grid.frames, grid.rejected, grid.column, grid.blocked, int(x0), int(y0), int(nx),
        int(ny), int(s), float(grid.params.fixed_fraction))
    kernels.scale_variances(f64, noise_scale(nis[0], nis[1], grid.params.cells_per_footprint))
    h, var, pose_var, p_hc, p_cc, sig_c, sig1 = f64
    return Region(x0, y0, grid.params.cell_m, seen, h, var, pose_var, looks, frames, rejected, f32[0], f32[1], f32[2],
                  column, p_hc, p_cc, sig_c, sig1)


def noise_scale(nis_sum: np.ndarray, nis_n: np.ndarray, window_cells: float) -> np.ndarray:
    """Per cell: how much the measurements of the ground around it scatter beyond their stated noise, the mean
    normalised innovation squared of every look at the cells of the ``window_cells`` square around it (a landing
    footprint), never below 1: an adaptive filter's noise scale, local. Why local: ground that measures worse than
    the camera's noise estimate (relief within a cell, a car's edge that the samples' sideways blur mixes with the
    asphalt) scales only itself; one scale for the whole view, set by a parking lot's cars (half of what a frame
    sees), stated the level asphalt 1.4-1.8 times too noisy and left the cars' own cells overconfident. Why a
    footprint and not the cell alone: the verdict takes the worst cell of a landing square, and ~20 looks of one
    cell scatter their mean by ~0.3, pooled over a footprint's ~64 cells by ~0.04."""
    n = max(1, round(window_cells))

    def box(a: np.ndarray) -> np.ndarray:       # float32: sums of at most a few 10,000 looks
        return np.asarray(cv2.boxFilter(a.astype(np.float32), -1, (n, n), normalize=False,
                                        borderType=cv2.BORDER_CONSTANT))

    num, den = box(nis_sum), box(nis_n)
    q = np.ones(num.shape)
    np.divide(num, den, out=q, where=den > 0)
    return np.maximum(q, 1.0, out=q)


def region_around(grid: FusedGrid, x_m: float, y_m: float, side_m: float) -> Region:
    """The square of ``side_m`` (at most the window) centred on world (x_m, y_m)."""
    cm = grid.params.cell_m
    n = min(grid.params.side_cells, max(1, int(np.ceil(side_m / cm))))
    return region(grid, int(np.floor(x_m / cm)) - n // 2, int(np.floor(y_m / cm)) - n // 2, n, n)


def seen_bounds(grid: FusedGrid) -> tuple[int, int, int, int] | None:
    """(x0, y0, nx, ny) of the cells the window holds (None: none)."""
    held = grid.owner != _EMPTY
    if not held.any():
        return None
    keys = grid.owner[held]
    xs = keys >> 32
    ys = (keys & 0xFFFFFFFF).astype(np.int64)
    ys = np.where(ys >= 1 << 31, ys - (1 << 32), ys)
    x0, y0 = int(xs.min()), int(ys.min())
    return x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1
