"""A level plane with a raised block, seen straight down by a moving camera, with stereo-like depth noise.

The noise is in inverse depth (sigma_z = a z^2) and has the structure the fusion models: a smooth field
fixed to the image (it moves over the ground with the camera, as a projector pattern or the matcher's
own error does) and a smooth field new in every frame (``white``). Both are Gaussian-filtered white
noise of ``corr_px`` pixels. ``cell_noise`` measures what one frame's cell mean then scatters by, so
tests hand the fusion the noise it really gets (the "known noise" of the tests).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from slzcli.synth.flight import R_WORLD_CAMERA_DOWN
from slzcli.types import Intrinsics

INTR = Intrinsics(231.0, 231.0, 159.5, 119.5, 320, 240)


@dataclass(frozen=True)
class Block:
    x0: float
    x1: float
    y0: float
    y1: float
    height_m: float


@dataclass(frozen=True)
class Slab:
    """A box hanging over the ground (a canopy, a roof): x0..x1, y0..y1, from z0 up to z1, open below."""

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float


def slab_depth(T: np.ndarray, slab: Slab, depth: np.ndarray, intr: Intrinsics = INTR) -> np.ndarray:
    """``depth`` with the slab in front of it where a ray enters the slab first (the slab test of a ray and a box)."""
    u = (np.arange(intr.width) - intr.cx) / intr.fx
    v = (np.arange(intr.height) - intr.cy) / intr.fy
    rx, ry = np.meshgrid(u, v)
    d = np.stack([rx, ry, np.ones_like(rx)], -1) @ T[:3, :3].T
    t = T[:3, 3]
    lo = np.full(rx.shape, -np.inf)
    hi = np.full(rx.shape, np.inf)
    for i, (a, b) in enumerate(((slab.x0, slab.x1), (slab.y0, slab.y1), (slab.z0, slab.z1))):
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (a - t[i]) / d[..., i], (b - t[i]) / d[..., i]
        lo = np.maximum(lo, np.minimum(t0, t1))
        hi = np.minimum(hi, np.maximum(t0, t1))
    hit = (lo <= hi) & (lo > 0)
    return np.where(hit & ~(depth < lo), lo, depth).astype(np.float32)


def pose(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R_WORLD_CAMERA_DOWN
    T[:3, 3] = (x, y, z)
    return T


def exact_depth(T: np.ndarray, block: Block | None, intr: Intrinsics = INTR, slope_deg: float = 0.0) -> np.ndarray:
    """Depth of the ground z = x tan(slope_deg) (level by default) and the block's top; NaN where a ray meets
    the block's side."""
    u = (np.arange(intr.width) - intr.cx) / intr.fx
    v = (np.arange(intr.height) - intr.cy) / intr.fy
    rx, ry = np.meshgrid(u, v)
    R, t = T[:3, :3], T[:3, 3]
    d = np.stack([rx, ry, np.ones_like(rx)], -1) @ R.T          # world direction per pixel (camera z = 1)
    g = math.tan(math.radians(slope_deg))
    lam_ground = (t[2] - g * t[0]) / (g * d[..., 0] - d[..., 2])
    depth = lam_ground.copy()
    if block is not None:
        lam_top = (t[2] - block.height_m) / -d[..., 2]

        def inside(lam: np.ndarray) -> np.ndarray:
            x, y = t[0] + lam * d[..., 0], t[1] + lam * d[..., 1]
            return (x >= block.x0) & (x < block.x1) & (y >= block.y0) & (y < block.y1)

        top, ground_in = inside(lam_top), inside(lam_ground)
        depth = np.where(top, lam_top, depth)
        depth[~top & ground_in] = np.nan
    return depth.astype(np.float32)


def _field(rng: np.random.Generator, shape: tuple[int, int], corr_px: float) -> np.ndarray:
    f = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), corr_px)
    return f / np.float32(f.std())


@dataclass
class Stereo:
    """The noise of one camera: ``a`` (1/m) per pixel, image-fixed pattern + per-frame part."""

    a_per_m: float
    white: float
    corr_px: float
    seed: int

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.pattern = _field(self.rng, (INTR.height, INTR.width), self.corr_px)

    def measure(self, depth: np.ndarray) -> np.ndarray:
        e = math.sqrt(1 - self.white) * self.pattern + math.sqrt(self.white) * _field(self.rng, self.pattern.shape,
                                                                                          self.corr_px)
        return (1.0 / (1.0 / depth + self.a_per_m * e)).astype(np.float32)


def cell_noise(stereo: Stereo, cell_px: float, trials: int = 4) -> float:
    """Std (in inverse depth, 1/m) of a cell-sized block mean of the noise: the a of one cell's mean."""
    rng = np.random.default_rng(stereo.seed + 1000)
    b = max(1, round(cell_px))
    vals = []
    for _ in range(trials):
        e = math.sqrt(1 - stereo.white) * _field(rng, stereo.pattern.shape, stereo.corr_px) + \
            math.sqrt(stereo.white) * _field(rng, stereo.pattern.shape, stereo.corr_px)
        h, w = (e.shape[0] // b) * b, (e.shape[1] // b) * b
        vals.append(e[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3)).ravel())
    return stereo.a_per_m * float(np.std(np.concatenate(vals)))


def fly(config_sets: list[str], *, a_per_m: float, white: float, corr_px: float, seed: int, frames: int,
        step_m: float, altitude_m: float = 8.0, block: Block | None = None, start_x: float | None = None,
        region_m: float = 8.0, noise_white: bool = False, slope_deg: float = 0.0,
        slab: Slab | None = None, rough_from_x: float | None = None, rough_factor: float = 0.0,
        estimate_factor: float = 1.0) -> Iterator[tuple[int, Any, Any]]:
    """Fly ``frames`` frames ``step_m`` apart along world x (centred on 0) over the scene; yield, per frame,
    (index, FusedTerrain, FusedMaps of the ``region_m`` square around the origin). ``slope_deg`` tilts the
    ground about the y axis (its height x tan(slope_deg)); the block needs level ground."""
    from slzcli.config import load_config
    from slzcli.fusion.session import FusedTerrain
    from slzcli.scoring import get_scorer
    from slzcli.terrain.noise import DepthNoise

    sets = [f"terrain.fusion.white_fraction={white}", "terrain.fusion.fixed_fraction=0",
            f"terrain.fusion.decorrelation_px={2.0 * corr_px}", *config_sets]
    cfg = load_config(None, sets)
    ft = FusedTerrain(cfg, get_scorer(cfg.scoring, cfg.mask, "fuzzy"))
    stereo = Stereo(a_per_m, white, corr_px, seed)
    a_cell = cell_noise(stereo, ft.params.cell_m * INTR.fx / altitude_m)
    a_told = estimate_factor * a_cell
    noise = DepthNoise.white(a_told, "known") if noise_white else DepthNoise.flat(a_told, "known")
    x0 = -0.5 * step_m * (frames - 1) if start_x is None else start_x
    for i in range(frames):
        T = pose(x0 + step_m * i, 0.0, altitude_m)
        depth = exact_depth(T, block, slope_deg=slope_deg)
        if slab is not None:
            depth = slab_depth(T, slab, depth)
        measured = stereo.measure(depth)
        if rough_from_x is not None:
            measured = ground_noise(T, depth, measured, ft.params.cell_m, stereo.rng, rough_from_x,
                                    rough_factor * a_cell)
        ft.add(measured, INTR, T, noise, 0, i)
        yield i, ft, ft.maps_around(0.0, 0.0, region_m)


def ground_noise(T: np.ndarray, depth: np.ndarray, measured: np.ndarray, cell_m: float, rng: np.random.Generator,
                 from_x: float, a_extra: float, intr: Intrinsics = INTR) -> np.ndarray:
    """``measured`` with an error in inverse depth of std ``a_extra`` (1/m) added where the ground (world x, by the
    exact ``depth``) lies at or beyond ``from_x``: one value per ground cell of ``cell_m`` and frame, so every
    sample of a cell shares it (ground that measures worse than the camera's noise says: a rough or shiny
    patch, relief within a cell)."""
    u = (np.arange(intr.width) - intr.cx) / intr.fx
    v = (np.arange(intr.height) - intr.cy) / intr.fy
    rx, ry = np.meshgrid(u, v)
    d = np.stack([rx, ry, np.ones_like(rx)], -1) @ T[:3, :3].T
    x = T[0, 3] + depth * d[..., 0]
    y = T[1, 3] + depth * d[..., 1]
    ix, iy = np.floor(x / cell_m).astype(np.int64), np.floor(y / cell_m).astype(np.int64)
    x0, y0 = ix.min(), iy.min()
    e = rng.standard_normal((iy.max() - y0 + 1, ix.max() - x0 + 1))[iy - y0, ix - x0]
    inv = 1.0 / measured + np.where(x >= from_x, a_extra * e, 0.0)
    return (1.0 / inv).astype(np.float32)


def cell_centres(reg: Any) -> tuple[np.ndarray, np.ndarray]:
    ny, nx = reg.shape
    xs = reg.origin_m[0] + (np.arange(nx) + 0.5) * reg.cell_m
    ys = reg.origin_m[1] + (np.arange(ny) + 0.5) * reg.cell_m
    return np.meshgrid(xs, ys)
