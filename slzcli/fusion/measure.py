"""One frame's depth as per-cell height measurements of the fused grid, each with its noise.

The depth is reduced to samples of inverse depth (planes stay planes) on the grid of blocks as coarse as still
puts ``samples_per_cell`` samples across a cell at the frame's median depth, each the mean over a window as wide
as a cell there (``sample_window_px``: a sample's noise moves it sideways, and the fused heights would be blurred
by it), back-projected, moved into the world (gravity-aligned, z up) by the frame's pose and binned into cells:
per cell the mean height of its samples is one measurement, whatever the number of samples, because
the stereo error of neighbouring pixels is correlated: many pixels of one frame are not many looks.

Noise of one measurement (``sigma_z = a_b z^2``, slz's own estimate): ``a_b`` at the cell's side in pixels
``b`` (``DepthNoise.a_at``, the pyramid measured on the depth itself), at the cell's mean depth, projected
on the vertical along the cell's viewing ray (a point's depth error moves it along its ray). Split into a
part that is new in every frame (``white_fraction``) and a part that moves with the camera's view (the rest,
``grid.fuse`` decorrelates it with the cell's shift in the image). Plus the pose: ``pose_sigma_m`` and
``pose_sigma_deg`` times the cell's distance from the camera in plan. A last part (``fixed_fraction``) is
fixed to the ground (the texture's own matching error): no motion averages it, so it is not in the filter
but added to every fused variance (``grid.region``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.fusion import kernels
from slzcli.geometry import fit_intrinsics, pixel_rays
from slzcli.terrain.geometry import DEPTH_SUBSAMPLE, median_depth_m
from slzcli.terrain.noise import DepthNoise
from slzcli.types import Intrinsics

_MIN_SAMPLES = 2      # samples a cell needs in a frame to count as measured (one sample has no spread)


@dataclass(frozen=True)
class FusionParams:
    """What the fusion needs from the config (``terrain.fusion``, the UAV, the mask and the limits)."""

    cell_m: float
    side_cells: int
    samples_per_cell: float
    white_fraction: float
    fixed_fraction: float
    cells_per_footprint: float
    decorrelation_px: float
    gate_sigma: float
    two_heights_fraction: float
    pose_sigma_m: float
    pose_sigma_rad: float
    confidence_sigma: float
    decided_margin: float       # a square is decided when its noise limits are this far within the tolerances
    unsafe_margin: float        # ... and its failing mask a finding when they are this far within
    max_step_m: float
    max_slope_deg: float
    column_m: float             # the descent column's height above a site (control.desired_depth_m)
    column_step_m: float        # the column above it checked for overhangs at levels this far apart
    border_sigma: float         # a frame measures cells this many sideways noise reaches inside its image border
    square_m: float             # side of the square a landing needs clear (the mask's footprint + margins)

    @classmethod
    def from_config(cls, config: Config) -> FusionParams:
        f = config.terrain.fusion
        uav, mc = config.uav, config.mask
        cell = max(uav.footprint_m) / f.cells_per_footprint
        return cls(cell_m=cell, side_cells=max(8, math.ceil(f.window_m / cell)), samples_per_cell=f.samples_per_cell,
                   white_fraction=f.white_fraction, fixed_fraction=f.fixed_fraction,
                   cells_per_footprint=f.cells_per_footprint,
                   decorrelation_px=f.decorrelation_px, gate_sigma=f.gate_sigma,
                   two_heights_fraction=f.two_heights_fraction, pose_sigma_m=f.pose_sigma_m,
                   pose_sigma_rad=math.radians(f.pose_sigma_deg),
                   confidence_sigma=config.terrain.limits.confidence_sigma,
                   decided_margin=f.decided_margin, unsafe_margin=f.unsafe_margin, max_step_m=uav.max_step_m,
                   max_slope_deg=uav.max_slope_deg, column_m=config.control.desired_depth_m,
                   column_step_m=f.column_step_m, border_sigma=f.border_sigma,
                   square_m=mc.margin_factor * max(uav.footprint_m) + 2.0 * uav.clearance_m)


@dataclass(frozen=True, eq=False)
class FrameCells:
    """One frame's measurements: one row per cell it saw (arrays of equal length)."""

    ix: np.ndarray           # int64 cell column (world x / cell_m, floored)
    iy: np.ndarray           # int64 cell row (world y / cell_m, floored)
    height_m: np.ndarray     # float64 mean height of the cell's samples
    spread_m: np.ndarray     # float64 std of the samples' heights inside the cell
    sigma_w_m: np.ndarray    # float64 std of the part of the error that is new in this frame
    sigma_c_m: np.ndarray    # float64 std of the part that moves with the view
    pose_var_m2: np.ndarray  # float64 variance added by the pose
    camera_m: np.ndarray     # (3,) camera position in the world
    T_world_camera: np.ndarray
    intrinsics: Intrinsics
    depth_m: float           # the frame's median depth
    step_per_sigma: float    # the frame's smallest detectable step / its cell-height std (limits.working_scale)
    tan_slope_per_sigma: float  # tan(smallest detectable slope) / its cell-height std, 1/m
    depth_image: np.ndarray  # float32 the frame's depth (m, 0 none), the intrinsics' size: what it saw free
    pixel_a: float           # a of one pixel's depth noise, sigma = a z^2 (the estimate's finest scale)

    def __len__(self) -> int:
        return int(self.ix.size)

    def pixels(self, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Image (column, row) of the cells' centres at their measured heights (cells ``cell_m`` wide)."""
        u, v, _ = project_cells(self.ix, self.iy, self.height_m, self.T_world_camera, self.intrinsics, cell_m)
        return u, v


@dataclass(frozen=True, eq=False)
class CellView:
    """Cells' centres in one frame's camera, the part that does not depend on their height: projections at
    several heights (a cell's estimate, its descent column) share it."""

    xy: tuple[np.ndarray, np.ndarray, np.ndarray]   # camera x, y, z of (centre - camera) at the camera's height
    r_z: np.ndarray                                  # the camera axes' world-z components (R[2, :])
    t_z: float
    intr: Intrinsics

    def at(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel (u, v) of the centres at heights ``h``, and whether they are in front of the camera."""
        pz = h - self.t_z
        xc = self.xy[0] + self.r_z[0] * pz
        yc = self.xy[1] + self.r_z[1] * pz
        zc = self.xy[2] + self.r_z[2] * pz
        intr = self.intr
        with np.errstate(divide="ignore", invalid="ignore"):
            return intr.fx * xc / zc + intr.cx, intr.fy * yc / zc + intr.cy, zc > 0


def cell_view(ix: np.ndarray, iy: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics,
              cell_m: float) -> CellView:
    T = np.asarray(T_world_camera, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    px = (ix + 0.5) * cell_m - t[0]
    py = (iy + 0.5) * cell_m - t[1]
    xy = (R[0, 0] * px + R[1, 0] * py, R[0, 1] * px + R[1, 1] * py, R[0, 2] * px + R[1, 2] * py)
    return CellView(xy, R[2, :].copy(), float(t[2]), intr)


def project_cells(ix: np.ndarray, iy: np.ndarray, h: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics,
                  cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (u, v) of cell centres at heights ``h`` in a frame, and whether they are in front of it."""
    return cell_view(ix, iy, T_world_camera, intr, cell_m).at(h)


def sample_block_px(depth_m: float, focal_px: float, params: FusionParams) -> int:
    """Block side (px) of the samples: the coarsest that keeps ``samples_per_cell`` across a cell at ``depth_m``."""
    px_m = depth_m / focal_px
    return max(1, math.floor(params.cell_m / (params.samples_per_cell * px_m)))


def sample_window_px(block: int, depth_m: float, focal_px: float, cell_m: float) -> int:
    """Side (px) of the window each sample averages: the widest within a cell at ``depth_m`` of the block's parity
    (so that it is centred where the block is), at least the block.

    Why a cell and not the block: a sample's depth error moves it along its ray, ``sigma sin(theta)`` sideways,
    and it is binned where it lands, so the fused heights are blurred by the samples' noise. Off nadir that blur
    hid a ramp's 0.10-0.17 m side drop from the step fit (read 0.02-0.04 m; gaussian 0.003 at 10 m, blocks of
    1 px, 0.3 m each, ~0.13 m sideways at 25 deg). Averaging over the cell cuts a sample's independent noise to
    the cell mean's (``cell_sigma_m``, what the measurement is said to carry anyway) at the price of a blur of
    at most a cell, which the step fit's middle column leaves out (METHOD 2.3.6)."""
    side = cell_m * focal_px / max(depth_m, 1e-6)
    return block + 2 * max(0, math.floor((side - block) / 2.0))


def window_depths(depth: np.ndarray, block: int, window: int) -> np.ndarray:
    """Per block of a ``block`` grid (``(H // block) x (W // block)``, as ``terrain.geometry.block_depth``'s): the
    depth of the mean inverse depth over the ``window`` x ``window`` pixels centred where the block's centre is
    (the window's parity is the block's; cut by the image's border), 0 where fewer than half the window's pixels
    in the image have depth.

    Two ways to the same sums: when every pixel is a sample (block 1, from ~10 m on a 640 x 480 camera) cv2's
    box filter (float32, the window's few pixels: rounding only), 0.38 ms a 640 x 480 frame against 1.0 ms by
    the compiled sliding sums (``kernels.window_depth``), which are faster once samples are sparser (0.32 ms
    against 0.81 at blocks of 3, windows of 7), as they sum only the blocks' rows."""
    d = kernels.readonly(depth, np.float32)
    if block > 1:
        return kernels.window_depth(d, block, window)
    inv, valid = kernels.inverse_depth(d)
    num = cv2.boxFilter(inv, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(valid, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    lo, hi = window // 2, window - 1 - window // 2

    def inside(n: int) -> np.ndarray:     # pixels of each window within the image's side
        c = np.arange(n)
        return (np.minimum(n - 1, c + hi) - np.maximum(0, c - lo) + 1).astype(np.float32)

    return kernels.window_ratio(num, den, inside(d.shape[0]), inside(d.shape[1]))


def cell_sigma_m(noise: DepthNoise, depth_m: np.ndarray | float, focal_px: float, cell_m: float) -> np.ndarray:
    """Std of one frame's mean depth over a cell at ``depth_m``: a_b z^2 with b the cell's side in pixels there."""
    z = np.asarray(depth_m, dtype=np.float64)
    b = cell_m * focal_px / np.maximum(z, 1e-6)
    a = np.interp(np.log(np.maximum(b, 1.0)), _LOG_SCALES, _a_vector(noise))
    return np.exp(a) * z * z


_SCALES = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
_LOG_SCALES = np.log(_SCALES)


@functools.lru_cache(maxsize=8)
def _a_vector(noise: DepthNoise) -> np.ndarray:
    """log a at ``_SCALES`` (one noise estimate serves many frames: computed once)."""
    out = np.log(np.maximum(np.array([noise.a_at(b) for b in _SCALES]), 1e-12))
    out.setflags(write=False)
    return out


def frame_median_m(depth_m: np.ndarray) -> float | None:
    """``terrain.geometry.median_depth_m`` (a float32 frame's by one compiled pass)."""
    if depth_m.dtype != np.float32 or depth_m.ndim != 2:
        return median_depth_m(depth_m)
    z = float(kernels.median_depth(kernels.readonly(depth_m, np.float32), DEPTH_SUBSAMPLE))
    return z if math.isfinite(z) else None


def frame_cells(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray, noise: DepthNoise,
                params: FusionParams, step_per_sigma: float, tan_slope_per_sigma: float,
                z_med: float | None = None) -> FrameCells | None:
    """The cells a frame saw and their height measurements (None: no depth). ``T_world_camera``: gravity-aligned;
    ``z_med``: the frame's median depth when the caller has it.

    The samples are binned by one compiled loop (``kernels.bin_samples``: numpy's passes over ~100,000 samples
    were most of the fusion's time); samples without depth, or beyond the window, are skipped there."""
    depth = np.asarray(depth_m, dtype=np.float32)
    if z_med is None:
        z_med = frame_median_m(depth)
    if z_med is None:
        return None
    intr = fit_intrinsics(intrinsics, depth.shape)
    f = 0.5 * (intr.fx + intr.fy)
    m = sample_block_px(z_med, f, params)
    win = sample_window_px(m, z_med, f, params.cell_m)
    if win > 1:
        a = window_depths(depth, m, win)
        intr_b = fit_intrinsics(intr, a.shape)
    else:
        a, intr_b = depth, intr
    rx, ry = pixel_rays(intr_b)
    T = np.asarray(T_world_camera, dtype=np.float64)
    t = T[:3, 3]
    # a sample's cell in float32 relative to the camera's (4 um at 50 m), the camera's own cell added as integers
    inv = 1.0 / params.cell_m
    cxy = (math.floor(t[0] * inv), math.floor(t[1] * inv))
    rad2 = params.pose_sigma_rad ** 2 if params.pose_sigma_rad > 0 else 0.0
    found, cells_x, cells_y, h, spread, zc, upc, pose_var = kernels.bin_frame(
        a, rx, ry, T[:3, :3], t[0] % params.cell_m, t[1] % params.cell_m, inv, params.side_cells // 2 - 1,
        _MIN_SAMPLES, t, params.cell_m, cxy, params.pose_sigma_m ** 2, rad2)
    if not found:
        return None
    sigma = cell_sigma_m(noise, zc, f, params.cell_m) * upc
    wf = params.white_fraction
    sw = sigma * math.sqrt(wf)
    sc = sigma * math.sqrt(1.0 - wf - params.fixed_fraction)
    return within_border(FrameCells(cells_x, cells_y, h, spread, sw, sc, pose_var, t.copy(), T, intr, z_med,
                                    step_per_sigma, tan_slope_per_sigma, kernels.readonly(depth, np.float32),
                                    float(noise.a1_per_m)), zc, params)


def border_px(pixel_a: float, depth_m: np.ndarray | float, intr: Intrinsics, params: FusionParams) -> np.ndarray:
    """How far inside the image border a frame measures a cell at depth ``depth_m`` (px): ``border_sigma`` times the
    sideways reach of one pixel's depth error at the image's farthest side, ``a_1 z x r`` (a depth error ``a_1 z^2``
    moves a sample along its ray, ``r / f`` of it sideways, ``f / z`` px a metre)."""
    half = max(intr.cx, intr.width - intr.cx, intr.cy, intr.height - intr.cy)
    return params.border_sigma * pixel_a * half * np.asarray(depth_m, np.float64)


def within_border(m: FrameCells, depth_m: np.ndarray, params: FusionParams) -> FrameCells | None:
    """The frame's cells whose centre, at its measured height, lies ``border_px`` at their depth ``depth_m`` or more
    inside the image (None: none). A cell at the edge of what the frame sees gets the samples its noise pushed
    outwards (too far: low) and none pushed in from beyond the view: its mean is biased, and only there (METHOD
    2.3.6). Each cell's own depth: a tilted camera's far side reaches farther."""
    if params.border_sigma <= 0 or m.pixel_a <= 0:
        return m
    margin = border_px(m.pixel_a, depth_m, m.intrinsics, params)
    intr = m.intrinsics
    u, v, front = project_cells(m.ix, m.iy, m.height_m, m.T_world_camera, intr, params.cell_m)
    with np.errstate(invalid="ignore"):
        keep = (front & (u >= margin - 0.5) & (u <= intr.width - 0.5 - margin)
                & (v >= margin - 0.5) & (v <= intr.height - 0.5 - margin))
    if keep.all():
        return m
    if not keep.any():
        return None
    return replace(m, **{f: getattr(m, f)[keep] for f in ("ix", "iy", "height_m", "spread_m", "sigma_w_m",
                                                          "sigma_c_m", "pose_var_m2")})


def frame_limit_ratios(noise: DepthNoise, depth_m: float, focal_px: float, config: Config,
                       params: FusionParams) -> tuple[float, float]:
    """(smallest detectable step, tan of the smallest detectable slope) of one frame at ``depth_m``
    (``limits.working_scale``: the per-frame path's honest limits), each divided by the std of one cell's
    height there. A cell fused to std s then detects steps of ``step_per_sigma x s``: the same windows, the
    noise of every band reduced alike."""
    from slzcli.terrain.limits import working_scale

    work = working_scale(noise, depth_m, focal_px, config.terrain, config.uav)
    sigma = float(cell_sigma_m(noise, depth_m, focal_px, params.cell_m))
    if sigma <= 0:
        return 0.0, 0.0
    return work.step_min_m / sigma, math.tan(math.radians(work.slope_min_deg)) / sigma


def measure_frame(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray, noise: DepthNoise,
                  config: Config, params: FusionParams) -> FrameCells | None:
    """``frame_cells`` with the frame's limit ratios from its own noise and median depth."""
    z = frame_median_m(np.asarray(depth_m))
    if z is None:
        return None
    intr = fit_intrinsics(intrinsics, np.asarray(depth_m).shape)
    step, tan = frame_limit_ratios(noise, z, 0.5 * (intr.fx + intr.fy), config, params)
    return frame_cells(depth_m, intrinsics, T_world_camera, noise, params, step, tan, z)
