"""The four terrain maps of METHOD.md 2.3: depth variance, flatness, inclination, steepness.

Every map is float32 in [0, 1] with 1 = good for landing, and 0 where the pixel has no depth
or too little valid neighbourhood to say (unknown is unsafe). Each map has two modes:
``absolute`` maps a physical quantity through a fixed documented range, so 1 means the same
thing in every frame; ``frame`` reproduces the paper's per-frame min-max (Eq. 5).

Absolute ranges (all from config):
  depth variance  exp(-s / s0_m), s = local depth standard deviation in metres
  flatness        min(d / clearance_m, 1), d = ground distance (m) to the nearest depth edge or hole
  inclination     exp(-C / curvature_ref), C = l0 / (l0 + l1 + l2) of the radius_m patch
  steepness       exp(-(psi / slope_limit_deg)^2), psi = surface slope against gravity
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.config import (Config, DepthVarianceCfg, FlatnessCfg, InclinationCfg, Mount,
                           SteepnessCfg, TerrainCfg)
from slzcli.errors import DatasetError
from slzcli.terrain.geometry import (NormalField, fit_intrinsics, median_depth_m, normal_field, patch_pca,
                                     valid_depth, window_px)
from slzcli.types import Frame, Intrinsics, TerrainMaps

# cv2.distanceTransform mask sizes by the config value (3 or 5 px).
_DIST_MASKS = {3: cv2.DIST_MASK_3, 5: cv2.DIST_MASK_5}


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
def depth_variance_map(depth_m: np.ndarray, cfg: DepthVarianceCfg) -> np.ndarray:
    """Alg. 1: local depth standard deviation s over a kernel_px window -> exp(-s / s0_m).

    The sensor's own noise (sigma = noise_a_per_m z^2, RealSense-like) is subtracted from the
    local variance first: at 10 m a 3x3 window of a level floor otherwise shows ~5 cm of
    "variation" that is only noise, and the map stops telling ground from clutter.

    Valid-only sums (holes do not bleed); sums and sums of squares accumulate in float64 so
    E[D^2] - E[D]^2 keeps millimetres at tens of metres.
    """
    return _depth_variance(_prepare(depth_m), cfg)


def _depth_variance(d: _Depth, cfg: DepthVarianceCfg) -> np.ndarray:
    k = (cfg.kernel_px, cfg.kernel_px)
    n = cv2.boxFilter(d.valid.view(np.uint8), cv2.CV_32F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    ok = d.valid & (n >= cfg.min_valid_fraction * cfg.kernel_px * cfg.kernel_px)
    s1 = cv2.boxFilter(d.filled, cv2.CV_64F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    s2 = cv2.sqrBoxFilter(d.filled, cv2.CV_64F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    s2 *= n                                             # n^2 var = n sum(D^2) - sum(D)^2, in float64
    mean = np.zeros(n.shape, np.float32)
    np.divide(s1, n, out=mean, where=ok, casting="unsafe")
    s1 *= s1
    s2 -= s1
    var = np.abs(s2).astype(np.float32)                 # the cancellation is done: float32 from here
    n *= n
    np.divide(var, n, out=var, where=ok)
    if cfg.noise_a_per_m > 0:                           # remove the sensor's own variance, (a z^2)^2
        mean *= mean
        mean *= np.float32(cfg.noise_a_per_m)
        mean *= mean
        var -= mean
        np.maximum(var, 0.0, out=var)
    s = np.sqrt(var, out=var)
    s *= np.float32(-1.0 / cfg.s0_m)
    return _finish(np.exp(s, out=s), ok, cfg.normalise)


def depth_edges(depth_m: np.ndarray, cfg: FlatnessCfg) -> np.ndarray:
    """Alg. 2 edges: Canny(canny_low, canny_high) of depth at metres_per_level, plus every hole.

    Canny is fed the Sobel derivatives of ``depth / metres_per_level`` directly: the same
    operator and thresholds as Canny on the fixed-scale 8-bit image, without its 256-level
    range (which would clip everything beyond 2.55 m of relief at 1 cm per level).
    """
    return _depth_edges(_prepare(depth_m), cfg)


def _depth_edges(d: _Depth, cfg: FlatnessCfg) -> np.ndarray:
    return _clear_of_edges(d, cfg) == 0


def _clear_of_edges(d: _Depth, cfg: FlatnessCfg) -> np.ndarray:
    """uint8: 1 where a pixel is neither a depth edge nor a hole (the distance-transform input)."""
    img = d.filled
    if cfg.blur_px > 1:   # normalised blur: holes do not pull their neighbours' depth to 0
        ksize = (cfg.blur_px, cfg.blur_px)
        num = cv2.GaussianBlur(img, ksize, 0)
        den = cv2.GaussianBlur(d.valid.astype(np.float32), ksize, 0)
        img = np.divide(num, den, out=num, where=d.valid)
    scale = float(1.0 / cfg.metres_per_level)
    derivs = []
    for dx, dy in ((1, 0), (0, 1)):
        g = cv2.Sobel(img, cv2.CV_32F, dx, dy, ksize=3, scale=scale, borderType=cv2.BORDER_REPLICATE)
        # Canny takes 16-bit derivatives: round and saturate (a saturated gradient is an edge anyway)
        derivs.append(cv2.add(g, 0.0, dtype=cv2.CV_16S))
    edges = cv2.Canny(derivs[0], derivs[1], cfg.canny_low, cfg.canny_high)   # 255 on edges
    clear = cv2.compare(edges, 0, cv2.CMP_EQ)                                 # 255 off edges
    return cv2.bitwise_and(clear, d.valid.view(np.uint8))                     # holes are edges


def flatness_map(depth_m: np.ndarray, intrinsics: Intrinsics, cfg: FlatnessCfg) -> np.ndarray:
    """Alg. 2 / Eq. 6: distance to the nearest depth edge or hole.

    absolute: pixel distance x depth / f = metres on the ground, map = min(d / clearance_m, 1);
    frame: the pixel distance min-maxed over the frame (the paper).
    """
    d = _prepare(depth_m)
    dist_px = _edge_distance_px(d, cfg)
    return _flatness(dist_px, _ground_m(dist_px, d, fit_intrinsics(intrinsics, d.depth.shape)), d.valid, cfg)


def _flatness(dist_px: np.ndarray, edge_m: np.ndarray, valid: np.ndarray, cfg: FlatnessCfg) -> np.ndarray:
    if cfg.normalise == "frame":
        return normalise_frame(dist_px, valid)
    return _finish(edge_m / np.float32(cfg.clearance_m), valid, "absolute")


def _edge_distance_px(d: _Depth, cfg: FlatnessCfg) -> np.ndarray:
    """Pixel distance of every pixel to the nearest depth edge or hole (float32)."""
    clear = _clear_of_edges(d, cfg)
    if cv2.countNonZero(clear) == clear.size:   # no edge and no hole anywhere: all as far as can be
        return np.full(clear.shape, np.float32(max(clear.shape)), dtype=np.float32)
    return cv2.distanceTransform(clear, cv2.DIST_L2, _DIST_MASKS[cfg.distance_mask])


def _ground_m(dist_px: np.ndarray, d: _Depth, intr: Intrinsics) -> np.ndarray:
    """Pixels -> metres on the ground at each pixel's depth (px x depth / f); 0 where no depth."""
    metres = dist_px * d.filled * np.float32(2.0 / (intr.fx + intr.fy))
    metres[~d.valid] = 0.0
    return metres


def edge_distance_m(depth_m: np.ndarray, intrinsics: Intrinsics, cfg: FlatnessCfg) -> np.ndarray:
    """Metres from each pixel to the nearest depth edge or hole: the clearance of the acceptance test."""
    d = _prepare(depth_m)
    return _ground_m(_edge_distance_px(d, cfg), d, fit_intrinsics(intrinsics, d.depth.shape))


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
    norm = cv2.magnitude(cv2.magnitude(normals.nx, normals.ny), normals.nz)
    cos = cv2.divide(np.abs(dot, out=dot), norm)      # orienting n up = taking |e3 . n|
    np.minimum(cos, np.float32(1.0), out=cos)
    np.arccos(cos, out=cos)
    np.copyto(cos, np.float32(np.nan), where=~normals.ok | (norm == 0))
    return cos


def steepness_map(psi_rad: np.ndarray, cfg: SteepnessCfg) -> np.ndarray:
    """Alg. 4 / Eq. 9: exp(-(psi / slope_limit)^2), or exp(-psi^2) min-maxed (METHOD's fix of line 7)."""
    ok = np.isfinite(psi_rad)
    scale = 1.0 if cfg.normalise == "frame" else 1.0 / math.radians(cfg.slope_limit_deg)
    x = np.multiply(psi_rad, np.float32(scale), dtype=np.float32)
    np.multiply(x, x, out=x)
    np.negative(x, out=x)
    np.exp(x, out=x)
    return _finish(x, ok, cfg.normalise)


def _slope(d: _Depth, intr: Intrinsics, up: np.ndarray, cfg: SteepnessCfg) -> np.ndarray:
    """Slope psi (radians) of every pixel from the plane fit over the metric window.

    A window ``step`` times ``normal_px`` wide runs as a ``normal_px``-ish window on the depth
    averaged over step x step blocks (valid pixels only), and the slope is upsampled: the same
    ground size and the same noise averaging for ~step^2 less work. Pixels without depth stay NaN.
    """
    win = normal_window_px(d.depth, intr, cfg)
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


def mount_from_up(up_camera: np.ndarray) -> tuple[float, float]:
    """(pitch_deg, roll_deg) of the mount whose ``gravity_up_in_camera`` is ``up_camera``."""
    up = np.asarray(up_camera, dtype=np.float64)
    up = up / np.linalg.norm(up)
    roll = math.asin(float(np.clip(up[0], -1.0, 1.0)))
    pitch = math.atan2(-float(up[1]), -float(up[2]))
    return math.degrees(pitch), math.degrees(roll)


# ----------------------------------------------------------------------------- all four
def compute_maps(frame_or_depth: Frame | np.ndarray, intrinsics: Intrinsics | None,
                 gravity_camera: np.ndarray, cfg: TerrainCfg) -> TerrainMaps:
    """The four maps of one frame (or bare depth image), plus slope in degrees and validity.

    ``intrinsics`` may be None for a Frame (its own are used); ``gravity_camera`` is world up
    in the camera frame (see ``gravity_up_in_camera``).
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

    psi = _slope(d, intr, up, cfg.steepness)
    slope_deg = np.multiply(psi, np.float32(180.0 / math.pi))
    pca = patch_pca(d.depth, intr, cfg.inclination.radius_m, cfg.inclination.work_px,
                    cfg.inclination.min_points, up, valid=d.valid, filled=d.filled)
    edge_px = _edge_distance_px(d, cfg.flatness)
    edge_m = _ground_m(edge_px, d, intr)
    return TerrainMaps(
        depth_variance=_depth_variance(d, cfg.depth_variance),
        flatness=_flatness(edge_px, edge_m, d.valid, cfg.flatness),
        edge_distance_m=edge_m,
        inclination=inclination_map(pca.curvature, cfg.inclination),
        steepness=steepness_map(psi, cfg.steepness),
        valid=d.valid,
        slope_deg=slope_deg,
    )


def frame_maps(frame: Frame, config: Config) -> TerrainMaps:
    """compute_maps with gravity from the frame's pose, or from ``camera.mount`` without one."""
    up = gravity_up_in_camera(frame.T_world_camera, config.camera.mount)
    return compute_maps(frame, None, up, config.terrain)
