"""Sensor models applied to an exact render; seeded and deterministic.

Depth (``synth.sensor.model``): ``ideal`` = the exact depth within the range limits;
``gaussian`` = Gaussian noise with sigma = a z^2 (stereo depth error grows with the square
of range), holes at depth discontinuities dropped with a probability, and range limits ->
NaN; ``stereo`` = an infrared pair matched by SGBM (``stereo.py``). Colour: additive
Gaussian noise, then 8 bits.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from slzcli.config import SensorCfg
from slzcli.synth.render import Renderer
from slzcli.synth.stereo import StereoDepth
from slzcli.types import Intrinsics


class DepthSensor(Protocol):
    """Measured depth (float32 HxW, NaN = none) of a colour camera pose, from its exact render."""

    def measure(self, exact_depth_m: np.ndarray, T_world_color: np.ndarray,
                rng: np.random.Generator) -> np.ndarray: ...


class IdealDepth:
    """The exact depth, NaN outside the range limits."""

    def __init__(self, cfg: SensorCfg) -> None:
        self.cfg = cfg

    def measure(self, exact_depth_m: np.ndarray, T_world_color: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        out = exact_depth_m.astype(np.float32).copy()
        with np.errstate(invalid="ignore"):
            out[~((out >= self.cfg.min_range_m) & (out <= self.cfg.max_range_m))] = np.nan
        return out


class GaussianDepth:
    """sigma = a z^2 noise and holes at depth edges (``apply_depth_model``)."""

    def __init__(self, cfg: SensorCfg) -> None:
        self.cfg = cfg

    def measure(self, exact_depth_m: np.ndarray, T_world_color: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        return apply_depth_model(exact_depth_m, self.cfg, rng)


SENSORS: dict[str, Callable[[SensorCfg, Renderer, Intrinsics], DepthSensor]] = {
    "ideal": lambda cfg, renderer, color: IdealDepth(cfg),
    "gaussian": lambda cfg, renderer, color: GaussianDepth(cfg),
    "stereo": lambda cfg, renderer, color: StereoDepth(cfg, renderer, color),
}


def get_depth_sensor(cfg: SensorCfg, renderer: Renderer, color: Intrinsics) -> DepthSensor:
    """The depth sensor model ``cfg.model`` for a scene's renderer and the colour camera."""
    return SENSORS[cfg.model](cfg, renderer, color)


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
