"""One frame's depth as per-cell height measurements of the fused grid, each with its noise.

The depth is reduced to block means of inverse depth (``terrain.geometry.block_depth``: planes stay
planes) as coarse as still puts ``samples_per_cell`` samples across a cell at the frame's median depth,
back-projected, moved into the world (gravity-aligned, z up) by the frame's pose and binned into cells:
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

import math
from dataclasses import dataclass

import numpy as np

from slzcli.config import Config
from slzcli.geometry import fit_intrinsics, pixel_rays, valid_depth
from slzcli.terrain.geometry import block_depth, median_depth_m
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
    decorrelation_px: float
    gate_sigma: float
    two_heights_fraction: float
    pose_sigma_m: float
    pose_sigma_rad: float
    confidence_sigma: float
    target_margin: float
    max_step_m: float
    max_slope_deg: float
    column_m: float             # the descent column's height above a site (control.desired_depth_m)
    square_m: float             # side of the square a landing needs clear (the mask's footprint + margins)

    @classmethod
    def from_config(cls, config: Config) -> FusionParams:
        f = config.terrain.fusion
        uav, mc = config.uav, config.mask
        cell = max(uav.footprint_m) / f.cells_per_footprint
        return cls(cell_m=cell, side_cells=max(8, math.ceil(f.window_m / cell)), samples_per_cell=f.samples_per_cell,
                   white_fraction=f.white_fraction, fixed_fraction=f.fixed_fraction,
                   decorrelation_px=f.decorrelation_px, gate_sigma=f.gate_sigma,
                   two_heights_fraction=f.two_heights_fraction, pose_sigma_m=f.pose_sigma_m,
                   pose_sigma_rad=math.radians(f.pose_sigma_deg),
                   confidence_sigma=config.terrain.limits.confidence_sigma,
                   target_margin=config.terrain.limits.target_margin, max_step_m=uav.max_step_m,
                   max_slope_deg=uav.max_slope_deg, column_m=config.control.desired_depth_m,
                   square_m=mc.margin_factor * max(uav.footprint_m) + 2.0 * uav.clearance_m)


@dataclass(frozen=True, eq=False)
class FrameCells:
    """One frame's measurements: one row per cell it saw (arrays of equal length)."""

    ix: np.ndarray           # int64 cell column (world x / cell_m, floored)
    iy: np.ndarray           # int64 cell row (world y / cell_m, floored)
    height_m: np.ndarray     # float64 mean height of the cell's samples
    spread_m: np.ndarray     # float64 std of the samples' heights inside the cell
    u_px: np.ndarray         # float64 image column of the cell's centre at its measured height
    v_px: np.ndarray         # float64 image row
    sigma_w_m: np.ndarray    # float64 std of the part of the error that is new in this frame
    sigma_c_m: np.ndarray    # float64 std of the part that moves with the view
    pose_var_m2: np.ndarray  # float64 variance added by the pose
    camera_m: np.ndarray     # (3,) camera position in the world
    T_world_camera: np.ndarray
    intrinsics: Intrinsics
    depth_m: float           # the frame's median depth
    step_per_sigma: float    # the frame's smallest detectable step / its cell-height std (limits.working_scale)
    tan_slope_per_sigma: float  # tan(smallest detectable slope) / its cell-height std, 1/m

    def __len__(self) -> int:
        return int(self.ix.size)


def project_cells(ix: np.ndarray, iy: np.ndarray, h: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics,
                  cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (u, v) of cell centres at heights ``h`` in a frame, and whether they are in front of it."""
    T = np.asarray(T_world_camera, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    px = (ix + 0.5) * cell_m - t[0]
    py = (iy + 0.5) * cell_m - t[1]
    pz = h - t[2]
    xc = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
    yc = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
    zc = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
    with np.errstate(divide="ignore", invalid="ignore"):
        return intr.fx * xc / zc + intr.cx, intr.fy * yc / zc + intr.cy, zc > 0


def sample_block_px(depth_m: float, focal_px: float, params: FusionParams) -> int:
    """Block side (px) of the samples: the coarsest that keeps ``samples_per_cell`` across a cell at ``depth_m``."""
    px_m = depth_m / focal_px
    return max(1, math.floor(params.cell_m / (params.samples_per_cell * px_m)))


def cell_sigma_m(noise: DepthNoise, depth_m: np.ndarray | float, focal_px: float, cell_m: float) -> np.ndarray:
    """Std of one frame's mean depth over a cell at ``depth_m``: a_b z^2 with b the cell's side in pixels there."""
    z = np.asarray(depth_m, dtype=np.float64)
    b = cell_m * focal_px / np.maximum(z, 1e-6)
    a = np.interp(np.log(np.maximum(b, 1.0)), np.log(_SCALES), np.log(np.maximum(_a_vector(noise), 1e-12)))
    return np.exp(a) * z * z


_SCALES = np.array([1.0, 2.0, 4.0, 8.0, 16.0])


def _a_vector(noise: DepthNoise) -> np.ndarray:
    out = np.array([noise.a_at(b) for b in _SCALES])
    return out


def frame_cells(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray, noise: DepthNoise,
                params: FusionParams, step_per_sigma: float, tan_slope_per_sigma: float) -> FrameCells | None:
    """The cells a frame saw and their height measurements (None: no depth). ``T_world_camera``: gravity-aligned."""
    depth = np.asarray(depth_m, dtype=np.float32)
    z_med = median_depth_m(depth)
    if z_med is None:
        return None
    intr = fit_intrinsics(intrinsics, depth.shape)
    f = 0.5 * (intr.fx + intr.fy)
    m = sample_block_px(z_med, f, params)
    valid = valid_depth(depth)
    if m > 1:
        depth_b, ok = block_depth(depth, valid, m)
        intr_b = fit_intrinsics(intr, depth_b.shape)
    else:
        depth_b, ok, intr_b = depth, valid, intr
    rx, ry = pixel_rays(intr_b)
    flat_ok = np.flatnonzero(ok)
    if flat_ok.size == 0:
        return None
    wb = depth_b.shape[1]
    rows, cols = np.divmod(flat_ok, wb)
    z = depth_b.reshape(-1)[flat_ok]
    xr = rx[0, cols]
    yr = ry[rows, 0]
    T = np.asarray(T_world_camera, dtype=np.float64)
    R, t = T[:3, :3].astype(np.float32), T[:3, 3]
    # float32 relative to the camera (4 um at 50 m), the camera's position added in float64 via the cell index
    wx = (R[0, 0] * xr + R[0, 1] * yr + R[0, 2]) * z
    wy = (R[1, 0] * xr + R[1, 1] * yr + R[1, 2]) * z
    up = R[2, 0] * xr + R[2, 1] * yr + R[2, 2]        # vertical component of each sample's ray (z = 1)
    wz = up * z
    inv = 1.0 / params.cell_m
    ix = np.floor((wx + np.float32(t[0] % params.cell_m)) * np.float32(inv)).astype(np.int64)
    iy = np.floor((wy + np.float32(t[1] % params.cell_m)) * np.float32(inv)).astype(np.int64)
    cx, cy = math.floor(t[0] * inv), math.floor(t[1] * inv)
    # never more than the window: a frame wider than it keeps the cells nearest the camera
    half = params.side_cells // 2 - 1
    near = (np.abs(ix) <= half) & (np.abs(iy) <= half)
    if not near.all():
        ix, iy, wz, z, up = (a[near] for a in (ix, iy, wz, z, up))
        if ix.size == 0:
            return None
    x0, y0 = int(ix.min()), int(iy.min())
    nx = int(ix.max()) - x0 + 1
    flat = (iy - y0) * nx + (ix - x0)
    size = nx * (int(iy.max()) - y0 + 1)
    count = np.bincount(flat, minlength=size)
    idx = np.flatnonzero(count >= _MIN_SAMPLES)
    n = count[idx].astype(np.float64)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(flat, weights=values, minlength=size)[idx] / n

    h = mean(wz)
    spread = np.sqrt(np.maximum(mean(wz * wz) - h * h, 0.0))
    h += t[2]
    zc = mean(z)
    upc = np.abs(mean(up))
    sigma = cell_sigma_m(noise, zc, f, params.cell_m) * upc
    wf = params.white_fraction
    sw = sigma * math.sqrt(wf)
    sc = sigma * math.sqrt(1.0 - wf - params.fixed_fraction)
    cells_x = idx % nx + x0 + cx
    cells_y = idx // nx + y0 + cy
    u, v, _ = project_cells(cells_x, cells_y, h, T, intr, params.cell_m)
    pose_var = np.full(idx.size, params.pose_sigma_m ** 2)
    if params.pose_sigma_rad > 0:
        r2 = ((cells_x + 0.5) * params.cell_m - t[0]) ** 2 + ((cells_y + 0.5) * params.cell_m - t[1]) ** 2
        pose_var += r2 * params.pose_sigma_rad ** 2
    return FrameCells(cells_x, cells_y, h, spread, u, v, sw, sc, pose_var, t.copy(), T, intr, z_med,
                      step_per_sigma, tan_slope_per_sigma)


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
    z = median_depth_m(np.asarray(depth_m))
    if z is None:
        return None
    intr = fit_intrinsics(intrinsics, np.asarray(depth_m).shape)
    step, tan = frame_limit_ratios(noise, z, 0.5 * (intr.fx + intr.fy), config, params)
    return frame_cells(depth_m, intrinsics, T_world_camera, noise, params, step, tan)
