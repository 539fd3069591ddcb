"""A small analytic RGB-D flight for the SLAM tests and benchmark (until `slz synth` is used).

Textured ground plane with a few boxes, rendered by ray casting (Open3D) from a downward
camera along a known path; colour is a procedural multi-scale texture looked up by world
position, so features are stable across views. An optional uniform tarp gives a
textureless stretch where visual tracking must fail.

Seeds: ``seed`` draws the texture and the boxes (a different scene); ``noise_seed`` adds
per-frame sensor noise (grey levels on the image, a fraction of the range on the depth) so
accuracy limits can be measured over inputs that differ the way two cameras' frames do.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d

from slzcli.types import Frame, Intrinsics

TEX_EXTENT_M = 40.0
TEX_PX = 2048


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = np.zeros((TEX_PX, TEX_PX), np.float32)
    for cells, amp, interp in ((16, 0.5, cv2.INTER_CUBIC), (64, 0.6, cv2.INTER_CUBIC),
                               (256, 1.0, cv2.INTER_NEAREST)):
        noise = rng.random((cells, cells), dtype=np.float32)  # hard-edged cells give crisp corners
        tex += amp * cv2.resize(noise, (TEX_PX, TEX_PX), interpolation=interp)
    tex -= tex.min()
    return tex / tex.max()


def look_down_pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    """T_world_camera for an optical frame looking straight down (z up world)."""
    # optical z -> world -z; optical x -> world x; optical y -> world -y (right-handed), then yaw
    R0 = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = Rz @ R0
    T[:3, 3] = (x, y, z)
    return T


class Scene:
    def __init__(self, seed: int = 0, tarp: tuple[float, float, float, float] | None = None) -> None:
        self.tex = _texture(seed)
        self.tarp = tarp  # (xmin, xmax, ymin, ymax) of a uniform grey patch on the ground
        self.scene = o3d.t.geometry.RaycastingScene()
        ground = o3d.geometry.TriangleMesh.create_box(60, 60, 0.1)
        ground.translate((-30, -30, -0.1))  # in place (the returned reference is typed as a Geometry3D)
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(ground))
        rng = np.random.default_rng(seed + 1)
        for _ in range(6):
            w, d, h = rng.uniform(0.6, 1.5, 3)
            x, y = rng.uniform(-6, 6, 2)
            box = o3d.geometry.TriangleMesh.create_box(w, d, h)
            box.translate((x, y, 0))
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(box))

    def render(self, T_world_camera: np.ndarray, K: Intrinsics, max_depth_m: float = 20.0,
               supersample: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """RGB and depth, rendered at ``supersample`` x resolution and box-filtered (no aliasing)."""
        s = supersample
        hi = Intrinsics(K.fx * s, K.fy * s, K.cx * s + (s - 1) / 2, K.cy * s + (s - 1) / 2, K.width * s, K.height * s)
        rgb, depth = self._render(T_world_camera, hi, max_depth_m)
        if s == 1:
            return rgb, depth
        rgb = cv2.resize(rgb, (K.width, K.height), interpolation=cv2.INTER_AREA)
        depth = cv2.resize(depth, (K.width, K.height), interpolation=cv2.INTER_AREA)  # NaN propagates
        return rgb, depth

    def _render(self, T_world_camera: np.ndarray, K: Intrinsics, max_depth_m: float) -> tuple[np.ndarray, np.ndarray]:
        u, v = np.meshgrid(np.arange(K.width, dtype=np.float32), np.arange(K.height, dtype=np.float32))
        dirs_c = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], -1).reshape(-1, 3)
        R, t = T_world_camera[:3, :3].astype(np.float32), T_world_camera[:3, 3].astype(np.float32)
        rays = np.empty((dirs_c.shape[0], 6), np.float32)
        rays[:, :3] = t
        rays[:, 3:] = dirs_c @ R.T
        ans = self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        th = ans["t_hit"].numpy()
        nrm = ans["primitive_normals"].numpy()
        hit = np.isfinite(th)
        th = np.where(hit, th, 0.0).astype(np.float32)
        p = t + rays[:, 3:] * th[:, None]
        # texture coordinates by the dominant normal axis (planar projection per face)
        ax = np.argmax(np.abs(nrm), axis=1)
        a = np.where(ax == 0, p[:, 1] + 7.0 * p[:, 0], p[:, 0])
        b = np.where(ax == 2, p[:, 1], p[:, 2] + 3.0 * np.where(ax == 0, 0.0, p[:, 1]))
        scale = np.float32(TEX_PX / TEX_EXTENT_M)
        shape = (K.height, K.width)
        grey = cv2.remap(self.tex, np.mod(a * scale, TEX_PX).reshape(shape), np.mod(b * scale, TEX_PX).reshape(shape),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).reshape(-1)
        grey *= 0.55 + 0.45 * np.abs(nrm[:, 2])
        if self.tarp is not None:
            x0, x1, y0, y1 = self.tarp
            on = (p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1) & (ax == 2)
            grey[on] = 0.5
        g8 = np.clip(grey * 255.0, 0, 255)
        rgb = np.stack([g8, 0.9 * g8 + 12.75, 0.8 * g8 + 25.5], -1).clip(0, 255).astype(np.uint8)
        depth = np.where(hit & (th < max_depth_m), th, np.nan).astype(np.float32)  # dirs_c z = 1: t is depth
        return rgb.reshape(K.height, K.width, 3), depth.reshape(K.height, K.width)


def intrinsics(width: int = 320, height: int = 240) -> Intrinsics:
    f = 462.137 * width / 640
    return Intrinsics(f, f, width / 2, height / 2, width, height)


def flight_poses(n: int, kind: str = "line") -> list[np.ndarray]:
    """Known camera path: 'line' = a gentle curved pass at 5-6 m; 'out_back' = out over a tarp and back."""
    s = np.linspace(0, 1, n)
    if kind == "line":
        x = -3 + 6 * s
        y = 1.5 * np.sin(2 * np.pi * s)
        z = 3.5 + 0.5 * s
        yaw = 0.4 * np.sin(np.pi * s)
    elif kind == "out_back":
        x = 9.0 * np.sin(np.pi * s)  # out to x=9 (over the tarp) and back
        y = 0.3 * s
        z = np.full(n, 4.0)
        yaw = 0.1 * s
    else:
        raise ValueError(kind)
    return [look_down_pose(*args) for args in zip(x, y, z, yaw, strict=True)]


def add_noise(rgb: np.ndarray, depth: np.ndarray, rng: np.random.Generator, grey_sigma: float,
              depth_sigma_rel: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian image noise (grey levels, rounded) and depth noise proportional to range."""
    noisy = np.clip(np.rint(rgb + rng.normal(0.0, grey_sigma, rgb.shape)), 0, 255).astype(np.uint8)
    d = (depth * (1.0 + rng.normal(0.0, depth_sigma_rel, depth.shape))).astype(np.float32)
    return noisy, d


def render_flight(n: int = 100, kind: str = "line", width: int = 320, height: int = 240,
                  seed: int = 0, fps: float = 10.0, with_pose: bool = False,
                  supersample: int = 2, noise_seed: int | None = None, grey_sigma: float = 2.0,
                  depth_sigma_rel: float = 0.002) -> tuple[list[Frame], list[np.ndarray]]:
    """Frames (pose withheld unless with_pose) and the true T_world_camera of each.

    ``noise_seed`` None renders noise-free frames; else the noise of ``add_noise`` with that seed.
    """
    tarp = (6.0, 14.0, -6.0, 6.0) if kind == "out_back" else None
    scene = Scene(seed, tarp)
    K = intrinsics(width, height)
    poses = flight_poses(n, kind)
    rng = None if noise_seed is None else np.random.default_rng(noise_seed)
    frames = []
    for i, T in enumerate(poses):
        rgb, depth = scene.render(T, K, supersample=supersample)
        if rng is not None:
            rgb, depth = add_noise(rgb, depth, rng, grey_sigma, depth_sigma_rel)
        frames.append(Frame(i, int(1_700_000_000e9) + int(i * 1e9 / fps), rgb, depth, K,
                            T.copy() if with_pose else None, "analytic"))
    return frames, poses
