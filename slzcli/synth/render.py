"""Ray-cast RGB-D frames of a scene with Open3D: exact depth, object ids, normals, shaded colour.

One ray per pixel centre of a pinhole camera; the ray direction in the optical frame is
``((u - cx) / fx, (v - cy) / fy, 1)``, so the hit distance in direction units is the
depth z directly. Colour = material albedo x (ambient + direct sun x Lambert x not in
shadow), then the scene's illumination gain and contrast. The sensor model
(``sensor.py``) is applied separately so the exact geometry stays available for tests
and ground truth.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from slzcli.config import LightCfg
from slzcli.synth.geometry import SceneMeshes, raycasting_scene
from slzcli.synth.scenes import Scene
from slzcli.synth.texture import albedo
from slzcli.types import Intrinsics


@dataclass(frozen=True, eq=False)
class Rendered:
    """One exact (noise-free) render. Arrays are HxW(x3); ``hit`` is False where no surface."""

    rgb_linear: np.ndarray       # float32 HxWx3 in [0, 1] before illumination/noise
    rgb: np.ndarray              # float32 HxWx3 in [0, 1] after illumination (before sensor noise)
    depth_m: np.ndarray          # float32 HxW, z in the optical frame, NaN where nothing hit
    object_id: np.ndarray        # uint16 HxW, 0 = nothing
    normal_world: np.ndarray     # float32 HxWx3, facing the camera, NaN where nothing hit
    point_world: np.ndarray      # float64 HxWx3, NaN where nothing hit
    hit: np.ndarray              # bool HxW


@dataclass(frozen=True, eq=False)
class Surface:
    """Flat (H*W) per-pixel lookup of one camera: geometry, material albedo and light, before any sensor."""

    depth_m: np.ndarray          # float64 (N,), z in the optical frame, NaN where nothing hit
    point_world: np.ndarray      # float64 (N, 3), NaN where nothing hit
    normal_world: np.ndarray     # float64 (N, 3), facing the camera, NaN where nothing hit
    hit: np.ndarray              # bool (N,)
    object_id: np.ndarray        # uint16 (N,), 0 = nothing
    albedo: np.ndarray           # float64 (N, 3) linear albedo; the sky colour where nothing hit
    light: np.ndarray            # float64 (N,) ambient + direct sun x Lambert x unshadowed (1 = full sun); 1 on sky


class Renderer:
    """Holds the raycasting scene of one ``Scene`` so many frames reuse it."""

    def __init__(self, scene: Scene, meshes: SceneMeshes, light: LightCfg) -> None:
        self.scene = scene
        self.meshes = meshes
        self.light = light
        self.rc, self.part_of_geometry = raycasting_scene(meshes)
        self.part_object = np.array([p.object_id for p in meshes.parts], dtype=np.uint16)
        names = sorted({p.material for p in meshes.parts})
        self.material_names = names
        self.part_material = np.array([names.index(p.material) for p in meshes.parts], dtype=np.int64)
        sun = np.asarray(light.sun_dir, dtype=np.float64)
        self.sun = sun / np.linalg.norm(sun)
        self._rays: dict[tuple[float, ...], np.ndarray] = {}

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
        """Cast rays (N, 3) + (N, 3); returns t, part index (-1 = none), triangle normals."""
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        ans = self.rc.cast_rays(o3d.core.Tensor(rays))  # type: ignore[call-overload]  # stubs lack the defaults
        t = ans["t_hit"].numpy().astype(np.float64)
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        part = np.full(len(t), -1, dtype=np.int64)
        part[hit] = self.part_of_geometry[gid[hit]]
        return {"t": t, "part": part, "hit": hit, "normal": ans["primitive_normals"].numpy().astype(np.float64)}

    def render(self, T_world_camera: np.ndarray, intr: Intrinsics) -> Rendered:
        """Render one exact frame from pose ``T_world_camera`` with pinhole ``intr``."""
        H, W = intr.height, intr.width
        s = self.surface(T_world_camera, intr)
        col = s.albedo.copy()
        col[s.hit] *= s.light[s.hit][:, None]
        lin = np.clip(col, 0.0, 1.0)
        ill = self.scene.illumination
        out = np.clip(ill.gain * (0.5 + ill.contrast * (lin - 0.5)), 0.0, 1.0)
        return Rendered(rgb_linear=lin.reshape(H, W, 3).astype(np.float32),
                        rgb=out.reshape(H, W, 3).astype(np.float32),
                        depth_m=s.depth_m.reshape(H, W).astype(np.float32),
                        object_id=s.object_id.reshape(H, W),
                        normal_world=s.normal_world.reshape(H, W, 3).astype(np.float32),
                        point_world=s.point_world.reshape(H, W, 3), hit=s.hit.reshape(H, W))

    def surface(self, T_world_camera: np.ndarray, intr: Intrinsics) -> Surface:
        """What each pixel ray of a camera hits, with the material albedo and the sun/ambient light there.

        Shared by the colour render and the infrared pair of the stereo sensor model, so both
        see the same geometry, textures and shadows.
        """
        d_cam = self._camera_rays(intr)
        R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
        d_world = np.einsum("ij,nj->ni", R, d_cam)   # not BLAS: avoids thread fights with Open3D
        origins = np.broadcast_to(t, d_world.shape)
        ans = self.cast(origins, d_world)
        hit, part = ans["hit"], ans["part"]
        depth = np.where(hit, ans["t"], np.nan)
        points = origins + d_world * np.where(hit, ans["t"], np.nan)[:, None]
        n = ans["normal"]
        flip = np.sum(n * d_world, axis=1) > 0
        n[flip] *= -1.0
        n[~hit] = np.nan

        obj = np.zeros(len(depth), dtype=np.uint16)
        obj[hit] = self.part_object[part[hit]]
        col = np.empty((len(depth), 3))
        col[~hit] = self.light.sky_rgb
        mat_idx = np.full(len(depth), -1, dtype=np.int64)
        mat_idx[hit] = self.part_material[part[hit]]
        # group pixels by material once (a sort) instead of one full-image mask per material
        order = np.argsort(mat_idx, kind="stable")
        bounds = np.searchsorted(mat_idx[order], np.arange(-1, len(self.material_names) + 1))
        p_sorted, n_sorted = points[order], n[order]
        for k, name in enumerate(self.material_names):
            a, b = bounds[k + 1], bounds[k + 2]
            if b > a:
                col[order[a:b]] = albedo(p_sorted[a:b], self.scene.materials[name],
                                         zlib.crc32(name.encode()) % 1000, n_sorted[a:b])
        lit = self._direct_light(points, n, hit)
        light = np.ones(len(depth))
        light[hit] = self.light.ambient + (1.0 - self.light.ambient) * lit[hit]
        return Surface(depth_m=depth, point_world=points, normal_world=n, hit=hit, object_id=obj,
                       albedo=col, light=light)

    def _camera_rays(self, intr: Intrinsics) -> np.ndarray:
        """Optical-frame ray directions (H*W, 3) with z = 1, cached per camera model (colour, infrared)."""
        key = (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height)
        if key not in self._rays:
            u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
            self._rays[key] = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)],
                                       -1).reshape(-1, 3)
        return self._rays[key]

    def _direct_light(self, points: np.ndarray, normals: np.ndarray, hit: np.ndarray) -> np.ndarray:
        """Lambert term of the sun, zero in shadow (one occlusion ray per lit pixel)."""
        lam = np.zeros(len(points))
        lam[hit] = np.clip(np.einsum("nj,j->n", normals[hit], self.sun), 0.0, 1.0)
        if self.light.shadows:
            idx = np.flatnonzero(lam > 0)
            if len(idx):
                o = points[idx] + normals[idx] * self.light.shadow_bias_m
                rays = np.concatenate([o, np.broadcast_to(self.sun, o.shape)], axis=1).astype(np.float32)
                tensor = o3d.core.Tensor(rays)  # type: ignore[call-overload]  # stubs lack the defaults
                occluded = self.rc.test_occlusions(tensor).numpy().astype(bool)
                lam[idx[occluded]] = 0.0
        return lam
