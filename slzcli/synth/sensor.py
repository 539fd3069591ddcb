"""A RealSense-like sensor model applied to an exact render; seeded and deterministic.

Depth: Gaussian noise with sigma = a z^2 (stereo depth error grows with the square of
range), holes at depth discontinuities (stereo matching fails there) dropped with a
probability, and range limits -> NaN. Colour: additive Gaussian noise, then 8 bits.
"""

from __future__ import annotations

import numpy as np

from slzcli.config import SensorCfg


def depth_edges(depth_m: np.ndarray, jump_m: float) -> np.ndarray:
    """Pixels whose depth differs from a 4-neighbour by more than ``jump_m`` (or borders a hole)."""
    d = np.where(np.isfinite(depth_m), depth_m, np.inf).astype(np.float64)
    edge = np.zeros(d.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        dy = np.abs(np.diff(d, axis=0))
        dx = np.abs(np.diff(d, axis=1))
    jy = ~(dy <= jump_m)     # NaN/inf differences count as jumps
    jx = ~(dx <= jump_m)
    edge[:-1] |= jy
    edge[1:] |= jy
    edge[:, :-1] |= jx
    edge[:, 1:] |= jx
    return edge & np.isfinite(depth_m)


def apply_depth_model(depth_m: np.ndarray, cfg: SensorCfg, rng: np.random.Generator) -> np.ndarray:
    """Noisy float32 depth (NaN = no measurement) from exact depth."""
    z = depth_m.astype(np.float64)
    noise = rng.standard_normal(z.shape)
    drop = rng.random(z.shape)
    out = z + cfg.depth_sigma_a * z * z * noise
    holes = depth_edges(depth_m, cfg.edge_jump_m) & (drop < cfg.edge_hole_prob)
    with np.errstate(invalid="ignore"):
        bad = holes | ~np.isfinite(z) | (z < cfg.min_range_m) | (z > cfg.max_range_m)
    out[bad] = np.nan
    return out.astype(np.float32)


def apply_color_model(rgb: np.ndarray, cfg: SensorCfg, rng: np.random.Generator) -> np.ndarray:
    """uint8 RGB from float [0, 1] colour with additive noise in grey levels."""
    levels = rgb.astype(np.float64) * 255.0 + cfg.color_noise * rng.standard_normal(rgb.shape)
    return np.clip(np.rint(levels), 0, 255).astype(np.uint8)
