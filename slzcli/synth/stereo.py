"""Stereo depth of a D4xx-like camera: an infrared pair rendered with the emitter's dots, SGBM, registration.

The left infrared imager is the depth reference; the right one sits ``baseline_m`` along its
+x (a rectified pair), the projector between them, the colour camera at the preset's offset.
Each imager sees the scene's reflectance (the mean of the material's linear albedo) lit by
the same sun, ambient and shadows as the colour render (``Renderer.surface``) plus the
projector's fixed pseudo-random dots (irradiance ~ power / range^2, occluded by the scene),
then shot noise, read noise and 8 bits. ``cv2.StereoSGBM`` with its left-right check
matches the pair; disparity d gives z = f B / d; the depth is forward-projected into the
colour camera (each infrared pixel covers the colour pixels its footprint reaches, nearest
surface wins, as librealsense's ``align`` does), so holes stay holes and occlusion shadows
appear where the two viewpoints differ. Growth of the error with z^2, holes on plain or dark
surfaces, flying pixels at edges and pixel-locking come out of the matching, not out of a
formula. Seeded and vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from slzcli.config import SensorCfg, StereoCfg, StereoPresetCfg
from slzcli.synth.render import Renderer, Surface
from slzcli.types import Intrinsics

_DISPARITY_STEP = 16          # multiple of 16 the SGBM search width must be (OpenCV); also its fixed-point scale
_GREY_LEVELS = 255            # cv2.StereoSGBM takes 8-bit images; the D4xx infrared stream is Y8 as well
_DOT_REACH_SIGMA = 4.0        # a dot's irradiance is cut beyond this many radii (exp(-8) ~ 3e-4)
_DOT_MIN_GREY = 0.05          # dots adding less than this (grey levels) at their peak are not rendered
_MAX_DOT_MARGIN = 0.45        # fraction of a cell kept free at each side, at most (dots wider than a cell are cut)
_SPLAT_MAX = 4                # colour pixels per axis one infrared pixel may cover (colour up to 3x finer)
_SGBM_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
               "hh": cv2.STEREO_SGBM_MODE_HH, "hh4": cv2.STEREO_SGBM_MODE_HH4}


@dataclass(frozen=True, eq=False)
class DotPattern:
    """The emitter's dots as unit directions in the projector's optical frame: a jittered grid.

    One dot per cell of an ``nx x ny`` grid over the field of projection (in tangent-plane
    coordinates), at a fixed pseudo-random place inside its cell, kept ``_DOT_REACH_SIGMA``
    radii from the cell's border: random-looking, evenly spread, and a point of the field is
    lit by the dot of its own cell only (one lookup per pixel).
    """

    dirs: np.ndarray          # (ny, nx, 3) unit vectors
    origin: np.ndarray        # (2,) tangent coordinates of the grid corner
    cell: np.ndarray          # (2,) cell size in tangent coordinates
    power_w: float            # optical power of one dot
    sigma_rad: float          # Gaussian radius of one dot


@dataclass(frozen=True, eq=False)
class StereoRig:
    """A D4xx-like camera fixed to the colour camera: infrared pair, projector, matcher settings."""

    ir: Intrinsics
    baseline_m: float
    T_color_left: np.ndarray      # 4x4: the left infrared imager in the colour optical frame
    T_left_projector: np.ndarray  # 4x4: the projector in the left infrared frame
    dots: DotPattern
    num_disparities: int
    camera: StereoPresetCfg
    cfg: StereoCfg

    @property
    def focal_baseline_px_m(self) -> float:
        """f B in px m: disparity (px) = f B / z."""
        return self.ir.fx * self.baseline_m


def _rows_times(v: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``v @ M`` for (N, 3) rows and a 3x3 matrix, without BLAS (whose threads fight Open3D's: 50x slower here)."""
    return v[:, 0:1] * M[0] + v[:, 1:2] * M[1] + v[:, 2:3] * M[2]


def ir_intrinsics(camera: StereoPresetCfg, width: int, height: int) -> Intrinsics:
    """Pinhole of an infrared stream mode: the imager's focal length in pixels, scaled to the mode's width."""
    f = camera.focal_length_mm * 1e3 / camera.pixel_um * width / camera.sensor_width_px
    return Intrinsics(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)


def make_dot_pattern(camera: StereoPresetCfg, seed: int) -> DotPattern:
    """``camera.projector_dots`` dots over the field of projection, fixed by ``seed``."""
    tx = np.tan(np.radians(camera.projector_hfov_deg) / 2.0)
    ty = np.tan(np.radians(camera.projector_vfov_deg) / 2.0)
    nx = max(1, round(float(np.sqrt(camera.projector_dots * tx / ty))))
    ny = max(1, round(camera.projector_dots / nx))
    cell = np.array([2 * tx / nx, 2 * ty / ny])
    origin = np.array([-tx, -ty])
    sigma = camera.dot_sigma_mrad * 1e-3
    margin = np.minimum(_DOT_REACH_SIGMA * sigma / cell, _MAX_DOT_MARGIN)   # cells near the axis: tan ~ angle
    jitter = margin + np.random.default_rng(seed).random((ny, nx, 2)) * (1.0 - 2.0 * margin)
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    t = origin + (np.stack([jj, ii], -1) + jitter) * cell
    d = np.concatenate([t, np.ones((ny, nx, 1))], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return DotPattern(dirs=d, origin=origin, cell=cell, power_w=camera.projector_power_w / (nx * ny),
                      sigma_rad=sigma)


def make_rig(cfg: SensorCfg) -> StereoRig:
    """The stereo rig of ``cfg.preset`` at the configured infrared stream mode."""
    cam, st = cfg.camera, cfg.stereo
    ir = ir_intrinsics(cam, st.ir_width_px, st.ir_height_px)
    T_color_left = np.eye(4)
    T_color_left[:3, 3] = -np.asarray(cam.color_offset_m, dtype=np.float64)
    T_left_proj = np.eye(4)
    T_left_proj[:3, 3] = cam.projector_offset_m
    d_max = ir.fx * cam.baseline_m / cam.min_z_m
    num = int(np.ceil(d_max / _DISPARITY_STEP)) * _DISPARITY_STEP
    return StereoRig(ir=ir, baseline_m=cam.baseline_m, T_color_left=T_color_left, T_left_projector=T_left_proj,
                     dots=make_dot_pattern(cam, st.pattern_seed), num_disparities=num, camera=cam, cfg=st)


def dot_irradiance(points_world: np.ndarray, normals_world: np.ndarray, hit: np.ndarray,
                   T_world_projector: np.ndarray, pattern: DotPattern, renderer: Renderer,
                   reach_m: float = np.inf) -> np.ndarray:
    """Irradiance (W/m^2) of the emitter's dots on each surface point; zero where the scene hides the projector
    and beyond ``reach_m`` from it (where the caller has found them too faint to matter)."""
    out = np.zeros(len(points_world))
    R, c = T_world_projector[:3, :3], T_world_projector[:3, 3]
    v = points_world - c
    with np.errstate(invalid="ignore"):
        idx = np.flatnonzero(hit & (np.einsum("nj,nj->n", v, v) < reach_m * reach_m))
    if len(idx) == 0:
        return out
    p = _rows_times(v[idx], R)                            # projector frame (R^T v per row)
    ahead = p[:, 2] > 0
    idx, p = idx[ahead], p[ahead]
    ny, nx = pattern.dirs.shape[:2]
    cell = np.floor((p[:, :2] / p[:, 2:3] - pattern.origin) / pattern.cell).astype(np.int64)
    inside = (cell[:, 0] >= 0) & (cell[:, 0] < nx) & (cell[:, 1] >= 0) & (cell[:, 1] < ny)
    idx, p, cell = idx[inside], p[inside], cell[inside]
    r = np.sqrt(np.einsum("nj,nj->n", p, p))
    u = p / r[:, None]
    d = pattern.dirs[cell[:, 1], cell[:, 0]]
    ang2 = np.einsum("nj,nj->n", u - d, u - d)            # chord^2 ~ angle^2 for small angles
    near = ang2 < (_DOT_REACH_SIGMA * pattern.sigma_rad) ** 2
    idx, r, ang2 = idx[near], r[near], ang2[near]
    if len(idx) == 0:
        return out
    # radiant intensity of a Gaussian spot: P / (2 pi sigma^2) per steradian at its centre; / r^2; x cos(incidence)
    e = np.exp(-0.5 * ang2 / pattern.sigma_rad ** 2) * pattern.power_w / (2 * np.pi * pattern.sigma_rad ** 2) / (r * r)
    to_proj = c - points_world[idx]
    e *= np.clip(np.einsum("nj,nj->n", normals_world[idx], to_proj) / r, 0.0, 1.0)
    o = points_world[idx] + normals_world[idx] * renderer.light.shadow_bias_m
    rays = np.concatenate([o, c - o], axis=1).astype(np.float32)     # t in [0, 1] reaches the projector
    hidden = renderer.rc.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=1.0).numpy().astype(bool)
    e[hidden] = 0.0
    out[idx] = e
    return out


def ir_signal_e(surface: Surface, dots_w_m2: np.ndarray, gain: float, rig: StereoRig) -> np.ndarray:
    """Mean electrons per pixel: reflectance x (sun and ambient x the scene's light level + dots).

    The exposure is fixed: a white Lambertian surface in full sun fills ``exposure_fill`` of the
    full well. Reflectance is the mean of the linear albedo (the imagers see visible and near
    infrared light; the near-infrared brightness of vegetation is not modelled).
    """
    cam, st = rig.camera, rig.cfg
    rho = surface.albedo.mean(axis=1)
    lit = gain * surface.light + dots_w_m2 / st.sun_irradiance_w_m2
    return st.exposure_fill * cam.full_well_e * rho * lit


def ir_image(signal_e: np.ndarray, shape: tuple[int, int], camera: StereoPresetCfg,
             rng: np.random.Generator) -> np.ndarray:
    """8-bit infrared image: shot noise (Poisson, as a Gaussian of variance = signal), read noise, quantisation."""
    s = np.maximum(signal_e, 0.0)
    e = s + np.sqrt(s) * rng.standard_normal(s.shape) + camera.read_noise_e * rng.standard_normal(s.shape)
    dn = np.rint(np.clip(e / camera.full_well_e, 0.0, 1.0) * _GREY_LEVELS)
    return dn.reshape(shape).astype(np.uint8)


def match(left: np.ndarray, right: np.ndarray, rig: StereoRig) -> np.ndarray:
    """Disparity (px, float32) of the left image; NaN where SGBM, its uniqueness or left-right check gave none.

    Both images are padded on the left by the search width, so columns near the left edge are
    searched too (their matches may fall outside the right image: the invalid band of a D4xx).
    With ``subpixel: refine`` SGBM's disparity is refined by a gradient step over the block.
    """
    s = rig.cfg.sgbm
    n = rig.num_disparities
    area = s.block_px * s.block_px
    sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=n, blockSize=s.block_px,
                                 P1=round(s.p1_per_px2 * area), P2=round(s.p2_per_px2 * area),
                                 disp12MaxDiff=s.lr_max_diff_px, preFilterCap=s.prefilter_cap,
                                 uniquenessRatio=s.uniqueness_pct, speckleWindowSize=s.speckle_window_px,
                                 speckleRange=s.speckle_range_px, mode=_SGBM_MODES[s.mode])
    pl = cv2.copyMakeBorder(left, 0, 0, n, 0, cv2.BORDER_CONSTANT, value=0)
    pr = cv2.copyMakeBorder(right, 0, 0, n, 0, cv2.BORDER_CONSTANT, value=0)
    raw = sgbm.compute(pl, pr)[:, n:]
    disp = raw.astype(np.float32) / _DISPARITY_STEP
    disp[raw <= 0] = np.nan                  # invalid (minDisparity - 1) or zero (infinitely far)
    if rig.cfg.subpixel == "refine":
        disp = refine_subpixel(left, right, disp, rig.cfg.refine_block_px, rig.cfg.refine_iterations)
    return disp


def refine_subpixel(left: np.ndarray, right: np.ndarray, disp: np.ndarray, block_px: int,
                    iterations: int) -> np.ndarray:
    """Gradient (Lucas-Kanade) refinement of a disparity map over ``block_px`` square windows.

    SGBM's parabola through three aggregated costs locks to whole pixels (its costs are V-shaped
    near the minimum); a least-squares step on the images themselves does not, and its error
    follows image noise and texture: sigma_d ~ noise / sqrt(sum of squared x-gradients).
    Steps larger than a pixel (SGBM picked the wrong match) make the pixel invalid.
    """
    L = left.astype(np.float32)
    R = right.astype(np.float32)
    H, W = L.shape
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    d0 = np.nan_to_num(disp, nan=0.0).astype(np.float32)
    d = d0.copy()
    win = (block_px, block_px)
    for _ in range(iterations):
        map_x = xs - d
        Rw = cv2.remap(R, map_x, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # ksize=1 Sobel is [-1, 0, 1], twice the derivative; the mean of both images' derivatives
        gx = 0.25 * (cv2.Sobel(Rw, cv2.CV_32F, 1, 0, ksize=1) + cv2.Sobel(L, cv2.CV_32F, 1, 0, ksize=1))
        res = L - Rw
        num = cv2.boxFilter(gx * res, -1, win, normalize=False)
        den = cv2.boxFilter(gx * gx, -1, win, normalize=False)
        step = np.where(den > 0, num / np.maximum(den, 1e-12), 0.0)
        d = d - step.astype(np.float32)      # L(x) = R(x - d - e) ~ Rw(x) - e Rw'(x): e = -sum(g r) / sum(g g)
    out = d.astype(np.float32)
    out[~np.isfinite(disp) | (np.abs(out - d0) > 1.0) | (out <= 0)] = np.nan
    return out


def register_to_color(depth_ir: np.ndarray, ir: Intrinsics, color: Intrinsics,
                      T_color_ir: np.ndarray) -> np.ndarray:
    """Depth of the infrared reference camera seen from the colour camera; NaN where nothing lands.

    Each valid infrared pixel is a small square on its surface; its corners are projected into
    the colour image and it fills the colour pixel centres inside (z-buffered: the nearest
    surface wins), like librealsense's align. Pixels nothing lands on stay holes.
    """
    v, u = np.nonzero(np.isfinite(depth_ir))
    z = depth_ir[v, u].astype(np.float64)
    out = np.full((color.height, color.width), np.inf)
    if len(z):
        R, t = T_color_ir[:3, :3], T_color_ir[:3, 3]
        corners = []
        for du in (-0.5, 0.5):
            uu = (u + du - ir.cx) / ir.fx
            vv = (v + du - ir.cy) / ir.fy
            p = _rows_times(np.stack([uu * z, vv * z, z], axis=1), R.T) + t
            corners.append((color.fx * p[:, 0] / p[:, 2] + color.cx, color.fy * p[:, 1] / p[:, 2] + color.cy,
                            p[:, 2]))
        (u0, v0, z0), (u1, v1, z1) = corners
        zc = 0.5 * (z0 + z1)
        k0, l0 = np.ceil(np.minimum(u0, u1)), np.ceil(np.minimum(v0, v1))
        hi_u, hi_v = np.maximum(u0, u1), np.maximum(v0, v1)
        n = int(min(_SPLAT_MAX, np.floor(max((hi_u - k0).max(), (hi_v - l0).max())) + 1))
        for a in range(n):
            for b in range(n):
                cu, cv_ = k0 + a, l0 + b
                ok = (cu <= hi_u) & (cv_ <= hi_v) & (cu >= 0) & (cu < color.width) & (cv_ >= 0) & (cv_ < color.height)
                if ok.any():
                    flat = cv_[ok].astype(np.int64) * color.width + cu[ok].astype(np.int64)
                    np.minimum.at(out.reshape(-1), flat, zc[ok])
    out[~np.isfinite(out)] = np.nan
    return out.astype(np.float32)


class StereoDepth:
    """The ``stereo`` sensor model: renders the infrared pair for a colour pose and returns registered depth."""

    def __init__(self, cfg: SensorCfg, renderer: Renderer, color: Intrinsics) -> None:
        self.cfg = cfg
        self.renderer = renderer
        self.color = color
        self.rig = make_rig(cfg)

    def infrared(self, T_world_color: np.ndarray, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The left and right 8-bit infrared images of a colour camera pose.

        Each pixel integrates ``supersample_x`` rays spread over its width along the baseline
        (a point sample per pixel aliases fine texture differently in the two views, which
        SGBM reads as disparity noise). Rows need no supersampling: a row of each imager lies
        in the same epipolar plane, so both sample the surface along the same curve.
        """
        rig = self.rig
        T_left = T_world_color @ rig.T_color_left
        shift = np.eye(4)
        shift[0, 3] = rig.baseline_m
        T_right = T_left @ shift
        T_proj = T_left @ rig.T_left_projector
        gain = self.renderer.scene.illumination.gain
        k = rig.cfg.supersample_x
        ir = rig.ir
        fine = Intrinsics(ir.fx * k, ir.fy, (ir.cx + 0.5) * k - 0.5, ir.cy, ir.width * k, ir.height)
        images = []
        reach = self.dot_reach_m()
        for T in (T_left, T_right):
            s = self.renderer.surface(T, fine)
            dots = dot_irradiance(s.point_world, s.normal_world, s.hit, T_proj, rig.dots, self.renderer, reach)
            signal = ir_signal_e(s, dots, gain, rig).reshape(ir.height, ir.width, k).mean(axis=2)
            images.append(ir_image(signal.ravel(), (ir.height, ir.width), rig.camera, rng))
        return images[0], images[1]

    def dot_reach_m(self) -> float:
        """Range beyond which the brightest dot, on a white surface, adds less than ``_DOT_MIN_GREY`` grey levels.

        Outdoors the dots are far fainter than sunlight (a fifth of a grey level at 4 m in full
        sun), so most frames need no dot lookup at all; 0 when the emitter is off.
        """
        rig = self.rig
        if not rig.cfg.emitter:
            return 0.0
        peak_w_sr = rig.dots.power_w / (2 * np.pi * rig.dots.sigma_rad ** 2)      # W/sr at a dot's centre
        grey_at_1m = rig.cfg.exposure_fill * _GREY_LEVELS * peak_w_sr / rig.cfg.sun_irradiance_w_m2
        return float(np.sqrt(grey_at_1m / _DOT_MIN_GREY))

    def depth_ir(self, T_world_color: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Depth (m, float32, NaN = none) in the left infrared imager's own pixels."""
        left, right = self.infrared(T_world_color, rng)
        disp = match(left, right, self.rig)
        return (self.rig.focal_baseline_px_m / disp).astype(np.float32)

    def measure(self, exact_depth_m: np.ndarray, T_world_color: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Depth registered to the colour camera, range limits applied (``exact_depth_m`` is not used)."""
        depth = register_to_color(self.depth_ir(T_world_color, rng), self.rig.ir, self.color, self.rig.T_color_left)
        with np.errstate(invalid="ignore"):
            depth[(depth < self.cfg.min_range_m) | (depth > self.cfg.max_range_m)] = np.nan
        return depth
