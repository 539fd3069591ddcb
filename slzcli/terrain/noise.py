"""Depth noise measured from the depth itself: sigma_z = a_b z^2 at every block scale b.

Stereo depth error grows with the square of range (sigma_z = z^2 s / (f B)), so in inverse
depth w = 1/z it is constant: sigma_w = a with sigma_z = a z^2. Inverse depth has a second
gift: a plane is exactly linear in the pixel coordinates, so the residual of a pixel against
the mean of its 3 x 3 neighbourhood is pure noise on any plane, level or tilted, near or far
(a terrain's curvature and edges are a minority the median ignores). For white noise the
residual's variance is (8/9) a^2; a MAD turns it into a robust estimate of a.

Real stereo noise is not white: SGBM's aggregation and the projector pattern correlate it over
several pixels, so averaging a block of b x b pixels removes far less than the factor b that
white noise would give (the real RealSense frames of the test data: a_8 ~ 2 a_1). The same
estimate on a pyramid of b x b block means (of inverse depth, so planes stay planes) measures
a_b at b = 1, 2, 4, 8, 16: the noise in the band each map works in. Every window of
the maps and every detection limit is derived from these numbers (``limits.py``).

``NoiseTracker`` smooths the per-frame estimates over a recording (a running median of the
last few detection frames), so one odd frame cannot swing the windows.
"""

from __future__ import annotations

import math
from collections import deque

import cv2
import numpy as np

from slzcli.config import NoiseEstimateCfg
from slzcli.types import SCALES_PX, DepthNoise

MAD_TO_SIGMA = 1.482602218505602       # sigma of a normal distribution / its median absolute deviation
_RESIDUAL_SCALE = math.sqrt(8.0 / 9.0)  # std of (x - mean of its 3 x 3 window) / std of x, white noise
_WINDOW = np.ones((3, 3), np.uint8)     # the residual's window
MEDIAN_SAMPLES = 65536                  # residuals a level's median needs at least (above 4x: a sub-lattice)


def _residual_mad(w: np.ndarray, ok: np.ndarray, min_count: int) -> tuple[float, int]:
    """Robust std of (w - mean of its 3 x 3 window) over pixels whose whole window is in ``ok``.

    A level with more than 4 x ``MEDIAN_SAMPLES`` such pixels takes its median on a regular
    sub-lattice of at least that many (the MAD's sampling error there is ~0.5 %, well inside the
    frame-to-frame spread the tracker's running median smooths; the full median of a 640x480 frame
    was most of the estimate's time). The count returned is every usable pixel.
    """
    wf = np.where(ok, w, np.float32(0)).astype(np.float32, copy=False)
    mean = cv2.blur(wf, (3, 3), borderType=cv2.BORDER_CONSTANT)
    # the whole 3 x 3 window in ok (outside the image is not): an erosion of the 0/1 mask
    inside = cv2.erode(ok.view(np.uint8), _WINDOW, borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)
    count = int(np.count_nonzero(inside))
    if count < min_count:
        return math.nan, count
    stride = max(1, math.isqrt(count // MEDIAN_SAMPLES))
    sub = (slice(None, None, stride), slice(None, None, stride))
    r = np.subtract(wf[sub], mean[sub])[inside[sub]]
    np.abs(r, out=r)                                 # r is a gathered copy: its median may reorder it
    return MAD_TO_SIGMA * float(np.median(r, overwrite_input=True)) / _RESIDUAL_SCALE, count


def _sum_2x2(a: np.ndarray) -> np.ndarray:
    """Sums of 2 x 2 blocks (even sides), added in the order ``reshape(h/2, 2, w/2, 2).sum(axis=(1, 3))``
    adds them, (a00 + a01) + (a10 + a11) (checked bit for bit), without its slow strided reduction."""
    out = a[0::2, 0::2] + a[0::2, 1::2]
    out += a[1::2, 0::2] + a[1::2, 1::2]
    return out


def depth_quantum_m(depth_m: np.ndarray, valid: np.ndarray) -> float:
    """The smallest step between horizontal neighbours: the unit of quantised depth (1 mm for 16UC1
    millimetres), ~0 for continuous depth. Sparse steps of exactly one unit are invisible to the
    MAD above, but on an oblique floor they line up into contour terraces an edge detector sees."""
    both = valid[:, 1:] & valid[:, :-1]
    dz = np.abs(depth_m[:, 1:] - depth_m[:, :-1])
    np.logical_and(both, dz > 0, out=both)
    step = float(np.min(dz, where=both, initial=np.inf))   # no gathers: a where-reduction
    return step if math.isfinite(step) else 0.0


def estimate_noise(depth_m: np.ndarray, cfg: NoiseEstimateCfg) -> DepthNoise | None:
    """a_b at every scale of ``SCALES_PX`` from one depth image; None when it has too little depth.

    A block enters a level only when all its pixels have depth (a half-empty block is not the
    mean the noise model describes). A level with fewer than ``cfg.min_residuals`` usable
    windows keeps the previous level's value (no credit for averaging it cannot see).
    """
    depth = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    quantum = depth_quantum_m(depth, valid)
    w: np.ndarray = np.zeros(depth.shape, np.float32)
    np.divide(np.float32(1.0), depth, out=w, where=valid)
    count = valid.astype(np.float32)
    out: list[float] = []
    first_n = 0
    for level, block in enumerate(SCALES_PX):
        full = float(block * block)
        ok = count > full - 0.5
        mean_w = np.divide(w, np.maximum(count, 1.0), dtype=np.float32)
        a, n = _residual_mad(mean_w, ok, cfg.min_residuals)
        if level == 0:
            if not math.isfinite(a):
                return None
            first_n = n
        out.append(a if math.isfinite(a) else out[-1])
        h, wd = w.shape[0] // 2 * 2, w.shape[1] // 2 * 2
        if h < 6 or wd < 6:
            out.extend(out[-1] for _ in SCALES_PX[level + 1:])
            break
        w, count = _sum_2x2(w[:h, :wd]), _sum_2x2(count[:h, :wd])
    # Each level is a band-pass of the noise (wavelengths ~2-6 blocks): what a map working at
    # that scale sees. A coarser level may read higher than white noise would (correlated error,
    # or terrain the median did not reject): both make the maps more careful, never less.
    return DepthNoise(tuple(out), "estimated", first_n, quantum)


class NoiseTracker:
    """The noise a recording's detection frames are computed with: per-frame estimates, smoothed.

    ``terrain.noise`` a number: that coefficient (white), always. ``auto``: the running median
    (per scale) of the last ``frames`` estimates; a frame too empty for an estimate reuses the
    median, and before any estimate the prior is used (counted, so the run can say so).
    """

    def __init__(self, noise: float | str, cfg: NoiseEstimateCfg) -> None:
        self.fixed = None if noise == "auto" else DepthNoise.white(float(noise), "config")
        self.cfg = cfg
        self._recent: deque[tuple[float, ...]] = deque(maxlen=cfg.frames)
        self._quanta: deque[float] = deque(maxlen=cfg.frames)
        self.estimates: list[float] = []      # pixel-scale a of every frame estimated (for the report)
        self.prior_frames = 0

    def update(self, depth_m: np.ndarray) -> DepthNoise:
        if self.fixed is not None:
            return self.fixed
        est = estimate_noise(depth_m, self.cfg)
        if est is not None:
            self._recent.append(est.a_per_m)
            self._quanta.append(est.quantum_m)
            self.estimates.append(est.a1_per_m)
        if not self._recent:
            self.prior_frames += 1
            return DepthNoise.flat(self.cfg.prior_a_per_m, "prior")
        med = np.median(np.asarray(self._recent, dtype=np.float64), axis=0)
        return DepthNoise(tuple(float(x) for x in med), "estimated", est.residuals if est else 0,
                          float(np.median(np.asarray(self._quanta))))

    def summary(self) -> dict[str, object]:
        """What run.json reports: the source and the spread of the per-frame estimates."""
        if self.fixed is not None:
            return {"source": "config", "a_per_m": self.fixed.a1_per_m}
        a = np.asarray(self.estimates, dtype=np.float64)
        out: dict[str, object] = {"source": "estimated" if a.size else "prior", "frames_estimated": int(a.size),
                                  "frames_on_prior": self.prior_frames}
        if a.size:
            out.update({"a_per_m_median": float(np.median(a)), "a_per_m_min": float(a.min()),
                        "a_per_m_max": float(a.max())})
        if self._recent:
            last = np.median(np.asarray(self._recent, dtype=np.float64), axis=0)
            out["a_per_m_by_block_px"] = {str(b): float(x) for b, x in zip(SCALES_PX, last, strict=False)}
        return out
