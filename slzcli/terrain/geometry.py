"""Organised-cloud geometry in image space: points, per-pixel normals, patch PCA (METHOD 2.1, 2.3).

Everything here works on the depth image as an organised point cloud, so neighbourhoods are
image windows and sums over them are box filters (OpenCV) or integral-image lookups: no
k-d tree and no Python loop over pixels. Holes (NaN depth) are handled by normalised
convolution: every window statistic is a sum over the valid pixels only, divided by the
valid count, so a hole never leaks a value into its neighbours; a window with too few valid
pixels is itself invalid (NaN).

Decisions (documented here because they shape the numbers):

* Normals come from a weighted least-squares plane fit of the *inverse depth* ``w = 1/Z``
  over a ``k x k`` window. For a pinhole camera a 3-D plane ``n . P = d`` is exactly linear in
  pixel coordinates in inverse depth, ``w = (n . r) / d`` with ``r = ((u-cx)/fx, (v-cy)/fy, 1)``,
  so the fit is exact on planes at any window size, tilt or distance, and the normal
  follows in closed form from the fitted gradient: ``n ~ (fx w_u, fy w_v, w - fx w_u rx - fy w_v ry)``.
* Patch PCA (inclination) runs on a reduced image ``work_px`` wide: each reduced cell holds the
  mean of its valid points, weighted by its valid count (a voxel-grid style subsampling).
  The window around every cell is the image footprint of a *level* disc of radius
  ``radius_m`` (normal = gravity up; face-on without gravity) at the cell's *own* depth:
  per-pixel adaptive and anisotropic (an obliquely seen floor gets a window short in v), an
  axis-aligned rectangle of equal area to the disc when seen face-on (half-side
  ``sqrt(pi)/2 * r * f / Z``), at least 3 x 3 cells. Window sums are taken from
  integral images in float64 of coordinates centred on the frame's mean point, so
  ``E[xx] - E[x]^2`` keeps its digits at any altitude. The curvature is upsampled bilinearly.
  Unlike a 3-D radius search the window does not reject points far behind or in front of
  the patch (a wall behind a box edge counts); near depth edges that only makes the patch
  look more cluttered, which is the safe direction.

Checked against Open3D in tests/terrain/test_terrain.py: normals within a median 1.1 deg (90th
percentile < 2.2 deg) of ``estimate_normals`` with KNN k*k on noisy planes and ramps; patch
curvature ~0 where Open3D's radius-0.5 m covariance is ~0, and 0.3-2x Open3D's where a step
lower than the radius puts both levels in the ball. Open3D takes 0.6-1.7 s per 640x480
frame for the normals alone (benchmarks/terrain.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.geometry import back_project as back_project  # Eq. 1 lives in slzcli.geometry (outputs use it too)
from slzcli.geometry import fit_intrinsics as fit_intrinsics
from slzcli.geometry import pixel_rays as pixel_rays
from slzcli.geometry import valid_depth as valid_depth
from slzcli.types import Intrinsics

# Numerical guards (not tuning parameters): a 2x2 / 3x3 moment matrix whose determinant is
# below this fraction of the product of its diagonal is treated as degenerate (collinear
# pixels), and eigenvalues are clipped at zero against round-off.
_DEGENERATE_REL_DET = 1e-6
# Side of the square with the same area as a disc of radius 1 (sqrt(pi)); half of it is
# the window half-width per unit of projected radius.
_EQUAL_AREA_HALF_SIDE = math.sqrt(math.pi) / 2.0


# ----------------------------------------------------------------------------- metric windows
DEPTH_SUBSAMPLE = 4  # px step of the grid a frame's median depth is taken on (a median needs no more)


def block_depth(depth_m: np.ndarray, valid: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """(depth, valid) of block x block means of inverse depth (a plane stays a plane), inverted; a block
    needs half its pixels with depth (NaN otherwise). The grid is (W // block) x (H // block)."""
    h, w = depth_m.shape
    size = (max(1, w // block), max(1, h // block))
    inv = np.zeros(depth_m.shape, np.float32)
    np.divide(np.float32(1.0), depth_m, out=inv, where=valid)
    num = cv2.resize(inv, size, interpolation=cv2.INTER_AREA)
    den = cv2.resize(valid.view(np.uint8).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    ok = (den >= 0.5) & (num > 0)
    depth: np.ndarray = np.full(num.shape, np.nan, np.float32)
    np.divide(den, num, out=depth, where=ok)
    return depth, ok


def median_depth_m(depth_m: np.ndarray) -> float | None:
    """Median of the finite, positive depths on a coarse grid; None when there are none."""
    d = np.asarray(depth_m)[::DEPTH_SUBSAMPLE, ::DEPTH_SUBSAMPLE]
    d = d[np.isfinite(d) & (d > 0)]
    return float(np.median(d)) if d.size else None


def window_px(side_m: float, focal_px: float, depth_m: float) -> int:
    """Odd window side in pixels covering ``side_m`` metres at ``depth_m``."""
    side = side_m * focal_px / depth_m
    return max(1, 2 * math.ceil((side - 1) / 2) + 1)


# ----------------------------------------------------------------------------- normals
@dataclass(frozen=True, eq=False)
class NormalField:
    """Unnormalised per-pixel normals (float32 H x W each), pointing towards the camera.

    ``nx, ny, nz`` share one scale per pixel; ``ok`` marks pixels with a normal. Kept as
    separate planes because the maps only need dot products with gravity.
    """

    nx: np.ndarray
    ny: np.ndarray
    nz: np.ndarray
    ok: np.ndarray

    def norm(self) -> np.ndarray:
        """|n| per pixel (float32), the same bits wherever the three planes lie in memory.

        Squares, sums and a square root in numpy, each rounded as IEEE 754 says, not ``cv2.magnitude``:
        OpenCV's IPP kernel for it rounds the elements before the first aligned address and after the
        last differently from the rest (by an ulp), so its result depended on where the allocator put
        the planes, and the slope of a run's frame changed from run to run of the same code.
        """
        sq = np.multiply(self.nx, self.nx)
        part = np.multiply(self.ny, self.ny)
        sq += part
        np.multiply(self.nz, self.nz, out=part)
        sq += part
        return np.sqrt(sq, out=sq)

    def unit(self) -> np.ndarray:
        """H x W x 3 float32 unit normals, NaN where there is none."""
        norm = self.norm()
        inv = np.full_like(norm, np.nan)
        np.divide(np.float32(1.0), norm, out=inv, where=self.ok & (norm > 0))
        return cv2.merge([self.nx * inv, self.ny * inv, self.nz * inv])


def normal_field(depth_m: np.ndarray, intrinsics: Intrinsics, window_px: int,
                 min_valid_fraction: float, valid: np.ndarray | None = None) -> NormalField:
    """Least-squares plane of inverse depth over a ``window_px`` window, valid-only sums.

    Fast path for windows without holes (the fit reduces to three correlations); the full
    weighted fit runs only on pixels whose window is partly empty. No normal where the pixel
    has no depth, less than ``min_valid_fraction`` of its window is valid, or the valid
    pixels are collinear. ``valid`` may be passed when already known (``valid_depth``).
    """
    intr = fit_intrinsics(intrinsics, depth_m.shape)
    valid = valid_depth(depth_m) if valid is None else valid
    w0 = np.zeros(depth_m.shape, dtype=np.float32)
    np.divide(np.float32(1.0), depth_m, out=w0, where=valid)

    k = int(window_px)
    t = np.arange(-(k // 2), k // 2 + 1, dtype=np.float32)
    one = np.ones(k, dtype=np.float32)
    full_n = float(k * k)
    full_ctt = float(k * (t * t).sum())                  # sum of t^2 over a full window

    def corr(img: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        # sum over the window of img(v+j, u+i) kx[i] ky[j]; outside the image counts as a hole
        return cv2.sepFilter2D(img, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_CONSTANT)

    m = valid.view(np.uint8)
    s0 = cv2.boxFilter(m, cv2.CV_32F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    ok = valid & (s0 >= min_valid_fraction * full_n)
    gu = corr(w0, t, one)                                # becomes d(1/Z)/du
    gv = corr(w0, one, t)                                # becomes d(1/Z)/dv
    wc = cv2.boxFilter(w0, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    partial = ok & (s0 < full_n)
    idx = np.flatnonzero(partial)
    if idx.size:
        mf = m.astype(np.float32)

        def at(img: np.ndarray) -> np.ndarray:
            return np.take(img.reshape(-1), idx)

        n = at(s0)
        su, sv = at(corr(mf, t, one)), at(corr(mf, one, t))
        suu, svv = at(corr(mf, t * t, one)), at(corr(mf, one, t * t))
        suv = at(corr(mf, t, t))
        sw, swu, swv = at(wc), at(gu), at(gv)
        mu, mv = su / n, sv / n                          # centroid of the valid pixels
        cuu, cvv, cuv = suu - su * mu, svv - sv * mv, suv - su * mv
        cwu, cwv = swu - sw * mu, swv - sw * mv
        det = cuu * cvv - cuv * cuv
        good = (det > _DEGENERATE_REL_DET * cuu * cvv) & (det > 0)
        det = np.where(good, det, np.float32(1.0))
        pu = (cvv * cwu - cuv * cwv) / det
        pv = (cuu * cwv - cuv * cwu) / det
        pw = sw / n - pu * mu - pv * mv
        ok.reshape(-1)[idx[~good]] = False
    gu *= np.float32(1.0 / full_ctt)
    gv *= np.float32(1.0 / full_ctt)
    wc *= np.float32(1.0 / full_n)                       # fitted 1/Z at the window centre
    if idx.size:
        for img, values in ((gu, pu), (gv, pv), (wc, pw)):
            np.put(img, idx, values)

    rx, ry = pixel_rays(intr)
    gu *= np.float32(-intr.fx)                           # nx (minus: towards the camera)
    gv *= np.float32(-intr.fy)                           # ny
    tmp = np.multiply(gu, rx)
    np.negative(wc, out=wc)
    wc -= tmp                                            # nz = -(1/Z) - nx rx - ny ry
    np.multiply(gv, ry, out=tmp)
    wc -= tmp
    return NormalField(nx=gu, ny=gv, nz=wc, ok=ok)


def plane_residual_var(inv_depth: np.ndarray, valid: np.ndarray, window_px: int,
                       min_valid_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Residual variance (float32, per pixel) of a least-squares plane fitted to ``inv_depth`` over
    a ``window_px`` window, valid pixels only, and where it is defined (enough valid pixels).

    Inverse depth is exactly linear in the pixel coordinates on any 3-D plane, so the residual
    is what is *not* a plane: roughness, steps, noise. Population variance (sum / n); sums in
    float64 (inverse depth at 10 m is 0.1, its residual 1e-4). Partial windows get the full
    weighted fit, like ``normal_field``.
    """
    k = int(window_px)
    t = np.arange(-(k // 2), k // 2 + 1, dtype=np.float64)
    one = np.ones(k, dtype=np.float64)
    full_n = float(k * k)
    full_ctt = float(k * (t * t).sum())
    w = np.where(valid, inv_depth, 0.0).astype(np.float64)
    m8 = valid.view(np.uint8)

    def corr(img: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(img, cv2.CV_64F, kx, ky, borderType=cv2.BORDER_CONSTANT)

    def corr_mask(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        # window sums of the 0/1 mask times integer weights are small integers, exact in float32:
        # the same values as the float64 sums at half the cost
        return cv2.sepFilter2D(m8, cv2.CV_32F, kx.astype(np.float32), ky.astype(np.float32),
                               borderType=cv2.BORDER_CONSTANT)

    n = cv2.boxFilter(m8, cv2.CV_32F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT).astype(np.float64)
    ok = valid & (n >= max(4.0, min_valid_fraction * full_n) - 0.5)
    sw, sww = corr(w, one, one), corr(w * w, one, one)
    swu, swv = corr(w, t, one), corr(w, one, t)
    nn = np.maximum(n, 1.0)
    partial = ok & (n < full_n - 0.5)
    idx = np.flatnonzero(partial)
    if idx.size:
        def at(img: np.ndarray) -> np.ndarray:
            return np.take(img.reshape(-1), idx).astype(np.float64, copy=False)

        cn, cw, cww, cwu, cwv = at(n), at(sw), at(sww), at(swu), at(swv)   # before the sums are reused below
    # full windows (u, v centred): ss = sww - sw sw / nn - swu swu / ctt - swv swv / ctt, the same
    # operations in the same order, in place (each 640x480 float64 temporary costs its page faults)
    ss = sww
    ss -= np.divide(np.multiply(sw, sw, out=sw), nn, out=sw)
    ss -= np.divide(np.multiply(swu, swu, out=swu), full_ctt, out=swu)
    ss -= np.divide(np.multiply(swv, swv, out=swv), full_ctt, out=swv)
    if idx.size:
        su, sv = at(corr_mask(t, one)), at(corr_mask(one, t))
        suu, svv, suv = at(corr_mask(t * t, one)), at(corr_mask(one, t * t)), at(corr_mask(t, t))
        mu, mv = su / cn, sv / cn                       # centre the regressors on the valid pixels
        cuu, cvv, cuv = suu - su * mu, svv - sv * mv, suv - su * mv
        xu, xv = cwu - cw * mu, cwv - cw * mv
        det = cuu * cvv - cuv * cuv
        good = (det > _DEGENERATE_REL_DET * cuu * cvv) & (det > 0)
        det = np.where(good, det, 1.0)
        pu = (cvv * xu - cuv * xv) / det
        pv = (cuu * xv - cuv * xu) / det
        np.put(ss, idx, cww - cw * cw / cn - pu * xu - pv * xv)
        ok.reshape(-1)[idx[~good]] = False
    var = np.maximum(ss, 0.0, out=ss)
    var /= nn
    return var.astype(np.float32), ok


def image_normals(depth_m: np.ndarray, intrinsics: Intrinsics, window_px: int,
                  min_valid_fraction: float) -> np.ndarray:
    """Unit surface normals (H x W x 3 float32, camera frame) oriented towards the camera; NaN where none.

    See ``normal_field`` for the estimator and validity rules.
    """
    return normal_field(depth_m, intrinsics, window_px, min_valid_fraction).unit()


# ----------------------------------------------------------------------------- patch PCA
@dataclass(frozen=True, eq=False)
class PatchPCA:
    """Patch covariance eigenvalues at the reduced resolution and the curvature at full size.

    eigenvalues: h x w x 3 float64 (l0 <= l1 <= l2, m^2), NaN where the patch is invalid.
    curvature_work: h x w float64, ``l0 / (l0 + l1 + l2)``, NaN where invalid.
    window_half_px: h x w x 2 int32, the half-sides (u, v) of each cell's window (reduced pixels).
    curvature: H x W float32, upsampled, NaN where the pixel has no depth or no valid patch.
    """

    eigenvalues: np.ndarray
    curvature_work: np.ndarray
    window_half_px: np.ndarray
    curvature: np.ndarray


def eigvalsh3(a00: np.ndarray, a01: np.ndarray, a02: np.ndarray, a11: np.ndarray,
              a12: np.ndarray, a22: np.ndarray) -> np.ndarray:
    """Eigenvalues (ascending, ... x 3) of symmetric 3x3 matrices given by their upper triangle.

    Closed form (trigonometric solution of the characteristic cubic), vectorised.
    """
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    det_b = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
             + a02 * (a01 * a12 - b11 * a02))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(p > 0, det_b / (2.0 * p * p * p), 0.0)
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    mid = 3.0 * q - hi - lo
    return np.stack([lo, mid, hi], axis=-1)


def _window_sums(integral: np.ndarray, width: int, y0: np.ndarray, y1: np.ndarray,
                 x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
    """Sums over per-pixel rectangles [y0, y1) x [x0, x1) from a (h+1)(w+1) x C integral -> h x w x C.

    Corner-major layout: each gather fetches C contiguous values (the fastest layout measured).
    """
    stride = width + 1

    def at(y: np.ndarray, x: np.ndarray) -> np.ndarray:
        return np.take(integral, (y * stride + x).ravel(), axis=0)

    s = at(y1, x1)
    s -= at(y0, x1)
    s -= at(y1, x0)
    s += at(y0, x0)
    return s.reshape((*y0.shape, integral.shape[-1]))


def _footprint_half_px(z_work: np.ndarray, intr_work: Intrinsics, radius_m: float,
                       up_camera: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Half-sides (u, v) in pixels of the window standing for the radius_m disc around each pixel.

    The disc is level (normal = world up, when known) or face-on (normal = -z): the surfaces a
    UAV may land on are near level, and a normal taken from the depth itself would be garbage
    exactly at the steps the patch must straddle. Its image extent along u is
    ``(r f / Z) sqrt(|j_u|^2 - (j_u . n)^2)`` with ``j_u = (1, 0, -X/Z)`` (the projection's
    Jacobian row), likewise v; scaled by sqrt(pi)/2 so a face-on window has the disc's area.
    Never less than 3 x 3 cells: when the disc is smaller than that (high altitude, small
    work_px) the patch is larger than radius_m.
    """
    n = np.array([0.0, 0.0, -1.0]) if up_camera is None else np.asarray(up_camera, dtype=np.float64)
    n = n / np.linalg.norm(n)
    rx, ry = pixel_rays(intr_work)
    ext_u = np.sqrt(np.maximum(1.0 + rx * rx - (n[0] - rx * n[2]) ** 2, 0.0))
    ext_v = np.sqrt(np.maximum(1.0 + ry * ry - (n[1] - ry * n[2]) ** 2, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(np.isfinite(z_work), _EQUAL_AREA_HALF_SIDE * radius_m * 0.5
                         * (intr_work.fx + intr_work.fy) / z_work, 0.0)
    limit = max(z_work.shape)

    def px(ext: np.ndarray) -> np.ndarray:   # at least 3 x 3 cells: a patch must span a plane
        return np.clip(np.rint(scale * ext), 1, limit).astype(np.int32)

    return px(ext_u), px(ext_v)


def patch_pca(depth_m: np.ndarray, intrinsics: Intrinsics, radius_m: float, work_px: int,
              min_points: int, up_camera: np.ndarray | None = None, *, valid: np.ndarray | None = None,
              filled: np.ndarray | None = None, noise_a_per_m: float = 0.0) -> PatchPCA:
    """PCA of the ``radius_m`` neighbourhood of every pixel, in image space (see module doc).

    ``up_camera`` (world up in the camera frame) shapes the windows as level discs; None
    takes them face-on. ``valid`` and ``filled`` (depth with holes at 0) may be passed when
    already known. ``noise_a_per_m``: the depth noise of one reduced cell, sigma_z = a z^2; its
    spread along the viewing ray (sigma^2 r r^T) is removed from each patch's covariance, so
    noise alone does not make level ground look curved.
    """
    intr = fit_intrinsics(intrinsics, depth_m.shape)
    big_h, big_w = depth_m.shape
    valid = valid_depth(depth_m) if valid is None else valid
    z0 = np.where(valid, depth_m, np.float32(0)) if filled is None else filled
    rx, ry = pixel_rays(intr)
    work_w = min(int(work_px), big_w)
    work_h = max(1, round(big_h * work_w / big_w))
    cells = (big_w / work_w) * (big_h / work_h)          # full-res pixels per reduced cell

    def area(img: np.ndarray) -> np.ndarray:
        return cv2.resize(img, (work_w, work_h), interpolation=cv2.INTER_AREA).astype(np.float64)

    frac = area(valid.view(np.uint8).astype(np.float32))  # valid fraction of each cell
    count = frac * cells
    has = count > 0.5
    inv_frac = np.divide(1.0, frac, out=np.zeros_like(frac), where=has)
    mean = np.empty((3, work_h, work_w), dtype=np.float64)  # mean point of each cell's valid pixels
    tmp = np.empty_like(z0)
    for ch, ray in enumerate((rx, ry)):
        np.multiply(z0, ray, out=tmp)
        np.multiply(area(tmp), inv_frac, out=mean[ch])
    np.multiply(area(z0), inv_frac, out=mean[2])
    weight = np.where(has, count, 0.0)
    centre = (mean * weight).sum(axis=(1, 2)) / max(weight.sum(), 1.0)
    c = mean - centre[:, None, None]                     # centred: E[xx]-E[x]^2 keeps its digits
    c *= has

    # moments w, w x_i, w x_i x_j (i <= j) as channels, and their integral images
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    chans = np.empty((work_h, work_w, 10), dtype=np.float64)
    chans[..., 0] = weight
    for i in range(3):
        np.multiply(c[i], weight, out=chans[..., 1 + i])
    for ch, (i, j) in enumerate(pairs, start=4):
        np.multiply(chans[..., 1 + i], c[j], out=chans[..., ch])
    integral = cv2.integral(chans, sdepth=cv2.CV_64F).reshape(-1, 10)   # one row of 10 per corner

    # per-cell window: the image footprint of a level radius_m disc at the cell's depth
    intr_work = intr.scaled(work_w, work_h)
    with np.errstate(invalid="ignore"):
        z_work = np.where(has, mean[2], np.nan).astype(np.float32)
    half_u, half_v = _footprint_half_px(z_work, intr_work, radius_m, up_camera)
    rows = np.arange(work_h, dtype=np.int32)[:, None]
    cols = np.arange(work_w, dtype=np.int32)[None, :]
    y0 = np.clip(rows - half_v, 0, work_h)
    y1 = np.clip(rows + half_v + 1, 0, work_h)
    x0 = np.clip(cols - half_u, 0, work_w)
    x1 = np.clip(cols + half_u + 1, 0, work_w)
    s = _window_sums(integral, work_w, y0, y1, x0, x1)

    n = s[..., 0]
    ok = has & (n >= min_points)
    e = s[..., 1:]
    e /= np.where(ok, n, 1.0)[..., None]                 # window means of x_i and x_i x_j
    cov = [e[..., 3 + k] - e[..., i] * e[..., j] for k, (i, j) in enumerate(pairs)]
    if noise_a_per_m > 0:                                # noise lies along the ray through the patch
        p = [e[..., i] + centre[i] for i in range(3)]
        with np.errstate(invalid="ignore", divide="ignore"):   # invalid patches stay NaN, dropped below
            inv_norm = 1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
            var = (noise_a_per_m * p[2] * p[2]) ** 2
            unit_ray = [c * inv_norm for c in p]
            for kk, (i, j) in enumerate(pairs):
                cov[kk] = cov[kk] - var * unit_ray[i] * unit_ray[j]
    eig = eigvalsh3(*cov)
    np.clip(eig, 0.0, None, out=eig)
    trace = eig.sum(axis=-1)
    ok &= trace > 0
    curv = np.divide(eig[..., 0], trace, out=np.full_like(trace, np.nan), where=ok)
    eig[~ok] = np.nan

    # upsample; invalid patches enter the interpolation as the worst curvature (1/3)
    worst = np.where(ok, curv, 1.0 / 3.0).astype(np.float32)
    up = cv2.resize(worst, (big_w, big_h), interpolation=cv2.INTER_LINEAR)
    ok_up = cv2.resize(ok.astype(np.uint8), (big_w, big_h), interpolation=cv2.INTER_NEAREST).astype(bool)
    ok_up &= valid
    np.copyto(up, np.float32(np.nan), where=~ok_up)
    curvature = up
    return PatchPCA(eigenvalues=eig, curvature_work=curv,
                    window_half_px=np.stack([np.where(ok, half_u, 0), np.where(ok, half_v, 0)], axis=-1),
                    curvature=curvature)
