"""The fusion's compiled loops (slzcli/fusion/kernels.py) against the array expressions they replaced.

``numpy_frame_cells`` and ``numpy_fuse`` below are ``measure.frame_cells`` and ``grid.fuse`` as they were
written with numpy (commit 2724c9d): the loops must give the same bits on random frames (holes of every kind,
tilted poses, block means and full-resolution samples, a view wider than the window) and random grids (cells
held, new, taken over, rejected by the gate), and the frame's median and the sweep of cells left behind must
equal theirs.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from fusion_scene import INTR, Block, exact_depth, pose

from slzcli.config import load_config
from slzcli.errors import ConfigError
from slzcli.fusion import kernels
from slzcli.fusion.grid import (
    _EMPTY,
    _RHO_MAX,
    FusedGrid,
    FuseStats,
    Region,
    cell_key,
    fuse,
    noise_scale,
    region,
    sweep_due,
)
from slzcli.fusion.kernels import (
    COLUMN_LEVELS,
    NISN,
    NISS,
    PCC,
    PHC,
    PHH,
    POSEV,
    SIG1,
    SIGC,
    SPREAD,
    STEPR,
    TANR,
    C,
    H,
    U,
    V,
)
from slzcli.fusion.measure import (
    _MIN_SAMPLES,
    CellView,
    FrameCells,
    FusionParams,
    cell_sigma_m,
    cell_view,
    frame_cells,
    frame_median_m,
    sample_block_px,
    sample_window_px,
    window_depths,
    within_border,
)
from slzcli.geometry import fit_intrinsics, pixel_rays, valid_depth
from slzcli.terrain.geometry import block_depth, median_depth_m
from slzcli.terrain.noise import DepthNoise
from slzcli.types import Intrinsics


# --------------------------------------------------------------------------- the reference (numpy) code
def numpy_window_depth(depth: np.ndarray, valid: np.ndarray, block: int, window: int) -> tuple[np.ndarray, np.ndarray]:
    """(depth, valid) of the mean inverse depth over ``window`` x ``window`` pixels centred on the ``block`` grid's
    centres, cut by the image's border (``measure.window_depths``; half the window's pixels in the image need
    depth, NaN otherwise): box sums with zeros beyond the border, over the count of pixels inside."""
    inv = np.zeros(depth.shape, np.float64)
    np.divide(1.0, depth, out=inv, where=valid)
    h, w = depth.shape
    o = block // 2
    at = (slice(o, o + (h // block) * block, block), slice(o, o + (w // block) * block, block))

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, cv2.CV_64F, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)[at]

    num, den, inside = box(inv), box(valid.astype(np.float64)), box(np.ones(depth.shape))
    ok = (2.0 * den >= inside) & (den > 0)
    out = np.full(num.shape, np.nan, np.float32)
    out[ok] = (den[ok] / num[ok]).astype(np.float32)
    return out, ok


def numpy_frame_cells(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray, noise: DepthNoise,
                      params: FusionParams, step_per_sigma: float, tan_slope_per_sigma: float,
                      z_med: float | None = None) -> FrameCells | None:
    """``measure.frame_cells`` in numpy: samples without depth, or beyond the window, go to one extra bin."""
    depth = np.asarray(depth_m, dtype=np.float32)
    if z_med is None:
        z_med = median_depth_m(depth)
    if z_med is None:
        return None
    intr = fit_intrinsics(intrinsics, depth.shape)
    f = 0.5 * (intr.fx + intr.fy)
    m = sample_block_px(z_med, f, params)
    valid = valid_depth(depth)
    win = sample_window_px(m, z_med, f, params.cell_m)
    if win > m:     # the windows' sums are cv2's box filter (against numpy_window_depth below, to rounding)
        depth_b = window_depths(depth, m, win)
        ok = depth_b > 0
        depth_b = np.where(ok, depth_b, np.float32(np.nan))
        intr_b = fit_intrinsics(intr, depth_b.shape)
    elif m > 1:
        depth_b, ok = block_depth(depth, valid, m)
        intr_b = fit_intrinsics(intr, depth_b.shape)
    else:
        depth_b, ok, intr_b = depth, valid, intr
    all_ok = bool(ok.all())
    if not all_ok and not ok.any():
        return None
    rx, ry = pixel_rays(intr_b)
    z = depth_b if all_ok else np.where(ok, depth_b, np.float32(0))
    T = np.asarray(T_world_camera, dtype=np.float64)
    R, t = T[:3, :3].astype(np.float32), T[:3, 3]
    # float32 relative to the camera (4 um at 50 m), the camera's position added in float64 via the cell index
    wx = (R[0, 0] * rx + R[0, 1] * ry + R[0, 2]) * z
    wy = (R[1, 0] * rx + R[1, 1] * ry + R[1, 2]) * z
    up = R[2, 0] * rx + R[2, 1] * ry + R[2, 2]        # vertical component of each sample's ray (z = 1)
    wz = up * z
    inv = 1.0 / params.cell_m
    ix = _floor(wx, np.float32(t[0] % params.cell_m), np.float32(inv))
    iy = _floor(wy, np.float32(t[1] % params.cell_m), np.float32(inv))
    cx, cy = math.floor(t[0] * inv), math.floor(t[1] * inv)
    # never more than the window: a frame wider than it keeps the cells nearest the camera
    half = params.side_cells // 2 - 1
    keep = None if all_ok else ok          # samples without depth sit at the camera's cell: in the window
    x0, x1, y0, y1 = int(ix.min()), int(ix.max()), int(iy.min()), int(iy.max())
    if max(-x0, x1, -y0, y1) > half:
        near = (np.abs(ix) <= half) & (np.abs(iy) <= half)
        keep = near if keep is None else keep & near
        if not keep.any():
            return None
    if keep is not None:
        x0, x1 = _bounds(ix, keep)
        y0, y1 = _bounds(iy, keep)
    nx = x1 - x0 + 1
    size = nx * (y1 - y0 + 1)
    # the bin index in float32 (whole numbers below 2^24: exact), one conversion to integers
    ff = iy - np.float32(y0)
    ff *= np.float32(nx)
    ff += ix
    ff -= np.float32(x0)
    if keep is not None:
        np.copyto(ff, np.float32(size), where=~keep)     # the dropped samples' bin
    flat = ff.reshape(-1).astype(np.intp)
    count = np.bincount(flat, minlength=size + 1)[:size]
    idx = np.flatnonzero(count >= _MIN_SAMPLES)
    n = count[idx].astype(np.float64)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(flat, weights=values.reshape(-1), minlength=size + 1)[idx] / n

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
    pose_var = np.full(idx.size, params.pose_sigma_m ** 2)
    if params.pose_sigma_rad > 0:
        r2 = ((cells_x + 0.5) * params.cell_m - t[0]) ** 2 + ((cells_y + 0.5) * params.cell_m - t[1]) ** 2
        pose_var += r2 * params.pose_sigma_rad ** 2
    return within_border(FrameCells(cells_x, cells_y, h, spread, sw, sc, pose_var, t.copy(), T, intr, z_med,
                                    step_per_sigma, tan_slope_per_sigma, depth, noise.a1_per_m), zc, params)


def _floor(w: np.ndarray, offset: np.float32, inv: np.float32) -> np.ndarray:
    """floor((w + offset) inv), the cell index in float32 (whole numbers: exact below 2^24)."""
    a = w + offset
    np.multiply(a, inv, out=a)
    np.floor(a, out=a)
    return a


def _bounds(i: np.ndarray, keep: np.ndarray) -> tuple[int, int]:
    """(min, max) of ``i`` where ``keep``."""
    lo = np.where(keep, i, np.inf).min()
    hi = np.where(keep, i, -np.inf).max()
    return int(lo), int(hi)


def numpy_fuse(grid: FusedGrid, m: FrameCells, frame_index: int, gate_scale: float = 1.0) -> FuseStats:
    """``grid.fuse`` in numpy: gathered rows updated in place, written back."""
    p = grid.params
    k, owned = grid.slots(m.ix, m.iy)
    st = np.take(grid.state, k, axis=0)  # a gathered copy, written back at the end
    f = st.T                              # f[FIELD]: that field of every cell (a view)
    sw2 = m.sigma_w_m * m.sigma_w_m
    sc2 = m.sigma_c_m * m.sigma_c_m
    y = m.height_m
    # --- predict the shared error by the cell's image shift since its last look: the cell's centre at its
    # estimated height projected into the frame (the mean pixel of its samples jitters with the depth
    # noise, which moves samples across cell borders: a hover would seem to move)
    h_ref = np.where(owned, f[H], y)
    view = cell_view(m.ix, m.iy, m.T_world_camera, m.intrinsics, p.cell_m)
    u_px, v_px, _ = view.at(h_ref)
    shift = np.hypot(u_px - f[U], v_px - f[V])
    rho = np.minimum(np.exp(-shift / p.decorrelation_px), _RHO_MAX)
    sc_old = f[SIGC]
    g = rho * np.divide(m.sigma_c_m, sc_old, out=np.ones_like(sc_old), where=sc_old > 0)
    c = g * f[C]
    p_hh = f[PHH]
    p_hc = g * f[PHC]
    p_cc = g * g * f[PCC] + (1.0 - rho * rho) * sc2
    innov = y - (f[H] + c)
    s_t = p_hh + 2.0 * p_hc + p_cc + sw2
    # the gate holds the cell's variance, the measurement's and the pose's
    ok = innov * innov <= (p.gate_sigma ** 2) * (gate_scale * s_t + m.pose_var_m2)
    # the update proper leaves the pose out: a frame's pose error is common to its cells (a height offset,
    # a tilt over the view), not terrain; it widens the gate and the reported variance only
    with np.errstate(invalid="ignore", divide="ignore"):
        kh = (p_hh + p_hc) / s_t
        kc = (p_hc + p_cc) / s_t
    acc = owned & ok
    new = ~owned
    look = acc | new
    # whole rows, in place (cheaper than boolean gathers and scatters): accepted looks are updated, new cells
    # start at h = y, c = 0 with the covariance of a flat prior, rejected ones keep theirs
    with np.errstate(invalid="ignore"):   # a new cell's slot holds another cell's numbers until replaced
        np.copyto(f[H], f[H] + kh * innov, where=acc)
        np.copyto(f[C], c + kc * innov, where=acc)
        np.copyto(f[PHH], p_hh - kh * kh * s_t, where=acc)
        np.copyto(f[PHC], p_hc - kh * kc * s_t, where=acc)
        np.copyto(f[PCC], p_cc - kc * kc * s_t, where=acc)
        np.copyto(f[SPREAD], np.maximum(f[SPREAD], m.spread_m), where=acc)
        np.copyto(f[POSEV], np.minimum(f[POSEV], m.pose_var_m2), where=acc)
        # every look at a cell held before, accepted or not: its innovation's normalised square, at most the gate's
        np.copyto(f[NISS], f[NISS] + np.minimum(innov * innov / s_t, p.gate_sigma ** 2), where=owned)
        np.copyto(f[NISN], f[NISN] + 1.0, where=owned)
    for row, value in ((H, y), (C, 0.0), (PHH, sc2 + sw2), (PHC, -sc2), (PCC, sc2), (SPREAD, m.spread_m),
                       (POSEV, m.pose_var_m2), (NISS, 0.0), (NISN, 0.0)):
        np.copyto(f[row], value, where=new)
    for row, value in ((U, u_px), (V, v_px), (SIGC, m.sigma_c_m),
                       (SIG1, np.sqrt((sc2 + sw2) / max(1.0 - p.fixed_fraction, 1e-9))),
                       (STEPR, m.step_per_sigma), (TANR, m.tan_slope_per_sigma)):
        np.copyto(f[row], value, where=look)
    grid.state[k] = st
    kn = k[new]
    grid.owner[kn] = cell_key(m.ix[new], m.iy[new])
    grid.frames[kn] = 0
    grid.rejected[kn] = 0
    grid.column[kn] = 0
    grid.blocked[kn] = 0
    grid.frames[k] += 1
    grid.rejected[k[owned & ~ok]] += 1
    grid.last_frame[k] = frame_index
    _column(grid, view, k, f[H], m)
    _sweep(grid, m)
    so = shift[owned]
    med = float(np.median(so)) if so.size else float("nan")
    with np.errstate(invalid="ignore", divide="ignore"):
        nis = innov[owned] ** 2 / s_t[owned]
    nis_med = float(np.median(nis)) if nis.size else float("nan")
    return FuseStats(len(m), int(np.count_nonzero(new)), int(np.count_nonzero(owned & ~ok)), med, nis_med)


def _sweep(grid: FusedGrid, m: FrameCells) -> None:
    """``grid._sweep``'s forgetting in numpy (when it is due is ``grid.sweep_due``, shared)."""
    due = sweep_due(grid, m)
    if due is None:
        return
    s = grid.params.side_cells
    cx, cy = due
    held = grid.owner != _EMPTY
    keys = grid.owner
    xs = keys >> 32
    ys = (keys & 0xFFFFFFFF).astype(np.int64)
    ys = np.where(ys >= 1 << 31, ys - (1 << 32), ys)
    far = held & ((np.abs(xs - cx) > s // 2) | (np.abs(ys - cy) > s // 2))
    grid.owner[far] = _EMPTY


def nadir_in_view(m: FrameCells) -> bool:
    """The image of the point below the camera in the frame (numpy's projection of the world's down)."""
    R = np.asarray(m.T_world_camera)[:3, :3]
    d = R.T @ np.array([0.0, 0.0, -1.0])
    if d[2] <= 0:
        return False
    u = m.intrinsics.fx * d[0] / d[2] + m.intrinsics.cx
    v = m.intrinsics.fy * d[1] / d[2] + m.intrinsics.cy
    return bool(-0.5 <= u < m.intrinsics.width - 0.5 and -0.5 <= v < m.intrinsics.height - 0.5)


def _column(grid: FusedGrid, view: CellView, k: np.ndarray, h: np.ndarray, m: FrameCells) -> None:
    """The column above each cell, level by level from ``column_m`` up: a level is seen free where the frame's
    depth at its pixel lies beyond it by k times that depth's noise, blocked where a depth lies nearer; levels
    seen free before are not looked at; the first level behind the camera ends the column, and so does the first
    outside the image after one inside it (or seen free before), or at all when the nadir is in the view."""
    p = grid.params
    depth = m.depth_image
    lv = np.arange(COLUMN_LEVELS)
    hl = h[:, None] + p.column_m + lv[None, :] * p.column_step_m          # (cells, levels)
    pz = hl - view.t_z
    xc, yc, zc = (view.xy[i][:, None] + view.r_z[i] * pz for i in range(3))
    intr = view.intr
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = intr.fx * xc / zc + intr.cx, intr.fy * yc / zc + intr.cy
    bits = np.left_shift(np.uint64(1), lv.astype(np.uint64))
    before = (grid.column[k][:, None] & bits[None, :]) != 0
    with np.errstate(invalid="ignore"):
        ju = np.floor(u + 0.5)
        jv = np.floor(v + 0.5)
        in_image = (zc > 0) & (ju >= 0) & (ju < depth.shape[1]) & (jv >= 0) & (jv < depth.shape[0])
    entered = np.cumsum(before | in_image, axis=1) - (before | in_image) > 0     # at some level below
    stop = ~before & ((zc <= 0) | (~in_image & (entered | nadir_in_view(m))))
    active = (np.cumsum(stop, axis=1) == 0) & ~before
    inside = active & in_image
    d = np.zeros_like(zc)
    d[inside] = depth[jv[inside].astype(np.intp), ju[inside].astype(np.intp)]
    with np.errstate(invalid="ignore"):   # NaN depth: neither
        has = inside & (d > 0) & (d < np.inf)
        free = has & (d - p.confidence_sigma * m.pixel_a * d * d > zc)
    grid.column[k] |= np.bitwise_or.reduce(np.where(free, bits[None, :], np.uint64(0)), axis=1)
    grid.blocked[k] |= np.bitwise_or.reduce(np.where(has & ~free, bits[None, :], np.uint64(0)), axis=1)


# --------------------------------------------------------------------------- random frames and grids
def _params(window_m: float = 40.0) -> FusionParams:
    return FusionParams.from_config(load_config(None, [f"terrain.fusion.window_m={window_m}"]))


def _tilted(rng: np.random.Generator, x: float, y: float, z: float, steep: bool = False) -> np.ndarray:
    """A downward pose with a random yaw and up to 15 degrees of roll and pitch; ``steep``: rolled 32-45 degrees
    (the test camera's half view is 27.5 degrees across its rows: the point below it is out of the view)."""
    T = pose(x, y, z, yaw_deg=float(rng.uniform(-180, 180)))
    ax, ay = np.radians(rng.uniform(-15, 15, 2))
    if steep:
        ax = math.copysign(math.radians(rng.uniform(32, 45)), ax)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    T[:3, :3] = rx @ ry @ T[:3, :3]
    return T


def _frame(rng: np.random.Generator, T: np.ndarray, intr: Intrinsics = INTR) -> np.ndarray:
    """Depth of a plane with a block, noise, and holes: NaN, 0, inf, negative, a whole corner empty."""
    x0, y0 = (float(v) for v in rng.uniform(-1, 0, 2))
    w, d = (float(v) for v in rng.uniform(0.2, 1.5, 2))
    block = Block(x0, x0 + w, y0, y0 + d, float(rng.uniform(0.1, 0.8)))
    depth = exact_depth(T, block, intr) + rng.normal(0, 0.03, (intr.height, intr.width))
    depth = depth.astype(np.float32)
    holes = rng.random(depth.shape)
    depth[holes < 0.1] = np.nan
    depth[(holes >= 0.1) & (holes < 0.12)] = 0.0
    depth[(holes >= 0.12) & (holes < 0.13)] = np.inf
    depth[(holes >= 0.13) & (holes < 0.14)] = -1.0
    depth[: intr.height // 5, : intr.width // 4] = np.nan
    return depth


def _same(a: object, b: object) -> None:
    """Equal to the bit (NaN where NaN), field by field."""
    for name in ("ix", "iy", "height_m", "spread_m", "sigma_w_m", "sigma_c_m", "pose_var_m2"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
    for name in ("camera_m", "T_world_camera"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert (a.intrinsics, a.depth_m) == (b.intrinsics, b.depth_m)  # type: ignore[attr-defined]


@pytest.mark.parametrize(("block", "window"), [(1, 3), (2, 4), (3, 7), (2, 2), (5, 9)])
def test_window_depth_is_the_mean_inverse_depth_over_each_window(block: int, window: int) -> None:
    """``measure.window_depths`` (cv2's float32 box sums at blocks of 1 px, the compiled float64 sliding sums at
    larger blocks) against float64 box sums over the count of pixels in the image: holes (NaN, 0, inf, a corner
    without depth), windows cut by every side, odd and even windows; equal to float32 rounding, and the same
    samples without depth."""
    rng = np.random.default_rng(block * 10 + window)
    depth = rng.uniform(4.0, 12.0, (97, 131)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[rng.random(depth.shape) < 0.05] = 0.0
    depth[rng.random(depth.shape) < 0.05] = np.inf
    depth[:12, :15] = np.nan
    got = window_depths(depth, block, window)
    want, ok = numpy_window_depth(depth, valid_depth(depth), block, window)
    assert got.shape == want.shape == (97 // block, 131 // block)
    assert np.array_equal(got > 0, ok) and 0 < ok.mean() < 1
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("altitude_m", "window_m"), [(4.0, 40.0), (9.0, 40.0), (6.0, 3.0)])
def test_frame_cells_are_the_array_expressions_to_the_bit(seed: int, altitude_m: float, window_m: float) -> None:
    """Samples over windows on block grids (4 m and 9 m here) and a view wider than the window (3 m):
    the same cells, heights, spreads, noises and pose variances as the numpy code, bit for bit."""
    rng = np.random.default_rng(seed)
    params = _params(window_m)
    x, y = rng.uniform(-50, 50, 2)
    T = _tilted(rng, float(x), float(y), altitude_m)
    depth = _frame(rng, T)
    noise = DepthNoise(tuple(0.002 / np.sqrt(b) for b in (1, 2, 4, 8, 16)), "estimated")
    got = frame_cells(depth, INTR, T, noise, params, 2.0, 0.1)
    want = numpy_frame_cells(depth, INTR, T, noise, params, 2.0, 0.1)
    assert got is not None and want is not None and len(want) > 50
    _same(got, want)


def test_frame_cells_without_depth_or_beyond_the_window_are_none_in_both() -> None:
    params = _params(3.0)
    T = pose(0.0, 0.0, 6.0)
    empty = np.full((INTR.height, INTR.width), np.nan, np.float32)
    assert frame_cells(empty, INTR, T, DepthNoise.white(0.001, "known"), params, 2.0, 0.1, z_med=6.0) is None
    assert numpy_frame_cells(empty, INTR, T, DepthNoise.white(0.001, "known"), params, 2.0, 0.1, z_med=6.0) is None
    # depth only far out in one corner: every sample beyond the window
    far = empty.copy()
    far[:5, :5] = 40.0
    args = (far, INTR, pose(0.0, 0.0, 2.0), DepthNoise.white(0.001, "known"), params, 2.0, 0.1, 2.0)
    assert frame_cells(*args) is None and numpy_frame_cells(*args) is None


def _copy(g: FusedGrid) -> FusedGrid:
    return FusedGrid(g.params, g.owner.copy(), g.state.copy(), g.frames.copy(), g.rejected.copy(), g.column.copy(),
                     g.blocked.copy(), g.last_frame.copy(), g.swept_at.copy())


@pytest.mark.parametrize("seed", range(4))
def test_fuse_is_the_array_expressions_to_the_bit(seed: int) -> None:
    """A random flight (moves, hovers, jumps of the window's side so slots are taken over, outliers the gate
    rejects, frames pitched so far that the point below the camera is out of the view): after every frame the grid
    (state, owners, counts, the columns' levels seen free and blocked) and the frame's stats are the numpy code's,
    bit for bit."""
    rng = np.random.default_rng(100 + seed)
    params = _params(12.0)
    noise = DepthNoise(tuple(0.003 / np.sqrt(b) for b in (1, 2, 4, 8, 16)), "estimated")
    got, want = FusedGrid.empty(params), FusedGrid.empty(params)
    x = y = 0.0
    rejected = taken = steep = 0
    for i in range(14):
        if i in (5, 10):       # a window's side on: the new cells take the slots of the ones left behind
            x += params.side_cells * params.cell_m
        else:
            step = rng.choice([0.0, 0.05, 0.5])
            x, y = x + step * rng.normal(), y + step * rng.normal()
        T = _tilted(rng, x, y, float(rng.uniform(3.0, 7.0)), steep=i % 4 == 3)
        depth = _frame(rng, T)
        depth[rng.random(depth.shape) < 0.01] -= 2.0          # outliers
        cells = frame_cells(depth, INTR, T, noise, params, float(rng.uniform(1, 3)), float(rng.uniform(0, 1)))
        assert cells is not None
        steep += not nadir_in_view(cells)
        k, owned = got.slots(cells.ix, cells.iy)
        taken += int(np.count_nonzero(~owned & (got.owner[k] != _EMPTY)))
        g = 1.0 + 0.5 * (i % 3)      # the gate widened by the frame's scale, as FusedTerrain does
        a, b = fuse(got, cells, i, g), numpy_fuse(want, cells, i, g)
        assert a.cells == b.cells and a.new == b.new and a.rejected == b.rejected
        assert np.array_equal([a.median_shift_px, a.nis_median], [b.median_shift_px, b.nis_median], equal_nan=True)
        for name in ("owner", "state", "frames", "rejected", "column", "blocked", "last_frame", "swept_at"):
            u, v = getattr(got, name), getattr(want, name)
            assert np.array_equal(u, v, equal_nan=u.dtype.kind == "f"), (i, name)
        rejected += a.rejected
    assert rejected > 0 and taken > 0      # the gate rejected some, new cells took slots over
    assert steep > 0                       # some frames had the nadir out of the view
    assert np.any(got.column) and np.any(got.blocked & ~got.column)   # levels seen free, some only blocked (outliers)


def numpy_region(grid: FusedGrid, x0: int, y0: int, nx: int, ny: int) -> Region:
    """``grid.region`` in numpy (as it was written before its compiled gather)."""
    s = grid.params.side_cells
    nx, ny = min(nx, s), min(ny, s)
    ix = np.arange(x0, x0 + nx, dtype=np.int64)[None, :]
    iy = np.arange(y0, y0 + ny, dtype=np.int64)[:, None]
    k = np.mod(iy, s) * s + np.mod(ix, s)
    seen = grid.owner[k] == cell_key(ix, iy)
    st = grid.state[k]

    def f(i: int) -> np.ndarray:
        return np.where(seen, st[..., i], np.nan)

    q = noise_scale(np.where(seen, st[..., NISS], 0.0), np.where(seen, st[..., NISN], 0.0),
                    grid.params.cells_per_footprint)
    sig1 = f(SIG1)
    var = f(PHH) + grid.params.fixed_fraction * sig1 * sig1
    with np.errstate(invalid="ignore", divide="ignore"):
        looks = np.where(seen, sig1 * sig1 / var, 0.0).astype(np.float32)
    zero = np.zeros(seen.shape)
    return Region(x0, y0, grid.params.cell_m, seen, f(H), q * var, f(POSEV), looks,
                  np.where(seen, grid.frames[k], 0), np.where(seen, grid.rejected[k], 0),
                  np.where(seen, st[..., SPREAD], zero).astype(np.float32),
                  np.where(seen, st[..., STEPR], zero).astype(np.float32),
                  np.where(seen, st[..., TANR], zero).astype(np.float32),
                  seen & ((grid.column[k] & np.uint64(1)) != 0) & ((grid.blocked[k] & ~grid.column[k]) == 0),
                  q * f(PHC), q * f(PCC), np.sqrt(q) * f(SIGC), np.sqrt(q) * sig1)


@pytest.mark.parametrize("seed", range(3))
def test_region_is_the_array_expressions_to_the_bit(seed: int) -> None:
    """A grid flown over (slots taken over by cells a window's side on, cells on both sides of 0): every
    rectangle, inside the ground seen, across its edge, at negative indices, as wide as the window, gives the
    numpy code's arrays, bit for bit and of the same types."""
    rng = np.random.default_rng(300 + seed)
    params = _params(12.0)
    noise = DepthNoise(tuple(0.003 / np.sqrt(b) for b in (1, 2, 4, 8, 16)), "estimated")
    grid = FusedGrid.empty(params)
    x = y = 0.0
    for i in range(8):
        if i == 4:
            x += params.side_cells * params.cell_m
        x, y = x + 0.3 * rng.normal(), y + 0.3 * rng.normal()
        T = _tilted(rng, x, y, float(rng.uniform(3.0, 7.0)))
        cells = frame_cells(_frame(rng, T), INTR, T, noise, params, float(rng.uniform(1, 3)),
                            float(rng.uniform(0, 1)))
        assert cells is not None
        fuse(grid, cells, i)
    s = params.side_cells
    cx, cy = int(np.floor(x / params.cell_m)), int(np.floor(y / params.cell_m))
    boxes = [(cx - 20, cy - 15, 40, 30), (cx - s // 2, cy - s // 2, s, s), (cx - 5, cy - 5, s + 9, 3),
             (-7, -9, 15, 12), (int(rng.integers(-200, 200)), int(rng.integers(-200, 200)), 25, 25)]
    seen_any = 0
    for box in boxes:
        got, want = region(grid, *box), numpy_region(grid, *box)
        for name in Region.__dataclass_fields__:
            u, v = getattr(got, name), getattr(want, name)
            if isinstance(v, np.ndarray):
                assert u.dtype == v.dtype and u.shape == v.shape, (box, name)
                assert np.array_equal(u, v, equal_nan=v.dtype.kind == "f"), (box, name)
            else:
                assert u == v, (box, name)
        seen_any += int(got.seen.any() and not got.seen.all())
    assert seen_any >= 2     # rectangles that cut the ground seen were compared


@pytest.mark.parametrize("seed", range(5))
def test_the_frame_median_is_numpys(seed: int) -> None:
    """Odd and even counts, holes of every kind, no depth at all; and another dtype goes to numpy itself."""
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 60)), int(rng.integers(1, 60))
    depth = rng.uniform(0.1, 30, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.3] = np.nan
    depth[rng.random((h, w)) < 0.1] = rng.choice([0.0, -1.0, np.inf])
    depth[rng.random((h, w)) < 0.3] = depth[0, 0]          # repeated values
    assert frame_median_m(depth) == median_depth_m(depth)
    assert frame_median_m(depth.astype(np.float64)) == median_depth_m(depth.astype(np.float64))
    assert frame_median_m(np.full((h, w), np.nan, np.float32)) is None


def test_median_inplace_is_numpys_median() -> None:
    """Odd and even counts, float64 and float32, ties, a NaN anywhere (then NaN), none at all."""
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 11, 1000, 1001, 20000, 20001):
        for values in (rng.normal(size=n), rng.integers(0, 3, n).astype(np.float64),
                       rng.uniform(0.1, 30, n).astype(np.float32)):
            got = kernels.median_inplace(values.copy())
            assert got == np.median(values) and isinstance(got, float)
            if n > 1:
                for at in (0, n // 2, n - 1):
                    holed = values.copy()
                    holed[at] = np.nan
                    assert math.isnan(kernels.median_inplace(holed))
    assert math.isnan(kernels.median_inplace(np.array([1.0, np.nan, 2.0])))
    assert math.isnan(kernels.median_inplace(np.zeros(0)))


def test_a_window_of_the_block_is_the_block_mean() -> None:
    """``window_depths`` with the window the block itself is ``terrain.geometry.block_depth`` (the per-frame path's
    block means of inverse depth, cv2's area resize: whole blocks where they divide the frame's sides, as here),
    to float32 rounding, with the same blocks without depth."""
    rng = np.random.default_rng(1)
    depth = _frame(rng, pose(0.0, 0.0, 5.0))
    for block in (2, 4, 5):
        got = window_depths(depth, block, block)
        want, ok = block_depth(depth, valid_depth(depth), block)
        assert np.array_equal(got > 0, ok) and 0 < np.count_nonzero(ok) < ok.size
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6)


def test_a_window_wider_than_the_binning_holds_is_refused() -> None:
    """The samples' cells are int16: a window of more cells is a config error naming its key, never a wrap."""
    one = np.ones((2, 2), np.float32)
    args = (np.zeros(2), np.zeros(2), np.eye(3), 0.0, 0.0, 1.0)
    rest = (2, np.zeros(3), 1.0, (0, 0), 0.0, 0.0)
    assert kernels.bin_frame(one, *args, kernels.MAX_HALF, *rest)[0] == 1
    with pytest.raises(ConfigError, match=r"terrain\.fusion\.window_m"):
        kernels.bin_frame(one, *args, kernels.MAX_HALF + 1, *rest)


def test_the_sweep_forgets_what_numpy_forgot() -> None:
    rng = np.random.default_rng(2)
    owner = cell_key(rng.integers(-400, 400, 5000), rng.integers(-400, 400, 5000))
    owner[rng.random(5000) < 0.2] = _EMPTY
    want = owner.copy()
    xs = want >> 32
    ys = (want & 0xFFFFFFFF).astype(np.int64)
    ys = np.where(ys >= 1 << 31, ys - (1 << 32), ys)
    want[(want != _EMPTY) & ((np.abs(xs - 30) > 200) | (np.abs(ys + 40) > 200))] = _EMPTY
    kernels.sweep(owner, 30, -40, 200, int(_EMPTY))
    assert np.array_equal(owner, want) and 0 < np.count_nonzero(owner == _EMPTY) < owner.size


def numpy_pixel_cells(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray,
                      origin_m: tuple[float, float], cell_m: float, shape: tuple[int, int]) -> np.ndarray:
    """``session.pixel_cells`` in numpy (as it was written before its compiled pass)."""
    depth = np.asarray(depth_m, dtype=np.float32)
    intr = fit_intrinsics(intrinsics, depth.shape)
    rx, ry = pixel_rays(intr)
    valid = valid_depth(depth)
    T = np.asarray(T_world_camera, dtype=np.float64)
    R, t = T[:3, :3].astype(np.float32), T[:3, 3]
    z = np.where(valid, depth, np.float32(0))
    ox, oy = origin_m
    wx = (R[0, 0] * rx + R[0, 1] * ry + R[0, 2]) * z + np.float32(t[0] - ox)
    wy = (R[1, 0] * rx + R[1, 1] * ry + R[1, 2]) * z + np.float32(t[1] - oy)
    inv = np.float32(1.0 / cell_m)
    i = np.floor(wx * inv, out=wx)
    j = np.floor(wy * inv, out=wy)
    ny, nx = shape
    inside = valid & (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    j *= np.float32(nx)
    j += i
    np.copyto(j, np.float32(ny * nx), where=~inside)
    return j.astype(np.intp)


@pytest.mark.parametrize("seed", range(6))
def test_pixel_cells_are_the_array_expressions(seed: int) -> None:
    """The frame's pixels' cells in a region (tilted poses, holes of every kind, a region that cuts the view on
    some sides): the same index as the numpy code at every pixel, and some pixels inside, some outside."""
    from types import SimpleNamespace

    from slzcli.fusion.session import pixel_cells

    rng = np.random.default_rng(100 + seed)
    x, y = rng.uniform(-50, 50, 2)
    T = _tilted(rng, float(x), float(y), float(rng.uniform(3, 12)))
    depth = _frame(rng, T)
    cell = 0.082
    nx, ny = (int(v) for v in rng.integers(40, 200, 2))
    origin = (float(x + rng.uniform(-6, 0)), float(y + rng.uniform(-6, 0)))
    reg = SimpleNamespace(origin_m=origin, cell_m=cell, shape=(ny, nx))
    got = pixel_cells(SimpleNamespace(region=reg), depth, INTR, T)   # type: ignore[arg-type]
    want = numpy_pixel_cells(depth, INTR, T, origin, cell, (ny, nx))
    assert got.dtype == want.dtype and np.array_equal(got, want)
    assert 0 < np.count_nonzero(got < nx * ny) < got.size


def test_the_verdicts_shared_window_terms_and_step_windows_are_the_same_bits() -> None:
    """``verdict._plane_fit`` on the window terms the maps share gives what it gives from the heights alone, and
    ``verdict.step_fits``' full windows (an erosion) are those of the sum of ones it replaced (random holes, a corner
    unseen, every window size the maps use)."""
    import cv2

    from slzcli.fusion.verdict import _plane_fit, _window_terms, step_fits, step_kernel

    rng = np.random.default_rng(7)
    some = 0
    for _ in range(12):
        ny, nx = (int(v) for v in rng.integers(5, 200, 2))
        ok = rng.random((ny, nx)) > rng.uniform(0, 0.1)
        ok[: rng.integers(0, ny), : rng.integers(0, nx)] = False
        h = rng.normal(0, 0.1, (ny, nx)) + 0.01 * np.arange(nx)[None, :]
        hc = np.where(ok, h, 0.0)
        rows = int(rng.choice([3, 5, 7, 9, 11, 13, 15]))
        terms = _window_terms(hc, ok, 0.082)
        for n in (3, rows):
            for a, b in zip(_plane_fit(h, ok, n, 0.082), _plane_fit(hc, ok, n, 0.082, terms), strict=True):
                assert np.array_equal(a, b, equal_nan=True)
        half = max(2, rows // 2)
        w, _ = step_kernel(rows, half)
        got = step_fits(hc, ok, rows, half)
        for kern, s in zip((w, np.ascontiguousarray(w.T)), got, strict=True):
            ones = (kern != 0).astype(np.float64)
            est = cv2.filter2D(hc, cv2.CV_64F, kern, borderType=cv2.BORDER_CONSTANT)
            full = cv2.filter2D(ok.astype(np.float64), cv2.CV_64F, ones,
                                borderType=cv2.BORDER_CONSTANT) >= ones.sum() - 0.5
            assert np.array_equal(s, np.where(full, est, np.nan), equal_nan=True)
            some += int(0 < np.count_nonzero(full) < full.size)
    assert some >= 12       # windows full and not full were compared
