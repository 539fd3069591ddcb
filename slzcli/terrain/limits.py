"""The working scale, windows and detection limits of one frame, derived from its depth noise.

Nothing here is tuned to a sensor: the inputs are the measured noise (``noise.DepthNoise``),
the frame's median depth and focal length, and the UAV's physical limits (footprint, the step
it tolerates, its slope limit). One frame, one set of windows (like the mask's minimum filter):

- **Block size b.** The maps run on b x b block means of the depth. b is the smallest that lets
  the depth-variance map tell its own half-value roughness (``s0 ln 2``) from the noise at
  ``confidence_sigma``: the 3 x 3-block plane-fit residual variance of pure noise has a standard
  deviation of sqrt(2/6) sigma_b^2. b never exceeds the size that leaves
  ``blocks_per_footprint`` blocks across the footprint (coarser could not place a landing square),
  and is never finer than ``finest_block_m`` on the ground: close to the ground a pixel covers a few
  millimetres, far finer than the plan-view mask's cell, and full-resolution maps there cost 4-5x
  the work for nothing the mask can use.
- **Slope window.** The steepness plane fit covers K x K blocks, at least ``normal_size_m`` and
  at most the footprint, the smallest K for which both limits below are ``target_margin`` times
  within the UAV's tolerances (a window that only just meets them leaves a slope map too noisy to
  call level ground level).
- **Limits** (what the issue calls the smallest step and slope detectable): a step is
  detectable when the difference of the two half-window means exceeds k times its noise,
  ``h_min = 2 k sigma / K`` (K x K samples, half on each side), and a slope when the fitted
  gradient exceeds k times its noise, ``tan(psi_min) = k sigma sqrt(12) / (spacing K sqrt(K^2 - 1))``.
  Correlated noise is handled by evaluating both with the noise measured at every coarser block
  scale that still gives 2 samples across the window, and keeping the worst.
- **Edge scaling.** Canny's depth scaling makes a step of ``uav.max_step_m`` a strong edge, unless
  the noise's derivatives would then cross the low threshold at k sigma: then the noise sets it
  (``edge_scaling_m``), as does the depth's quantum (16UC1 millimetre terraces on an oblique floor
  line up into contours), and only larger steps are edges (the slope and patch maps still see them).
- **Vouching.** The frame can vouch for a site when ``h_min <= uav.max_step_m`` and
  ``psi_min <= uav.max_slope_deg``. With fixed pixel windows, h_min grows as z^2 and psi_min as z
  (sigma ~ z^2, spacing ~ z), so the same windows vouch up to ``vouch_depth_m``; nothing beyond
  it is called safe.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.config import TerrainCfg, UavCfg
from slzcli.types import SCALES_PX, DepthNoise, Working

_PLANE_DOF_3X3 = 6.0      # 9 samples less the 3 parameters of a plane
# A coarser scale still counts while it puts this many samples across the window: correlated
# noise tilts a window most at wavelengths near its own size (measured with Gaussian-filtered
# noise: stopping at 3 samples missed half the slope noise); for white noise n = 2 overstates
# the slope noise by 15 % at most.
_MIN_SAMPLES_ACROSS = 2.0


@functools.lru_cache(maxsize=16)
def _edge_kernel_gains(blur_px: int) -> tuple[float, float]:
    """(noise gain, step gain) of the flatness map's derivative (its Gaussian blur, then Sobel-x):
    the std of one derivative of unit white noise, and the peak derivative of a unit step."""
    size = 4 * blur_px + 9
    delta = np.zeros((size, size), np.float32)
    delta[size // 2, size // 2] = 1.0
    step = np.zeros((size, size), np.float32)
    step[:, size // 2:] = 1.0

    def deriv(img: np.ndarray) -> np.ndarray:
        img = cv2.GaussianBlur(img, (blur_px, blur_px), 0) if blur_px > 1 else img
        return cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)

    noise = float(np.sqrt(np.sum(deriv(delta).astype(np.float64) ** 2)))
    return noise, float(np.abs(deriv(step)).max())


def edge_scaling_m(step_m: float, sigma_m: float, k: float, canny_low: float, canny_high: float,
                   blur_px: int, quantum_m: float = 0.0) -> float:
    """Canny's depth scaling (metres per level): a step of ``step_m`` is a strong edge (its derivative
    reaches ``canny_high``), unless the noise needs a coarser scaling to stay below ``canny_low`` at
    k sigma, or the depth's quantum (one unit of 16UC1 depth) would reach canny_low / k. Then only
    larger steps are strong edges."""
    noise_gain, step_gain = _edge_kernel_gains(blur_px)
    return max(step_gain * step_m / canny_high, k * sigma_m * noise_gain / canny_low,
               k * quantum_m * step_gain / canny_low)


def _odd_at_least(x: float) -> int:
    k = max(1, math.ceil(x - 1e-9))
    return k if k % 2 == 1 else k + 1


def _odd_at_most(x: float) -> int:
    k = max(1, math.floor(x + 1e-9))
    return k if k % 2 == 1 else k - 1


def _limits(noise: DepthNoise, z: float, focal_px: float, block_px: int, blocks: int,
            k: float) -> tuple[float, float]:
    """(smallest step m, smallest slope deg) distinguishable at k sigma in a blocks x blocks window."""
    step, tan_slope = 0.0, 0.0
    scales = [block_px] + [s for s in SCALES_PX if s > block_px]
    for b in scales:
        n = blocks * block_px / b                        # samples across the window at this scale
        if b != block_px and n < _MIN_SAMPLES_ACROSS:
            break
        sigma = noise.sigma_m(z, b)
        spacing = b * z / focal_px
        step = max(step, 2.0 * k * sigma / n)
        tan_slope = max(tan_slope, k * sigma * math.sqrt(12.0) / (spacing * n * math.sqrt(max(n * n - 1.0, 1.0))))
    return step, math.degrees(math.atan(tan_slope))


def working_scale(noise: DepthNoise, depth_m: float, focal_px: float, cfg: TerrainCfg, uav: UavCfg) -> Working:
    """Block size, slope window and limits of a frame whose median depth is ``depth_m``."""
    lim = cfg.limits
    k = lim.confidence_sigma
    footprint = max(uav.footprint_m)
    px_per_m = focal_px / depth_m
    b_max = max(1, math.floor(footprint * px_per_m / lim.blocks_per_footprint))
    b_min = min(b_max, max(1, math.floor(lim.finest_block_m * px_per_m)))
    s_half_sq = (cfg.depth_variance.s0_m * math.log(2.0)) ** 2
    block = b_max
    for b in range(b_min, b_max + 1):
        if k * math.sqrt(2.0 / _PLANE_DOF_3X3) * noise.sigma_m(depth_m, b) ** 2 <= s_half_sq:
            block = b
            break
    block_m = block * depth_m / focal_px
    st = cfg.steepness
    k_max = max(3, _odd_at_most(footprint / block_m))
    # the noise-free window: normal_size_m on the ground, within [normal_px, normal_max_px] pixels
    free_px = min(max(st.normal_px, st.normal_size_m * px_per_m), st.normal_max_px)
    k_min = min(k_max, max(3, _odd_at_least(free_px / block - 1e-9)))
    blocks, (step, slope) = k_max, _limits(noise, depth_m, focal_px, block, k_max, k)
    m = lim.target_margin
    for kk in range(k_min, k_max + 1, 2):
        s, p = _limits(noise, depth_m, focal_px, block, kk, k)
        if s * m <= uav.max_step_m and p * m <= uav.max_slope_deg:
            blocks, step, slope = kk, s, p
            break
    vouched = step <= uav.max_step_m and slope <= uav.max_slope_deg
    ratio = min(math.sqrt(uav.max_step_m / step) if step > 0 else math.inf,
                uav.max_slope_deg / slope if slope > 0 else math.inf)
    flat = cfg.flatness
    mpl = edge_scaling_m(uav.max_step_m, noise.sigma_m(depth_m, block), k, flat.canny_low, flat.canny_high,
                         flat.blur_px, noise.quantum_m)
    sigma = max(a for a in noise.a_per_m) * depth_m * depth_m   # the worst band: correlated error lives coarse
    return Working(altitude_m=depth_m, sigma_m=sigma, block_px=block, block_m=block_m,
                   slope_window_blocks=blocks, metres_per_level=mpl,
                   step_min_m=step, slope_min_deg=slope, vouch_depth_m=depth_m * ratio, vouched=vouched,
                   max_step_m=uav.max_step_m, max_slope_deg=uav.max_slope_deg, focal_px=focal_px, noise=noise)


def vouchable_altitude_m(noise: DepthNoise, focal_px: float, cfg: TerrainCfg, uav: UavCfg,
                         upper_m: float, lower_m: float = 0.3) -> float | None:
    """The highest altitude below ``upper_m`` at which this noise would let a frame vouch (None: none)."""
    if not working_scale(noise, lower_m, focal_px, cfg, uav).vouched:
        return None
    lo, hi = lower_m, upper_m
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if working_scale(noise, mid, focal_px, cfg, uav).vouched:
            lo = mid
        else:
            hi = mid
    return lo


@dataclass(frozen=True)
class WouldVouch:
    """What a frame that cannot vouch hides at its altitude, and the altitude below which its noise would let
    it vouch: one bisection serves the run's no-site reason and its advice."""

    altitude_m: float
    sigma_m: float
    hidden: str                 # ``Working.hidden``: "steps below 0.30 m (the UAV tolerates 0.09 m)" ...
    below_m: float | None       # ``vouchable_altitude_m`` (None: at no altitude with this sensor)

    def hides(self, with_sigma: bool) -> str:
        """"at 9.8 m the depth noise [(sigma ~ 0.37 m)] hides steps below 0.30 m ..."."""
        noise = f"the depth noise (sigma ~ {self.sigma_m:.2f} m)" if with_sigma else "the depth noise"
        return f"at {self.altitude_m:.1f} m {noise} hides {self.hidden}"

    def reason(self) -> str:
        """The one-line "why not", e.g. "at 9.8 m the depth noise (sigma ~ 0.37 m) hides steps below 0.30 m ...;
        below 6.1 m it would not"."""
        tail = f"; below {self.below_m:.1f} m it would not" if self.below_m is not None else \
            "; at no altitude with this sensor"
        return self.hides(with_sigma=True) + tail


def would_vouch(work: Working, cfg: TerrainCfg, uav: UavCfg) -> WouldVouch:
    """What the frame of ``work`` hides and below which altitude it would not."""
    return WouldVouch(work.altitude_m, work.sigma_m, work.hidden(),
                      vouchable_altitude_m(work.noise, work.focal_px, cfg, uav, work.altitude_m))


def limit_reason(work: Working, cfg: TerrainCfg, uav: UavCfg) -> str:
    """The one-line "why not" of a frame that cannot vouch (``WouldVouch.reason``)."""
    return would_vouch(work, cfg, uav).reason()
