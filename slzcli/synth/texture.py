"""Procedural textures evaluated at world points, so a surface looks the same in every frame.

Value noise (a fixed periodic random table, bicubic lookup) summed over octaves gives the
high-frequency detail ORB needs; each point is textured in the plane its normal faces.
Tiles and stripes add man-made structure.
"""

from __future__ import annotations

import cv2
import numpy as np

from slzcli.synth.scenes import Material

_TABLE_SIZE = 256          # lattice cells of the periodic noise table (repeats every 256 features)
_TABLE_SEED = 20241010     # fixed: the table is part of the look of every scene, not of a run
_OCTAVE_SHIFT = 37.17      # lattice offset between octaves/materials so they do not line up
_GOLDEN = 1.618034         # different offset along v than along u
_REMAP_COLS = 1024
_GRAIN_SHARPNESS = 10.0    # slope of the speck edges: noise 0.5 +- 0.1 spans dark..bright
_TABLE = np.random.default_rng(_TABLE_SEED).random((_TABLE_SIZE, _TABLE_SIZE)).astype(np.float32)


def value_noise(uv: np.ndarray, seed: int) -> np.ndarray:
    """Smooth periodic value noise in [0, 1] at 2-D lattice coordinates ``uv`` (N, 2); bicubic lookup."""
    n = len(uv)
    off = (seed * _OCTAVE_SHIFT) % _TABLE_SIZE
    rows = -(-n // _REMAP_COLS)
    m = np.zeros((rows * _REMAP_COLS, 2), np.float32)      # remap wants a 2-D map of bounded width
    m[:n, 0] = uv[:, 0] + off
    m[:n, 1] = uv[:, 1] + _GOLDEN * off
    m -= _TABLE_SIZE * np.floor(m * (1.0 / _TABLE_SIZE))    # wrap into the table (np.mod is slow)
    out = cv2.remap(_TABLE, m.reshape(rows, _REMAP_COLS, 2), None,  # type: ignore[call-overload]  # stubs: map2 None
                    cv2.INTER_CUBIC, borderMode=cv2.BORDER_WRAP)
    return out.ravel()[:n]


def surface_uv(points_m: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
    """2-D texture coordinates (m): project each point along its normal's dominant axis.

    Horizontal surfaces use (x, y), walls facing x use (y, z), walls facing y use (x, z),
    so every face gets undistorted detail and the mapping is fixed in the world.
    """
    if normals is None:
        return points_m[:, :2]
    axis = np.argmax(np.abs(np.nan_to_num(normals)), axis=1)
    uv = points_m[:, :2].copy()
    sel = axis == 0
    uv[sel] = points_m[sel][:, [1, 2]] + _OCTAVE_SHIFT
    sel = axis == 1
    uv[sel] = points_m[sel][:, [0, 2]] - _OCTAVE_SHIFT
    return uv


def fbm(uv_m: np.ndarray, scale_m: float, octaves: int, seed: int, persistence: float = 0.5) -> np.ndarray:
    """Fractal sum of value noise, coarsest feature ``scale_m``, each octave half the size and
    ``persistence`` times the amplitude of the previous; in [0, 1]."""
    total = np.zeros(len(uv_m), np.float32)
    weight_sum = 0.0
    for k in range(octaves):
        w = persistence ** k
        total += w * value_noise(uv_m * (2 ** k / scale_m), seed + k + 1)
        weight_sum += w
    return np.clip(total / weight_sum, 0.0, 1.0)


def albedo(points_m: np.ndarray, material: Material, seed: int, normals: np.ndarray | None = None) -> np.ndarray:
    """Linear RGB albedo (N, 3) of ``material`` at world points (N, 3) with surface normals."""
    base = np.asarray(material.color, dtype=np.float64)
    n = len(points_m)
    if material.texture == "plain" or n == 0:
        return np.broadcast_to(base, (n, 3)).copy()
    uv = surface_uv(points_m, normals).astype(np.float32)
    detail = fbm(uv, material.scale_m, material.octaves, seed, material.persistence)
    shade = 1.0 + material.contrast * 2.0 * (detail - 0.5)
    col = np.broadcast_to(base, (n, 3)).copy()
    if material.color2 is not None:
        mix = np.clip(2.0 * fbm(uv, 4.0 * material.scale_m, 2, seed + 101) - 0.5, 0.0, 1.0)
        col = col * (1.0 - mix[:, None]) + np.asarray(material.color2)[None, :] * mix[:, None]
    if material.texture == "tiles":
        # grout lines every scale_m along world x and y (floors, paving)
        u = uv / material.scale_m
        u -= np.floor(u)
        line = np.any((u < 0.04) | (u > 0.96), axis=1)
        shade = np.where(line, shade * (1.0 - material.contrast), shade)
        detail = fbm(uv, material.scale_m / 8.0, 2, seed + 202)
        shade = shade * (1.0 + 0.5 * material.contrast * (detail - 0.5))
    elif material.texture == "stripes":
        # wood grain / corrugation along world x
        phase = uv[:, 0] / material.scale_m * 2 * np.pi + 6.0 * fbm(uv, material.scale_m, 2, seed + 303)
        shade = shade * (1.0 + 0.5 * material.contrast * np.sin(phase))
    if material.grain > 0:
        # sharp-edged specks at two sizes: corners for ORB at 10 m and at 2 m altitude
        for k, size in enumerate((material.grain_scale_m, material.grain_scale_m / 4.0)):
            blob = fbm(uv, size, 2, seed + 404 + k)
            shade = shade * (1.0 + material.grain / (k + 1) * np.clip((blob - 0.5) * _GRAIN_SHARPNESS, -1.0, 1.0))
    return col * shade[:, None]
