"""The four terrain maps of METHOD.md 2.3: depth variance, flatness, inclination, steepness.

Every map is float32 in [0, 1] with 1 = good for landing, and 0 where the pixel has no depth
or too little valid neighbourhood to say (unknown is unsafe). Each map has two modes:
``absolute`` maps a physical quantity through a fixed documented range, so 1 means the same
thing in every frame; ``frame`` reproduces the paper's per-frame min-max (Eq. 5).

Noise. Every map runs on b x b block means of the depth (inverse depth averaged, so planes stay
planes), with windows in blocks, and is then upsampled: b, the slope window and Canny's depth
scaling come from the frame's measured depth noise and the UAV's limits (``limits.py``); with
little noise b = 1 and the maps are the paper's at full resolution. The noise is removed where
it adds to a statistic (the depth variance's residual variance, the patch covariance's spread
along the viewing ray), never by a constant fitted to a simulator.

Absolute ranges (all from config):
  depth variance  exp(-s / s0_m), s = residual depth std about the window's plane, noise removed
  flatness        min(d / clearance_m, 1), d = ground distance (m) to the nearest depth edge or hole
  inclination     exp(-C / curvature_ref), C = l0 / (l0 + l1 + l2) of the radius_m patch
  steepness       exp(-(psi / uav.max_slope_deg)^2), psi = surface slope against gravity
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.config import (
    Config,
    DepthVarianceCfg,
    FlatnessCfg,
    InclinationCfg,
    Mount,
    SteepnessCfg,
    TerrainCfg,
    UavCfg,
    load_config,
)
from slzcli.errors import DatasetError, FrameError
from slzcli.terrain.geometry import (
    NormalField,
    block_depth,
    fit_intrinsics,
    median_depth_m,
    normal_field,
    patch_pca,
    plane_residual_var,
    valid_depth,
    window_px,
)
from slzcli.terrain.limits import working_scale
from slzcli.terrain.noise import MAD_TO_SIGMA, NoiseTracker
from slzcli.types import BlockGrid, DepthNoise, Frame, Intrinsics, TerrainMaps, Working

# The flanks of a step's derivative (blur + Sobel spread it over ~2 px each side) are left out of
# the local trend with the step itself.
_SHOULDERS = np.ones((5, 5), np.uint8)
# cv2.distanceTransform mask sizes by the config value (3 or 5 px).
_DIST_MASKS = {3: cv2.DIST_MASK_3, 5: cv2.DIST_MASK_5}
# _within_spread: pixels of the sub-lattice its median is taken on (the whole frame below 4x this)
_SPREAD_SAMPLES = 65536


# ----------------------------------------------------------------------------- helpers
def normalise_frame(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Eq. 5: min-max over the valid pixels; invalid pixels 0. A constant map becomes all 1."""
    out = np.zeros(values.shape, dtype=np.float32)
    if not valid.any():
        return out
    v = values[valid]
    lo, hi = float(v.min()), float(v.max())
    if hi > lo:
        out[valid] = (v - lo) / (hi - lo)
    else:
        out[valid] = 1.0
    return out


def _finish(values: np.ndarray, ok: np.ndarray, normalise: str) -> np.ndarray:
    """float32 in [0, 1], 0 where not ok; frame mode min-maxes over the ok pixels. May reuse ``values``."""
    if normalise == "frame":
        return normalise_frame(values, ok)
    out = values if values.dtype == np.float32 else values.astype(np.float32)
    np.copyto(out, np.float32(0), where=~ok)
    return np.clip(out, 0.0, 1.0, out=out)


@dataclass(frozen=True, eq=False)
class _Depth:
    """A checked depth image prepared once for all maps: valid mask and holes filled with 0."""

    depth: np.ndarray
    valid: np.ndarray
    filled: np.ndarray


def _prepare(depth_m: np.ndarray, what: str = "depth image") -> _Depth:
    depth = np.asarray(depth_m)
    if depth.ndim != 2 or depth.size == 0:
        raise DatasetError(what, f"expected a 2-D depth image, got shape {depth.shape}")
    if depth.dtype != np.float32:
        depth = depth.astype(np.float32)
    valid = valid_depth(depth)
    return _Depth(depth, valid, np.where(valid, depth, np.float32(0)))


# ----------------------------------------------------------------------------- maps
def depth_variance_map(depth_m: np.ndarray, cfg: DepthVarianceCfg, noise_a_per_m: float = 0.0) -> np.ndarray:
    """Alg. 1 on a full-resolution depth image: see ``_depth_variance``; ``noise_a_per_m`` is a in
    sigma_z = a z^2 of that image's pixels (0: no noise removed)."""
    return _depth_variance(_prepare(depth_m), cfg, noise_a_per_m)


def _roughness_m(d: _Depth, cfg: DepthVarianceCfg, noise_a_per_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(s, ok): the residual depth std (m) about the plane of each kernel_px window, noise removed.

    Alg. 1 takes the plain local std; at the working scale a window spans up to a footprint,
    where a safe 15-degree ramp alone would read as several cm of "variation", so the plane
    (the steepness map's business) is removed first. The fit is in inverse depth, where noise
    sigma_w = a is the same at every range and a plane is exact; its expected share of the
    residual variance, a^2 (n - 3) / n, is subtracted, then s = z^2 sigma_w in metres.
    """
    if cfg.statistic == "std":
        return _local_std_m(d, cfg)
    inv = np.zeros(d.depth.shape, np.float32)
    np.divide(np.float32(1.0), d.depth, out=inv, where=d.valid)
    var, ok = plane_residual_var(inv, d.valid, cfg.kernel_px, cfg.min_valid_fraction)
    if noise_a_per_m > 0:
        n = cfg.kernel_px * cfg.kernel_px
        var -= np.float32(noise_a_per_m * noise_a_per_m * (n - 3) / n)
        np.maximum(var, 0.0, out=var)
    s = np.sqrt(var, out=var)
    z2 = np.multiply(d.filled, d.filled)
    s *= z2
    return s, ok


def _local_std_m(d: _Depth, cfg: DepthVarianceCfg) -> tuple[np.ndarray, np.ndarray]:
    """(s, ok): Alg. 1 lines 1-4 as printed, s = sqrt|blur(D^2) - blur(D)^2| over kernel_px (the paper's
    statistic, ``statistic: std``): no plane removed, no noise removed. Means over the window's valid
    pixels only, and a window with less than min_valid_fraction of them is not ok (no bleeding of holes)."""
    side = (cfg.kernel_px, cfg.kernel_px)
    box = lambda a: cv2.boxFilter(a, -1, side, normalize=False, borderType=cv2.BORDER_REPLICATE)  # noqa: E731
    filled = d.filled.astype(np.float64)        # E[D^2] - E[D]^2 cancels: float32 leaves mm of false std at 10 m
    count = box(d.valid.astype(np.float64))
    ok = d.valid & (count >= cfg.min_valid_fraction * cfg.kernel_px * cfg.kernel_px)
    n = np.maximum(count, 1.0)
    mu1 = box(filled) / n
    s = np.sqrt(np.abs(box(filled * filled) / n - mu1 * mu1)).astype(np.float32)
    s[~ok] = 0.0
    return s, ok


def _depth_variance(d: _Depth, cfg: DepthVarianceCfg, noise_a_per_m: float = 0.0) -> np.ndarray:
    s, ok = _roughness_m(d, cfg, noise_a_per_m)
    return _roughness_map(s, ok, cfg)


def _roughness_map(s: np.ndarray, ok: np.ndarray, cfg: DepthVarianceCfg) -> np.ndarray:
    x = np.multiply(s, np.float32(-1.0 / cfg.s0_m), dtype=np.float32)
    return _finish(np.exp(x, out=x), ok, cfg.normalise)


def depth_edges(depth_m: np.ndarray, cfg: FlatnessCfg, metres_per_level: float) -> np.ndarray:
    """Alg. 2 edges: Canny(canny_low, canny_high) of depth at metres_per_level, plus every hole.

    Canny is fed the Sobel derivatives of ``depth / metres_per_level`` directly: the same
    operator and thresholds as Canny on the fixed-scale 8-bit image, without its 256-level
    range (which would clip everything beyond 2.55 m of relief at 1 cm per level).
    """
    return _clear_of_edges(_prepare(depth_m), cfg, metres_per_level) == 0


def _clear_of_edges(d: _Depth, cfg: FlatnessCfg, metres_per_level: float, hole_px: float = 0.0,
                    noise_k: float = 0.0) -> np.ndarray:
    """uint8: 1 where a pixel is neither a depth edge nor a hole (the distance-transform input).

    ``metres_per_level``: the depth scaling (``Working.metres_per_level``: a step the UAV cannot
    tolerate is a strong edge, unless the noise needs a coarser scaling).
    ``noise_k`` > 0: the scaling is also coarsened until the derivatives Canny sees stay below its
    low threshold at ``noise_k`` times their own robust spread (MAD over the frame). The noise model
    behind ``metres_per_level`` is white; a stereo sensor's error is correlated over several pixels
    and its sub-pixel steps line up into terraces, and neither is white after the blur (synth D455
    at 5 m: 17 % of the pixels were Canny edges on open ground at the modelled scaling).
    ``hole_px``: holes narrower than this (``flatness.hole_min_m`` on the ground) do not count as
    edges: a real stereo sensor drops isolated pixels everywhere, and a speck of no data cannot
    hide what a landing cares about. Their pixels still have no depth (they score 0).
    """
    # Detrended (detrend_px > 0): Canny sees inverse depth in metres at the median depth,
    # z_ref^2 / z, less each derivative's local trend: its mean over detrend_px, taken without
    # the pixels that already stand out (so a step's own response does not leak into its
    # neighbours' trend and ring). A plane is linear in inverse depth, so its derivatives are
    # constant and vanish however oblique the view; a step h stays a step of ~h. Without it a
    # tilted floor's gradient reads as edges once the scaling is fine enough to see a step the UAV
    # cannot tolerate.
    if cfg.detrend_px > 0:
        z_ref = median_depth_m(d.depth) or 1.0
        source = np.zeros(d.depth.shape, np.float32)
        np.divide(np.float32(z_ref * z_ref), d.depth, out=source, where=d.valid)
    else:
        source = d.filled
    # Normalised blur: holes do not pull their neighbours' depth to 0, and a hole is filled with
    # its neighbourhood's depth so the derivatives see no dip there (a real sensor's scattered
    # dropouts would otherwise ring every one with Canny edges); a wide hole is an edge below.
    ksize = (max(cfg.blur_px, 3), max(cfg.blur_px, 3))
    num = cv2.GaussianBlur(source, ksize, 0)
    den = cv2.GaussianBlur(d.valid.astype(np.float32), ksize, 0)
    filled = den > 1e-6
    smooth = np.divide(num, den, out=np.zeros_like(num), where=filled)
    img = smooth if cfg.blur_px > 1 else np.where(d.valid, source, smooth)
    # no derivative across the inside of a wide hole (it has no depth to differ from)
    blind = cv2.erode(filled.view(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE) == 0
    scale = float(1.0 / metres_per_level)
    derivs = []
    for dx, dy in ((1, 0), (0, 1)):
        g = cv2.Sobel(img, cv2.CV_32F, dx, dy, ksize=3, scale=scale, borderType=cv2.BORDER_REPLICATE)
        g[blind] = 0.0
        if cfg.detrend_px > 0:
            side = (cfg.detrend_px, cfg.detrend_px)
            first = g - cv2.blur(g, side, borderType=cv2.BORDER_REPLICATE)
            calm = (~blind & (np.abs(first) < np.float32(cfg.canny_low))).view(np.uint8)
            # eroded: a step's flanks too
            calm = cv2.erode(calm, _SHOULDERS, borderType=cv2.BORDER_REPLICATE).astype(np.float32)
            num = cv2.boxFilter(g * calm, -1, side, normalize=False, borderType=cv2.BORDER_REPLICATE)
            den = cv2.boxFilter(calm, -1, side, normalize=False, borderType=cv2.BORDER_REPLICATE)
            g -= np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        derivs.append(g)
    if noise_k > 0:
        derivs = _within_spread(derivs, ~blind & d.valid, noise_k, cfg.canny_low)
    # Canny takes 16-bit derivatives: round and saturate (a saturated gradient is an edge anyway)
    derivs = [cv2.add(g, 0.0, dtype=cv2.CV_16S) for g in derivs]  # type: ignore[call-overload]  # stubs lack a scalar src2
    edges = cv2.Canny(derivs[0], derivs[1], cfg.canny_low, cfg.canny_high)   # 255 on edges
    clear = cv2.compare(edges, 0, cv2.CMP_EQ)  # type: ignore[call-overload]  # 255 off edges; stubs lack a scalar src2
    known: np.ndarray = d.valid.view(np.uint8)
    hole_side = math.ceil(hole_px)
    if hole_side >= 2:                               # an opening of the hole mask keeps the wide holes
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (hole_side, hole_side))
        known = 1 - cv2.morphologyEx(1 - known, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_CONSTANT,
                                     borderValue=0)
    return cv2.bitwise_and(clear, known)                                      # holes are edges


def _within_spread(derivs: list[np.ndarray], seen: np.ndarray, k: float, low: float) -> list[np.ndarray]:
    """The derivatives scaled down so that k times their robust spread (MAD over ``seen``) is at most
    Canny's low threshold; unchanged when it already is.

    The median is only taken when at least half the values exceed the level it would have to pass
    (fewer than half above it put the median at or below it): a count is ~10x cheaper than the
    median of 600,000 values, and white or exact depth, the common case, never needs it.
    """
    level = np.float32(low / (k * MAD_TO_SIGMA) * (1.0 - 1e-6))   # just below: the median decides the edge
    n = 2 * int(np.count_nonzero(seen))
    above = sum(int(np.count_nonzero((np.abs(g) > level) & seen)) for g in derivs)
    if n == 0 or 2 * above < n:
        return derivs
    # a large frame's spread from a regular sub-lattice of at least _SPREAD_SAMPLES pixels: the MAD's own
    # sampling error there is ~0.5 %, and the median of 600,000 values was a third of a 640x480 frame's maps
    stride = max(1, math.isqrt(n // (2 * _SPREAD_SAMPLES)))
    sub = seen[::stride, ::stride]
    values = np.concatenate([g[::stride, ::stride][sub] for g in derivs])
    spread = MAD_TO_SIGMA * float(np.median(np.abs(values, out=values), overwrite_input=True))
    if k * spread <= low:
        return derivs
    gain = np.float32(low / (k * spread))
    return [g * gain for g in derivs]


def flatness_map(depth_m: np.ndarray, intrinsics: Intrinsics, cfg: FlatnessCfg, metres_per_level: float) -> np.ndarray:
    """Alg. 2 / Eq. 6: distance to the nearest depth edge or hole.

    absolute: pixel distance x depth / f = metres on the ground, map = min(d / clearance_m, 1);
    frame: the pixel distance min-maxed over the frame (the paper).
    """
    d = _prepare(depth_m)
    dist_px = _edge_distance_px(d, cfg, metres_per_level)
    return _flatness(dist_px, _ground_m(dist_px, d, fit_intrinsics(intrinsics, d.depth.shape)), d.valid, cfg)


def _flatness(dist_px: np.ndarray, edge_m: np.ndarray, valid: np.ndarray, cfg: FlatnessCfg) -> np.ndarray:
    if cfg.normalise == "frame":
        return normalise_frame(dist_px, valid)
    return _finish(edge_m / np.float32(cfg.clearance_m), valid, "absolute")


def _edge_distance_px(d: _Depth, cfg: FlatnessCfg, metres_per_level: float, hole_px: float = 0.0,
                      noise_k: float = 0.0) -> np.ndarray:
    """Pixel distance of every pixel to the nearest depth edge or wide hole (float32)."""
    clear = _clear_of_edges(d, cfg, metres_per_level, hole_px, noise_k)
    if cv2.countNonZero(clear) == clear.size:   # no edge and no hole anywhere: all as far as can be
        return np.full(clear.shape, np.float32(max(clear.shape)), dtype=np.float32)
    return cv2.distanceTransform(clear, cv2.DIST_L2, _DIST_MASKS[cfg.distance_mask])


def _ground_m(dist_px: np.ndarray, d: _Depth, intr: Intrinsics) -> np.ndarray:
    """Pixels -> metres on the ground at each pixel's depth (px x depth / f); 0 where no depth."""
    metres = dist_px * d.filled * np.float32(2.0 / (intr.fx + intr.fy))
    metres[~d.valid] = 0.0
    return metres


def edge_distance_m(depth_m: np.ndarray, intrinsics: Intrinsics, cfg: FlatnessCfg,
                    metres_per_level: float) -> np.ndarray:
    """Metres from each pixel to the nearest depth edge or hole: the clearance of the acceptance test."""
    d = _prepare(depth_m)
    return _ground_m(_edge_distance_px(d, cfg, metres_per_level), d, fit_intrinsics(intrinsics, d.depth.shape))


def inclination_map(curvature: np.ndarray, cfg: InclinationCfg) -> np.ndarray:
    """Alg. 3 / Eq. 7 on the patch curvature C: exp(-C / curvature_ref), or exp(-C / C_max) min-maxed."""
    ok = np.isfinite(curvature)
    if cfg.normalise == "frame":
        c_max = float(np.max(curvature, where=ok, initial=0.0))
        scale = -1.0 / c_max if c_max > 0 else 0.0
    else:
        scale = -1.0 / cfg.curvature_ref
    x = np.multiply(curvature, np.float32(scale), dtype=np.float32)
    np.exp(x, out=x)
    return _finish(x, ok, cfg.normalise)


def slope_rad(normals: NormalField, up_camera: np.ndarray) -> np.ndarray:
    """Eq. 8: psi = arccos(e3 . n), n oriented up; NaN where there is no normal. Radians, [0, pi/2]."""
    ux, uy, uz = (float(c) for c in np.asarray(up_camera, dtype=np.float64))
    dot = cv2.addWeighted(normals.nx, ux, normals.ny, uy, 0.0)
    dot = cv2.scaleAdd(normals.nz, uz, dot)
    norm = normals.norm()
    cos = cv2.divide(np.abs(dot, out=dot), norm)      # orienting n up = taking |e3 . n|
    np.minimum(cos, np.float32(1.0), out=cos)
    np.arccos(cos, out=cos)
    np.copyto(cos, np.float32(np.nan), where=~normals.ok | (norm == 0))
    return cos


def steepness_map(psi_rad: np.ndarray, cfg: SteepnessCfg, slope_limit_deg: float) -> np.ndarray:
    """Alg. 4 / Eq. 9: exp(-(psi / slope_limit)^2), or exp(-psi^2) min-maxed (METHOD's fix of line 7).

    ``slope_limit_deg`` is psi_ref, the UAV's own limit ``uav.max_slope_deg`` (one key for the map,
    the working-scale limits and the site acceptance test).
    """
    ok = np.isfinite(psi_rad)
    scale = 1.0 if cfg.normalise == "frame" else 1.0 / math.radians(slope_limit_deg)
    x = np.multiply(psi_rad, np.float32(scale), dtype=np.float32)
    np.multiply(x, x, out=x)
    np.negative(x, out=x)
    np.exp(x, out=x)
    return _finish(x, ok, cfg.normalise)


def _slope(d: _Depth, intr: Intrinsics, up: np.ndarray, win: int, cfg: SteepnessCfg) -> np.ndarray:
    """Slope psi (radians) of every pixel from the plane fit over a ``win`` x ``win`` window.

    A window ``step`` times ``normal_px`` wide runs as a ``normal_px``-ish window on the depth
    averaged over step x step blocks (valid pixels only), and the slope is upsampled: the same
    ground size and the same noise averaging for ~step^2 less work. Pixels without depth stay NaN.
    """
    step = max(1, win // cfg.normal_px)
    if step == 1:
        return slope_rad(normal_field(d.depth, intr, win, cfg.min_valid_fraction, valid=d.valid), up)
    h, w = d.depth.shape
    size = (max(1, w // step), max(1, h // step))
    num = cv2.resize(d.filled, size, interpolation=cv2.INTER_AREA)
    den = cv2.resize(d.valid.view(np.uint8).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    small_valid = den >= 0.5                               # at least half of the block has depth
    small = np.divide(num, den, out=np.full_like(num, np.nan), where=small_valid)
    small_win = max(3, 2 * ((win // step) // 2) + 1)
    normals = normal_field(small, fit_intrinsics(intr, small.shape), small_win, cfg.min_valid_fraction,
                           valid=small_valid)
    psi = cv2.resize(slope_rad(normals, up), (w, h), interpolation=cv2.INTER_LINEAR)
    psi[~d.valid] = np.nan
    return psi


def normal_window_px(depth_m: np.ndarray, intr: Intrinsics, cfg: SteepnessCfg) -> int:
    """The plane-fit window: ``normal_size_m`` on the ground at the frame's median depth, at least ``normal_px``.

    A fixed pixel window turns sensor noise into slope noise that grows with range (a 5 px
    window at 10 m spans 11 cm, where RealSense-like noise is ~5 cm: tens of degrees of
    false slope). A metric window keeps the slope estimate's noise roughly constant with
    altitude; one window per frame, like the mask's minimum filter.
    """
    depth = median_depth_m(depth_m)
    if depth is None:
        return cfg.normal_px
    return min(max(cfg.normal_px, window_px(cfg.normal_size_m, 0.5 * (intr.fx + intr.fy), depth)),
               cfg.normal_max_px)


# ----------------------------------------------------------------------------- gravity
def gravity_up_in_camera(T_world_camera: np.ndarray | None, mount: Mount) -> np.ndarray:
    """World "up" expressed in the camera (optical) frame, a unit 3-vector.

    With a pose (world z up, REP 103): ``R_world_camera^T e3``. Without: from the configured
    mount relative to looking straight down (up = -z_camera): positive pitch tilts the view
    towards the top of the image, positive roll towards its right:
    ``up = (sin r, -sin p cos r, -cos p cos r)``.
    """
    if T_world_camera is not None:
        T = np.asarray(T_world_camera, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):  # recorded poses are checked where decoded
            what = f"shape {T.shape}" if T.shape != (4, 4) else "non-finite values (NaN or inf)"
            raise DatasetError("pose", f"T_world_camera must be a finite 4x4 matrix, got {what}")
        up = T[2, :3].copy()                          # third row of R = R^T e3
        norm = np.linalg.norm(up)
        if norm == 0:
            raise DatasetError("pose", "T_world_camera has a singular rotation")
        return up / norm
    p, r = math.radians(mount.pitch_deg), math.radians(mount.roll_deg)
    return np.array([math.sin(r), -math.sin(p) * math.cos(r), -math.cos(p) * math.cos(r)])


def frame_up(frame: Frame, mount: Mount) -> np.ndarray:
    """A frame's world up in its camera frame: from its pose, else its own gravity (``Frame.up_camera``), else
    the mount."""
    if frame.T_world_camera is None and frame.up_camera is not None:
        up = np.asarray(frame.up_camera, dtype=np.float64)
        return up / np.linalg.norm(up)
    return gravity_up_in_camera(frame.T_world_camera, mount)


def mount_from_up(up_camera: np.ndarray) -> tuple[float, float]:
    """(pitch_deg, roll_deg) of the mount whose ``gravity_up_in_camera`` is ``up_camera``."""
    up = np.asarray(up_camera, dtype=np.float64)
    up = up / np.linalg.norm(up)
    roll = math.asin(float(np.clip(up[0], -1.0, 1.0)))
    pitch = math.atan2(-float(up[1]), -float(up[2]))
    return math.degrees(pitch), math.degrees(roll)


# ----------------------------------------------------------------------------- all four
@functools.lru_cache(maxsize=1)
def _default_uav() -> UavCfg:
    """The default config's UAV: the limits a bare depth image is mapped for (no config given)."""
    return load_config().uav


def noise_free_working(depth_m: np.ndarray, intr: Intrinsics, cfg: TerrainCfg, uav: UavCfg) -> Working | None:
    """The working scale of a depth image known to be exact (None without depth)."""
    return frame_working(depth_m, intr, DepthNoise.white(0.0, "none"), cfg, uav)


def frame_working(depth_m: np.ndarray, intr: Intrinsics, noise: DepthNoise, cfg: TerrainCfg,
                  uav: UavCfg) -> Working | None:
    """``limits.working_scale`` at the frame's median depth (None without depth)."""
    depth = median_depth_m(depth_m)
    if depth is None:
        return None
    intr = fit_intrinsics(intr, np.asarray(depth_m).shape)
    return working_scale(noise, depth, 0.5 * (intr.fx + intr.fy), cfg, uav)


def _blocks(d: _Depth, intr: Intrinsics, block: int) -> tuple[_Depth, Intrinsics]:
    """block x block means of inverse depth (``block_depth``) with the camera scaled to them."""
    depth, ok = block_depth(d.depth, d.valid, block)
    return _Depth(depth, ok, np.where(ok, depth, np.float32(0))), fit_intrinsics(intr, depth.shape)


def _upsample(values: np.ndarray, ok: np.ndarray, worst: float, shape: tuple[int, int],
              valid: np.ndarray) -> np.ndarray:
    """Block-level quantity -> full resolution (bilinear); undefined blocks enter as ``worst`` and
    stay undefined (NaN), as do pixels without depth."""
    h, w = shape
    if values.shape == (h, w):
        out: np.ndarray = values.astype(np.float32, copy=True)
        out[~(ok & valid)] = np.nan
        return out
    filled = np.where(ok, values, np.float32(worst)).astype(np.float32)
    out = cv2.resize(filled, (w, h), interpolation=cv2.INTER_LINEAR)
    defined = cv2.resize(ok.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    out[~(defined & valid)] = np.nan
    return out


def _nan_to_zero(values: np.ndarray, finite: np.ndarray | None = None) -> np.ndarray:
    """NaN -> 0 in place (``finite``: ``np.isfinite(values)`` when known). The values are finite or NaN
    here, so this is ``np.nan_to_num(values, nan=0.0)`` without its two infinity passes."""
    np.copyto(values, np.float32(0), where=np.isnan(values) if finite is None else ~finite)
    return values


def compute_maps(frame_or_depth: Frame | np.ndarray, intrinsics: Intrinsics | None,
                 gravity_camera: np.ndarray, cfg: TerrainCfg, work: Working | None = None,
                 noise: DepthNoise | None = None) -> TerrainMaps:
    """The four maps of one frame (or bare depth image), plus slope in degrees and validity.

    ``intrinsics`` may be None for a Frame (its own are used); ``gravity_camera`` is world up
    in the camera frame (see ``gravity_up_in_camera``). ``work`` (``frame_working``) sets the
    block size and windows and ``noise`` the noise removed; without them the depth is taken as
    exact (full resolution, the noise-free windows of the default UAV, nothing removed).
    """
    if isinstance(frame_or_depth, Frame):
        depth = frame_or_depth.depth_m
        intrinsics = intrinsics or frame_or_depth.intrinsics
    else:
        depth = frame_or_depth
    if intrinsics is None:
        raise DatasetError("depth image", "intrinsics are required with a bare depth image")
    d = _prepare(depth)
    up = np.asarray(gravity_camera, dtype=np.float64).reshape(-1)
    if up.shape != (3,) or not np.all(np.isfinite(up)) or np.linalg.norm(up) == 0:
        raise DatasetError("gravity", f"gravity_camera must be a finite non-zero 3-vector, got {gravity_camera!r}")
    up = up / np.linalg.norm(up)
    intr = fit_intrinsics(intrinsics, d.depth.shape)
    if work is None:
        work = noise_free_working(d.depth, intr, cfg, _default_uav())
    if work is None:  # no depth at all: every map is 0
        work = working_scale(DepthNoise.white(0.0, "none"), 1.0, 0.5 * (intr.fx + intr.fy), cfg, _default_uav())
    block, win, mpl = work.block_px, work.slope_window_blocks, work.metres_per_level
    if block > min(d.depth.shape):
        raise FrameError(f"median depth {work.altitude_m:.3g} m puts one working block ({float(block):.3g} px) "
                         f"beyond the {d.depth.shape[1]}x{d.depth.shape[0]} px image: is the depth in the unit its "
                         "encoding says (16UC1/mono16: sources.depth_unit_16u_m per count, 32FC1: metres, "
                         "little-endian unless is_bigendian)?")
    db, intr_b = (d, intr) if block == 1 else _blocks(d, intr, block)
    noise_a = noise.a_at(block) if noise is not None else 0.0

    rough, rough_ok = _roughness_m(db, cfg.depth_variance, noise_a)
    hole_px = cfg.flatness.hole_min_m * 0.5 * (intr_b.fx + intr_b.fy) / work.altitude_m
    edge_px = _edge_distance_px(db, cfg.flatness, mpl, hole_px,
                                cfg.limits.confidence_sigma if noise is not None else 0.0)
    edge_m = _ground_m(edge_px, db, intr_b)
    psi = _slope(db, intr_b, up, win, cfg.steepness)
    inc = cfg.inclination
    work_w = min(inc.work_px, db.depth.shape[1])
    cell_px = block * db.depth.shape[1] / work_w
    pca = patch_pca(db.depth, intr_b, inc.radius_m, work_w, inc.min_points, up, valid=db.valid, filled=db.filled,
                    noise_a_per_m=noise.a_at(cell_px) if noise is not None else 0.0)

    shape, valid = d.depth.shape, d.valid
    if block > 1:
        return _grid_maps(db, intr_b, block, rough, rough_ok, edge_px, edge_m, psi, pca.curvature, work, up, cfg,
                          d)
    rough = _upsample(rough, rough_ok, 10.0 * cfg.depth_variance.s0_m, shape, valid)
    psi = _upsample(psi, np.isfinite(psi), math.pi / 2, shape, valid)
    curvature = _upsample(pca.curvature, np.isfinite(pca.curvature), 1.0 / 3.0, shape, valid)
    edge_m = _nan_to_zero(_upsample(edge_m, db.valid, 0.0, shape, valid))
    slope_deg = np.multiply(psi, np.float32(180.0 / math.pi))
    rough_ok_full = np.isfinite(rough)
    return TerrainMaps(
        depth_variance=_roughness_map(_nan_to_zero(rough, rough_ok_full), rough_ok_full, cfg.depth_variance),
        flatness=_flatness(edge_px, edge_m, valid, cfg.flatness),
        edge_distance_m=edge_m,
        inclination=inclination_map(curvature, cfg.inclination),
        steepness=steepness_map(psi, cfg.steepness, work.max_slope_deg),
        valid=valid,
        slope_deg=slope_deg,
        work=work,
        up_camera=up,
    )


def _grid_maps(db: _Depth, intr_b: Intrinsics, block: int, rough: np.ndarray, rough_ok: np.ndarray,
               edge_px: np.ndarray, edge_m: np.ndarray, psi: np.ndarray, curvature: np.ndarray, work: Working,
               up: np.ndarray, cfg: TerrainCfg, d: _Depth) -> TerrainMaps:
    """b > 1: the four maps on the block grid (``BlockGrid``), and at full resolution that grid upsampled
    (bilinear; zero where the pixel has no depth or its nearest block has none), with the slope and the
    edge distance likewise."""
    ok = db.valid
    on_grid = {
        "depth_variance": _roughness_map(np.where(rough_ok, rough, np.float32(0)), rough_ok & ok, cfg.depth_variance),
        "flatness": _flatness(edge_px * np.float32(block), edge_m, ok, cfg.flatness),
        "inclination": inclination_map(curvature, cfg.inclination),
        "steepness": steepness_map(psi, cfg.steepness, work.max_slope_deg),
    }
    shape, valid = d.depth.shape, d.valid
    h, w = shape
    known = cv2.resize(ok.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)
    np.logical_and(known, valid, out=known)
    unknown = ~known

    def up_sample(values: np.ndarray, fill: float) -> np.ndarray:
        out = cv2.resize(values, (w, h), interpolation=cv2.INTER_LINEAR)
        np.copyto(out, np.float32(fill), where=unknown)
        return out

    full = {name: up_sample(m, 0.0) for name, m in on_grid.items()}
    slope_deg = _upsample(psi, np.isfinite(psi), math.pi / 2, shape, valid)
    slope_deg *= np.float32(180.0 / math.pi)
    grid = BlockGrid(on_grid, ok, block)
    return TerrainMaps(**full, valid=valid, slope_deg=slope_deg, edge_distance_m=up_sample(edge_m, 0.0), work=work,
                       up_camera=up, grid=grid)


@dataclass(frozen=True)
class MapParams:
    """What a frame's maps read: the ``terrain`` section, the UAV (its limits set the working scale) and
    ``camera.mount`` (gravity for a frame without a pose or its own)."""

    terrain: TerrainCfg
    uav: UavCfg
    mount: Mount

    @classmethod
    def of(cls, config: Config) -> MapParams:
        return cls(config.terrain, config.uav, config.camera.mount)


def frame_maps(frame: Frame, params: MapParams, noise: DepthNoise | None = None) -> TerrainMaps:
    """compute_maps with gravity from the frame's pose (or ``camera.mount``) and windows from the noise.

    ``noise``: what the recording's ``NoiseTracker`` says; None measures it on this frame alone
    (or takes ``terrain.noise`` when that is a number).
    """
    up = frame_up(frame, params.mount)
    if noise is None:
        noise = NoiseTracker(params.terrain.noise, params.terrain.noise_estimate).update(frame.depth_m)
    work = frame_working(frame.depth_m, frame.intrinsics, noise, params.terrain, params.uav)
    return compute_maps(frame, None, up, params.terrain, work, noise)
