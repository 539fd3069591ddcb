"""The fusion's per-frame loops, compiled (numba): a frame's samples binned into cells, and the cells' update.

Why compiled: a frame is ~100,000 samples and ~12,000 cells, and the array expressions of ``measure`` and
``grid`` passed over them some 60 times (temporaries, masks, gathers, scatters, one ``np.bincount`` per
mean): numpy's fixed cost per pass was most of the fusion's time. Each loop here does the same IEEE operations
in the same order as the expressions it replaces (float32 where they were float32, weighted sums in sample
order as ``np.bincount`` adds them), so the results are the same bits; ``exp`` and ``log``, whose numpy
versions are vectorised and differ from libm's in the last bit, stay in numpy between the loops
(tests/fusion/test_kernels.py holds the loops equal to the array expressions on random frames and grids).

Compiled on first use and cached on disk beside this file (``cache=True``); ``warm_up`` does that before a
run's first timed frame. ``nogil``: a thread that fuses does not hold up the others.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from slzcli.errors import ConfigError

# the float fields of a grid slot (grid.FusedGrid.state's columns; grid.py names them)
H, C, PHH, PHC, PCC, SIGC, SIG1, U, V, SPREAD, POSEV, STEPR, TANR, NISS, NISN = range(15)
FIELDS = NISN + 1

_jit = njit(cache=True, nogil=True, error_model="numpy")   # numpy's float errors: inf / nan, no exception
_NONE = np.iinfo(np.int16).min     # a sample's cell in ``bin_samples`` when the sample is not kept
MAX_HALF = np.iinfo(np.int16).max - 1   # the window's half side in cells that ``bin_samples``' int16 cells hold


@_jit
def inverse_depth(depth):
    """(1 / depth where it is finite and positive else 0, that validity as 1 / 0), both float32: what
    ``measure.window_depths`` sums, in one pass."""
    inv = np.empty(depth.shape, np.float32)
    valid = np.empty(depth.shape, np.float32)
    one, zero = np.float32(1.0), np.float32(0.0)
    for j in range(depth.shape[0]):
        for i in range(depth.shape[1]):
            d = depth[j, i]
            if d > 0 and d < np.inf:
                inv[j, i] = one / d
                valid[j, i] = one
            else:
                inv[j, i] = zero
                valid[j, i] = zero
    return inv, valid


@_jit
def _add_row(inv, valid, col_inv, col_n, sign):
    """Add (sign 1) or take away (-1) one row's inverse depths and depth counts to / from the column sums."""
    for i in range(inv.size):
        col_inv[i] += sign * inv[i]
        col_n[i] += sign * valid[i]


@_jit
def window_depth(depth, block, window):
    """``measure.window_depths`` by sliding sums, for blocks of 2 px or more: one pass down the frame, the window's
    column sums slide from block row to block row (each image row added once and taken away once), and a block's
    sum is a difference of their running sums along the row; float64 sums."""
    h, w = depth.shape
    oh, ow = h // block, w // block
    out = np.empty((oh, ow), np.float32)
    lo = window // 2
    hi = window - 1 - lo
    inv, valid = inverse_depth(depth)
    col_inv = np.zeros(w, np.float64)
    col_n = np.zeros(w, np.float64)      # whole numbers: exact
    run_inv = np.zeros(w + 1, np.float64)
    run_n = np.zeros(w + 1, np.float64)
    r0, r1 = 0, -1          # the rows the column sums hold
    for jb in range(oh):
        p = jb * block + block // 2
        a, b = max(0, p - lo), min(h - 1, p + hi)
        for r in range(r0, min(a, r1 + 1)):
            _add_row(inv[r], valid[r], col_inv, col_n, -1.0)
        for r in range(max(a, r1 + 1), b + 1):
            _add_row(inv[r], valid[r], col_inv, col_n, 1.0)
        r0, r1 = a, b
        for i in range(w):
            run_inv[i + 1] = run_inv[i] + col_inv[i]
            run_n[i + 1] = run_n[i] + col_n[i]
        rows = b - a + 1
        o = out[jb]
        for ib in range(ow):
            q = ib * block + block // 2
            c0, c1 = max(0, q - lo), min(w - 1, q + hi)
            n = run_n[c1 + 1] - run_n[c0]
            s = run_inv[c1 + 1] - run_inv[c0]
            o[ib] = np.float32(n / s) if (2.0 * n >= rows * (c1 - c0 + 1)) & (n > 0) else np.float32(0.0)
    return out


@_jit
def window_ratio(num, den, rows_in, cols_in):
    """The depth of window means of inverse depth from the windows' sums ``num`` (inverse depth) and ``den``
    (pixels with depth): den / num where at least half the window's pixels in the image (``rows_in[j] x
    cols_in[i]``) have depth, else 0 (``measure.window_depths``)."""
    out = np.empty(num.shape, np.float32)
    zero = np.float32(0.0)
    for j in range(num.shape[0]):
        for i in range(num.shape[1]):
            n = den[j, i]
            out[j, i] = n / num[j, i] if (n + n >= rows_in[j] * cols_in[i]) & (n > 0) else zero
    return out


@_jit
def bin_samples(a, rx, ry, r, off_x, off_y, inv, half, min_samples, t, cell, cxy, pose_var2, rad2):
    """One frame's samples binned into cells: per cell with ``min_samples`` or more, the means of the samples'
    height (relative to the camera), squared height, depth and ray's vertical component, float64 sums in
    sample order.

    The samples: ``a``, the depth (finite and positive: a sample; ``measure.window_depths`` gives that of the
    samples' windows). ``rx`` (W,), ``ry`` (H,): the rays; ``r``: the pose's rotation in float32; a sample's cell is
    floor((w + off) inv) in float32 relative to the camera's cell ``cxy``. ``half``: samples whose cell is
    farther than that from the camera's cell in x or y are dropped (the window; at most ``MAX_HALF``). Returns
    (status, cells_x, cells_y, h, spread, zc, upc, pose_var): status 0 with empty arrays when no sample was
    kept."""
    n_rows, n_cols = a.shape
    # the sample's cell relative to the camera's (_NONE: not kept), in int16: half the bytes of int32 to write
    # and read back, and the loop below vectorises on them (1.9 ms against 3.1 ms a 640 x 480 frame)
    cx = np.empty((n_rows, n_cols), np.int16)
    cy = np.empty((n_rows, n_cols), np.int16)
    zero = np.float32(0.0)
    big = np.float32(np.inf)
    fh = np.float32(half)
    none = np.int16(_NONE)
    # the bounds of the kept samples' cells in integers and by selects, no branch (float min / max with their
    # NaN rules were half of the loop's time)
    x0, x1, y0, y1 = half, -half, half, -half
    for j in range(n_rows):
        y = ry[j]
        bx = r[0, 1] * y
        by = r[1, 1] * y
        for i in range(n_cols):
            z = a[j, i]
            good = z > 0 and z < big
            z = z if good else zero
            x = rx[i]
            ca = np.floor(((r[0, 0] * x + bx + r[0, 2]) * z + off_x) * inv)
            cb = np.floor(((r[1, 0] * x + by + r[1, 2]) * z + off_y) * inv)
            # a sample without depth sits in the camera's cell (z = 0): never outside the window, so "keep
            # the samples within the window" is the same as "drop them only when some sample is outside"
            keep = good and abs(ca) <= fh and abs(cb) <= fh
            ia = np.int16(ca) if keep else none
            ib = np.int16(cb) if keep else none
            cx[j, i] = ia
            cy[j, i] = ib
            x0 = ia if keep and ia < x0 else x0
            x1 = ia if keep and ia > x1 else x1
            y0 = ib if keep and ib < y0 else y0
            y1 = ib if keep and ib > y1 else y1
    if x0 > x1:
        e = np.empty(0, np.float64)
        return 0, np.empty(0, np.int64), np.empty(0, np.int64), e, e, e, e, e
    nx = x1 - x0 + 1
    size = nx * (y1 - y0 + 1)
    count = np.zeros(size, np.int64)
    sums = np.zeros((size, 4), np.float64)   # wz, wz^2, z, up
    for j in range(n_rows):
        y = ry[j]
        bz = r[2, 1] * y
        for i in range(n_cols):
            ia = cx[j, i]
            if ia == none:
                continue
            k = (cy[j, i] - y0) * nx + ia - x0
            z = a[j, i]
            up = r[2, 0] * rx[i] + bz + r[2, 2]
            wz = up * z
            count[k] += 1
            sums[k, 0] += wz
            sums[k, 1] += wz * wz
            sums[k, 2] += z
            sums[k, 3] += up
    cells = 0
    for k in range(size):
        if count[k] >= min_samples:
            cells += 1
    cells_x = np.empty(cells, np.int64)
    cells_y = np.empty(cells, np.int64)
    h = np.empty(cells, np.float64)
    spread = np.empty(cells, np.float64)
    zc = np.empty(cells, np.float64)
    upc = np.empty(cells, np.float64)
    pose_var = np.empty(cells, np.float64)
    c = 0
    for k in range(size):
        if count[k] < min_samples:
            continue
        n = np.float64(count[k])
        m = sums[k, 0] / n
        d = sums[k, 1] / n - m * m
        if d < 0.0:
            d = 0.0
        spread[c] = np.sqrt(d)
        h[c] = m + t[2]
        zc[c] = sums[k, 2] / n
        upc[c] = abs(sums[k, 3] / n)
        gx = k % nx + x0 + cxy[0]
        gy = k // nx + y0 + cxy[1]
        cells_x[c] = gx
        cells_y[c] = gy
        if rad2 > 0.0:
            dx = (gx + 0.5) * cell - t[0]
            dy = (gy + 0.5) * cell - t[1]
            pose_var[c] = pose_var2 + (dx * dx + dy * dy) * rad2
        else:
            pose_var[c] = pose_var2
        c += 1
    return 1, cells_x, cells_y, h, spread, zc, upc, pose_var


@_jit
def _pixel(px, py, h, r, t, cam):
    """Pixel (u, v) and depth of the point (px, py) from the camera in plan at height ``h``
    (``measure.CellView.at``'s arithmetic)."""
    pz = h - t[2]
    xc = (r[0, 0] * px + r[1, 0] * py) + r[2, 0] * pz
    yc = (r[0, 1] * px + r[1, 1] * py) + r[2, 1] * pz
    zc = (r[0, 2] * px + r[1, 2] * py) + r[2, 2] * pz
    return cam[0] * xc / zc + cam[2], cam[1] * yc / zc + cam[3], zc


@_jit
def cell_shifts(owner, state, ix, iy, y, side, cell, r, t, cam):
    """Per cell of a frame: its slot, whether the slot holds it, its centre's pixel at its height (the fused
    one when held, else the measured ``y``) and how far that moved in the image since the last look.
    ``cam``: fx, fy, cx, cy."""
    n = ix.size
    slot = np.empty(n, np.int64)
    owned = np.empty(n, np.bool_)
    u = np.empty(n, np.float64)
    v = np.empty(n, np.float64)
    shift = np.empty(n, np.float64)
    for c in range(n):
        k = (iy[c] % side) * side + ix[c] % side
        own = owner[k] == ((ix[c] << 32) ^ (iy[c] & 0xFFFFFFFF))
        px = (ix[c] + 0.5) * cell - t[0]
        py = (iy[c] + 0.5) * cell - t[1]
        uc, vc, _ = _pixel(px, py, state[k, H] if own else y[c], r, t, cam)
        slot[c], owned[c], u[c], v[c] = k, own, uc, vc
        shift[c] = math.hypot(uc - state[k, U], vc - state[k, V])
    return slot, owned, u, v, shift


@_jit
def _max(a, b):
    """np.maximum: NaN when either is."""
    return a if (a != a or a >= b) else b


@_jit
def _min(a, b):
    return a if (a != a or a <= b) else b


COLUMN_LEVELS = 64   # levels of the column above a cell, one bit each of a uint64


@_jit
def _lowest_zero_bit(bits):
    """Index of the lowest bit not set (``bits`` not all ones): log2 of that bit alone, exact for a power of 2."""
    low = ~bits & (bits + np.uint64(1))
    return int(np.log2(float(low)) + 0.5)


@_jit
def column_clear(free, blocked):
    """The descent column above a cell is clear: its lowest level (control.desired_depth_m) seen free, and every
    level some frame had in view with depth seen free by some frame (one only ever seen behind something, or at
    a surface, is under an overhang or hidden by one)."""
    return (free & np.uint64(1)) != 0 and (blocked & ~free) == 0


@_jit
def update_cells(owner, state, frames, rejected, column, blocked, last_frame, slot, owned, u, v, rho, ix, iy, y,
                 sigma_w, sigma_c, spread, pose_var, gate2, gate_scale, sig1_den, step_ratio, tan_ratio, frame_index,
                 column_m, column_step, cell, r, t, cam, depth, free_a, free_k, nadir_in_view):
    """The Kalman update of a frame's cells in their slots (in place; grid.fuse says what each step means).
    Returns (new cells, rejected, the normalised innovation squared of the cells held before, in order). The gate
    widens the innovation's variance by ``gate_scale`` (the frame's, ``grid.fuse``). Every look at a cell held
    before adds its normalised innovation squared (at most ``gate2``) to the cell's ``NISS`` and one to ``NISN``
    (``grid.region``'s noise scale).

    Then the column above each cell, ``COLUMN_LEVELS`` levels ``column_step`` apart from ``column_m`` up:
    ``column`` gains the levels this frame saw free (its ``depth`` at the level's pixel beyond the level by
    ``free_k`` x the depth's noise ``free_a D^2``), ``blocked`` the levels it had in view with a depth nearer
    than that (something at or in front of them: a crown, a roof, a pole between); a level without depth at its
    pixel, outside the image or behind the camera, neither. A vertical line's image runs away from the image of the
    nadir as it rises: once out of the image it stays out when that point is in the view (``nadir_in_view``) or a
    lower level was in it."""
    n = slot.size
    nis = np.empty(n, np.float64)
    n_owned = 0
    n_new = 0
    n_rej = 0
    for c in range(n):
        k = slot[c]
        own = owned[c]
        sw2 = sigma_w[c] * sigma_w[c]
        sc2 = sigma_c[c] * sigma_c[c]
        rh = rho[c]
        sc_old = state[k, SIGC]
        g = rh * (sigma_c[c] / sc_old) if sc_old > 0 else rh * 1.0
        cc = g * state[k, C]
        p_hh = state[k, PHH]
        p_hc = g * state[k, PHC]
        p_cc = g * g * state[k, PCC] + (1.0 - rh * rh) * sc2
        innov = y[c] - (state[k, H] + cc)
        s_t = p_hh + 2.0 * p_hc + p_cc + sw2
        ok = innov * innov <= gate2 * (gate_scale * s_t + pose_var[c])
        if own:
            e2 = innov * innov / s_t
            nis[n_owned] = e2
            n_owned += 1
            state[k, NISS] += _min(e2, gate2)
            state[k, NISN] += 1.0
            if ok:
                kh = (p_hh + p_hc) / s_t
                kc = (p_hc + p_cc) / s_t
                state[k, H] = state[k, H] + kh * innov
                state[k, C] = cc + kc * innov
                state[k, PHH] = p_hh - kh * kh * s_t
                state[k, PHC] = p_hc - kh * kc * s_t
                state[k, PCC] = p_cc - kc * kc * s_t
                state[k, SPREAD] = _max(state[k, SPREAD], spread[c])
                state[k, POSEV] = _min(state[k, POSEV], pose_var[c])
            else:
                rejected[k] += 1
                n_rej += 1
        else:
            n_new += 1
            state[k, H] = y[c]
            state[k, C] = 0.0
            state[k, PHH] = sc2 + sw2
            state[k, PHC] = -sc2
            state[k, PCC] = sc2
            state[k, SPREAD] = spread[c]
            state[k, POSEV] = pose_var[c]
            state[k, NISS] = 0.0
            state[k, NISN] = 0.0
            owner[k] = (ix[c] << 32) ^ (iy[c] & 0xFFFFFFFF)
            frames[k] = 0
            rejected[k] = 0
            column[k] = 0
            blocked[k] = 0
        if ok or not own:
            state[k, U] = u[c]
            state[k, V] = v[c]
            state[k, SIGC] = sigma_c[c]
            state[k, SIG1] = np.sqrt((sc2 + sw2) / sig1_den)
            state[k, STEPR] = step_ratio
            state[k, TANR] = tan_ratio
        frames[k] += 1
        last_frame[k] = frame_index
        # the column above the cell's (updated) height, level by level from column_m up; a level seen free once
        # is not looked at again
        px = (ix[c] + 0.5) * cell - t[0]
        py = (iy[c] + 0.5) * cell - t[1]
        free = column[k]
        if ~free == 0:
            continue
        first = _lowest_zero_bit(free)  # the levels below were all seen free: not looked at again
        entered = first > 0
        for lv in range(first, COLUMN_LEVELS):
            bit = np.uint64(1) << np.uint64(lv)
            if free & bit:
                entered = True
                continue
            uc, vc, zc = _pixel(px, py, state[k, H] + column_m + lv * column_step, r, t, cam)
            if zc <= 0:
                break                  # this level and the ones above are behind the camera
            ju = int(np.floor(uc + 0.5))
            jv = int(np.floor(vc + 0.5))
            if ju < 0 or ju >= depth.shape[1] or jv < 0 or jv >= depth.shape[0]:
                if entered or nadir_in_view:
                    break
                continue
            entered = True
            d = depth[jv, ju]
            if d > 0 and d < np.inf:
                if d - free_k * free_a * d * d > zc:
                    free |= bit
                else:
                    blocked[k] |= bit
        column[k] = free
    return n_new, n_rej, nis[:n_owned]


@_jit
def region_cells(owner, state, frames, rejected, column, blocked, x0, y0, nx, ny, side, fixed_fraction):
    """Cells x0..x0+nx-1, y0..y0+ny-1 of the window as dense arrays, in one pass (``grid.region``'s gathers and
    selects, the same operations): seen, then the float64 fields H, the terrain variance (PHH + fixed_fraction
    sig1^2), POSEV, PHC, PCC, SIGC, SIG1 (NaN unseen), looks (sig1^2 / variance, float32), frames, rejected
    (0 unseen), SPREAD, STEPR, TANR (float32, 0 unseen), the column clear (``column_clear``; False unseen), NISS and
    NISN (0 unseen)."""
    seen = np.zeros((ny, nx), np.bool_)
    f64 = np.full((7, ny, nx), np.nan)
    nis = np.zeros((2, ny, nx))
    looks = np.zeros((ny, nx), np.float32)
    fr = np.zeros((ny, nx), np.int32)
    rej = np.zeros((ny, nx), np.int32)
    f32 = np.zeros((3, ny, nx), np.float32)
    col = np.zeros((ny, nx), np.bool_)
    for j in range(ny):
        y = y0 + j
        for i in range(nx):
            x = x0 + i
            k = (y % side) * side + x % side
            if owner[k] != ((x << 32) ^ (y & 0xFFFFFFFF)):
                continue
            seen[j, i] = True
            sig1 = state[k, SIG1]
            var = state[k, PHH] + fixed_fraction * sig1 * sig1
            f64[0, j, i] = state[k, H]
            f64[1, j, i] = var
            f64[2, j, i] = state[k, POSEV]
            f64[3, j, i] = state[k, PHC]
            f64[4, j, i] = state[k, PCC]
            f64[5, j, i] = state[k, SIGC]
            f64[6, j, i] = sig1
            nis[0, j, i] = state[k, NISS]
            nis[1, j, i] = state[k, NISN]
            looks[j, i] = np.float32(sig1 * sig1 / var)
            fr[j, i] = frames[k]
            rej[j, i] = rejected[k]
            f32[0, j, i] = np.float32(state[k, SPREAD])
            f32[1, j, i] = np.float32(state[k, STEPR])
            f32[2, j, i] = np.float32(state[k, TANR])
            col[j, i] = column_clear(column[k], blocked[k])
    return seen, f64, looks, fr, rej, f32, col, nis


@_jit
def scale_variances(f64, q):
    """``region_cells``' variance fields scaled in place by the noise scale ``q`` (the variance, PHC, PCC) and its
    square root (the stds SIGC, SIG1), in one pass; ``x * 1.0`` is ``x``, so cells at 1 are skipped."""
    ny, nx = q.shape
    for j in range(ny):
        for i in range(nx):
            s = q[j, i]
            if s != 1.0:
                r = np.sqrt(s)
                f64[1, j, i] *= s
                f64[3, j, i] *= s
                f64[4, j, i] *= s
                f64[5, j, i] *= r
                f64[6, j, i] *= r


@_jit
def pixel_cells(depth, rx, ry, r, off_x, off_y, inv, nx, ny):
    """Per pixel: the flat index j nx + i of its cell in an ny x nx region (its point on the ground by its depth:
    column floor((w + off) inv), all in float32), ny nx where it has no depth or falls outside
    (``session.pixel_cells``'s arithmetic, in one pass instead of a dozen over the frame)."""
    out = np.empty(depth.shape, np.intp)
    big = np.float32(np.inf)
    zero = np.float32(0.0)
    fnx = np.float32(nx)
    fny = np.float32(ny)
    outside = ny * nx
    for j in range(depth.shape[0]):
        y = ry[j]
        for i in range(depth.shape[1]):
            z = depth[j, i]
            if not (z > 0 and z < big):
                out[j, i] = outside
                continue
            x = rx[i]
            ci = np.floor(((r[0, 0] * x + r[0, 1] * y + r[0, 2]) * z + off_x) * inv)
            cj = np.floor(((r[1, 0] * x + r[1, 1] * y + r[1, 2]) * z + off_y) * inv)
            inside = ci >= zero and ci < fnx and cj >= zero and cj < fny
            out[j, i] = int(cj) * nx + int(ci) if inside else outside
    return out


def median_inplace(a: np.ndarray) -> float:
    """``np.median`` of a 1-d float array (NaN when any is NaN or there are none), reordering it: the middle
    value, or the mean of the two middle ones in ``a``'s own type, as numpy's. Not compiled: numpy's
    ``partition`` (a vectorised selection) is ~10x faster than a compiled quickselect over 20,000 values, and
    ``np.median`` itself, which partitions at three places, ~5x slower than one partition."""
    n = a.size
    if n == 0:
        return math.nan
    k = n // 2
    a.partition(k)                  # NaN sorts last: after it a[:k] <= a[k] <= a[k + 1:]
    hi = a[k]
    if hi != hi or np.isnan(a[k + 1:]).any():
        return math.nan
    if n % 2:
        return float(hi)
    lo = a[:k].max()
    return float((lo + hi) / a.dtype.type(2))


@_jit
def valid_depths(depth, step):
    """The finite, positive depths on the grid of every ``step``-th pixel, row by row."""
    buf = np.empty(((depth.shape[0] + step - 1) // step) * ((depth.shape[1] + step - 1) // step), depth.dtype)
    n = 0
    for j in range(0, depth.shape[0], step):
        for i in range(0, depth.shape[1], step):
            d = depth[j, i]
            if d > 0 and d < np.inf:
                buf[n] = d
                n += 1
    return buf[:n]


def median_depth(depth: np.ndarray, step: int) -> float:
    """``terrain.geometry.median_depth_m``: the median of the finite, positive depths on the grid of every
    ``step``-th pixel (NaN: none)."""
    return median_inplace(valid_depths(depth, step))


@_jit
def sweep(owner, cx, cy, reach, empty):
    """Forget (owner = ``empty``) the cells more than ``reach`` cells from cell (cx, cy) in x or y."""
    for k in range(owner.size):
        key = owner[k]
        if key == empty:
            continue
        x = key >> 32
        y = key & 0xFFFFFFFF
        if y >= 1 << 31:
            y -= 1 << 32
        if abs(x - cx) > reach or abs(y - cy) > reach:
            owner[k] = empty


def bin_frame(a: np.ndarray, rx: np.ndarray, ry: np.ndarray, r: np.ndarray, off_x: float, off_y: float, inv: float,
              half: int, min_samples: int, t: np.ndarray, cell: float, cxy: tuple[int, int], pose_var2: float,
              rad2: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                    np.ndarray]:
    """``bin_samples`` with its arguments in the types it was compiled for (one compilation serves every frame):
    ``a`` the samples' depth (the frame's, or its ``measure.window_depths``)."""
    if half > MAX_HALF:
        raise ConfigError("terrain.fusion.window_m", f"{2 * half + 2} cells wide; the fusion takes at most "
                          f"{2 * MAX_HALF + 2}: make it smaller, or the cells larger "
                          "(terrain.fusion.cells_per_footprint)")
    f32 = np.float32
    return bin_samples(readonly(a, f32), readonly(rx.reshape(-1), f32),
                       readonly(ry.reshape(-1), f32), np.array(r, f32), f32(off_x), f32(off_y), f32(inv), int(half),
                       int(min_samples), np.array(t, np.float64), float(cell), np.array(cxy, np.int64),
                       float(pose_var2), float(rad2))


def readonly(a: np.ndarray, dtype: type) -> np.ndarray:
    """A contiguous read-only view (a copy only when the layout or type differs): the one array type compiled."""
    v = np.ascontiguousarray(a, dtype).view()
    v.flags.writeable = False
    return v


@functools.lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the loops (or load them from the disk cache) on a tiny frame, once per process, so that no
    timed frame pays for it."""
    r = np.eye(3)
    t = np.zeros(3)
    cam = np.ones(4)
    one = np.ones((2, 2), np.float32)
    bin_frame(one, np.zeros(2), np.zeros(2), r, 0.0, 0.0, 1.0, 4, 2, t, 1.0, (0, 0), 0.0, 0.0)
    window_depth(one, 2, 2)
    window_ratio(one, one, np.ones(2, np.float32), np.ones(2, np.float32))
    f32 = np.float32
    ray = readonly(np.zeros(2), f32)
    pixel_cells(readonly(one, f32), ray, ray, np.eye(3, dtype=f32), f32(0.0), f32(0.0), f32(1.0), 2, 2)
    valid_depths(readonly(one, np.float32), 4)
    sweep(np.zeros(1, np.int64), 0, 0, 1, -1)
    scale_variances(np.ones((7, 1, 1)), np.full((1, 1), 2.0))
    region_cells(np.zeros(1, np.int64), np.zeros((1, FIELDS)), np.zeros(1, np.int32), np.zeros(1, np.int32),
                 np.zeros(1, np.uint64), np.zeros(1, np.uint64), 0, 0, 1, 1, 1, 0.0)
    i = np.zeros(1, np.int64)
    x = np.zeros(1)
    owner = np.zeros(1, np.int64)
    state = np.zeros((1, FIELDS))
    slot, owned, u, v, _ = cell_shifts(owner, state, i, i, x, 1, 1.0, r, t, cam)
    bits = np.zeros(1, np.uint64)
    update_cells(owner, state, np.zeros(1, np.int32), np.zeros(1, np.int32), bits, bits.copy(),
                 np.zeros(1, np.int64), slot, owned, u, v, x, i, i, x, x, x, x, x, 1.0, 1.0, 1.0, 0.0, 0.0, 0, 1.0,
                 0.25, 1.0, r, t, cam, readonly(one, np.float32), 0.0, 3.0, True)
