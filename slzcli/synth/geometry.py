"""Scene -> triangle meshes in the world frame, one per primitive, tagged with an object id.

Object id 0 means "nothing hit"; the ground is id 1; objects follow in scene order.
Primitives standing on the ground (dz = 0) are extended ``embed_m`` below it so that no
gap shows on sloped or undulating ground.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from slzcli.synth.scenes import Primitive, Scene

CYLINDER_SEGMENTS = 24   # facets around cylinders and cones (normals within 7.5 deg of the true ones)
SPHERE_RESOLUTION = 16   # Open3D sphere tessellation


@dataclass(frozen=True, eq=False)
class SceneObject:
    """One object of the ground-truth object table."""

    id: int
    name: str
    kind: str
    landable: bool


@dataclass(frozen=True, eq=False)
class Part:
    """One mesh: its vertices/triangles (world frame), object id, material and landability."""

    vertices: np.ndarray
    triangles: np.ndarray
    object_id: int
    material: str
    landable: bool


@dataclass(frozen=True, eq=False)
class SceneMeshes:
    parts: tuple[Part, ...]
    objects: tuple[SceneObject, ...]
    extent_xy: tuple[float, float, float, float]   # xmin, xmax, ymin, ymax of the ground


def build_meshes(scene: Scene, embed_m: float) -> SceneMeshes:
    """Every primitive (repeats expanded) as a world-frame mesh, plus the object table."""
    g = scene.ground
    parts = [_ground_part(scene)]
    objects = [SceneObject(1, "ground", "ground", True)]
    ids: dict[str, int] = {}
    for prim in scene.primitives:
        for p, suffix in _expand(prim):
            obj_name = p.object + suffix
            if obj_name not in ids:
                ids[obj_name] = len(objects) + 1
                objects.append(SceneObject(ids[obj_name], obj_name, p.kind, p.is_landable))
            v, t = _primitive_mesh(p, scene, embed_m)
            parts.append(Part(v, t, ids[obj_name], p.material, p.is_landable))
    cx, cy = g.center_m
    sx, sy = g.size_m
    return SceneMeshes(tuple(parts), tuple(objects), (cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2))


def raycasting_scene(meshes: SceneMeshes) -> tuple[o3d.t.geometry.RaycastingScene, np.ndarray]:
    """An Open3D raycasting scene and the lookup geometry id -> part index."""
    rc = o3d.t.geometry.RaycastingScene()
    lookup: list[int] = []
    for i, part in enumerate(meshes.parts):
        mesh = o3d.t.geometry.TriangleMesh()
        # open3d's stubs drop Tensor's optional dtype and device (None: from the array, the CPU)
        mesh.vertex.positions = o3d.core.Tensor(part.vertices.astype(np.float32))  # type: ignore[call-overload]
        mesh.triangle.indices = o3d.core.Tensor(part.triangles.astype(np.int32))  # type: ignore[call-overload]
        gid = rc.add_triangles(mesh)
        assert gid == len(lookup)
        lookup.append(i)
    return rc, np.asarray(lookup, dtype=np.int64)


# ----------------------------------------------------------------------------- primitives
def _expand(p: Primitive) -> list[tuple[Primitive, str]]:
    if p.repeat is None:
        return [(p, "")]
    r = p.repeat
    nx, ny = [*r.count, 1, 1][:2]
    px, py = [*r.pitch_m, 0.0, 0.0][:2]
    rng = np.random.default_rng(r.seed)
    out = []
    for j in range(ny):
        for i in range(nx):
            jit = rng.uniform(-r.jitter_m, r.jitter_m, 2) if r.jitter_m > 0 else np.zeros(2)
            yaw = rng.uniform(-r.yaw_jitter_deg, r.yaw_jitter_deg) if r.yaw_jitter_deg > 0 else 0.0
            at = list(p.at_m)
            at[0] += i * px + jit[0]
            at[1] += j * py + jit[1]
            q = dataclasses.replace(p, at_m=tuple(at), yaw_deg=p.yaw_deg + yaw, repeat=None)
            out.append((q, f"_{j * nx + i}"))
    return out


def _ground_part(scene: Scene) -> Part:
    g = scene.ground
    cx, cy = g.center_m
    sx, sy = g.size_m
    nx = max(2, int(np.ceil(sx / g.mesh_step_m)) + 1)
    ny = max(2, int(np.ceil(sy / g.mesh_step_m)) + 1)
    xs = np.linspace(cx - sx / 2, cx + sx / 2, nx)
    ys = np.linspace(cy - sy / 2, cy + sy / 2, ny)
    X, Y = np.meshgrid(xs, ys)
    Z = g.height(X, Y)
    v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])   # counter-clockwise from above
    return Part(v, t, 1, g.material, True)


def _legacy(mesh: o3d.geometry.TriangleMesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)


def _box(sx: float, sy: float, sz: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box with its base centred on the origin."""
    v, t = _legacy(o3d.geometry.TriangleMesh.create_box(sx, sy, sz))
    return v - np.array([sx / 2, sy / 2, 0.0]), t


def _wedge(run: float, width: float, rise: float) -> tuple[np.ndarray, np.ndarray]:
    """Ramp solid: base run x width centred on the origin, top rising to ``rise`` at +x."""
    x0, x1, y0, y1 = -run / 2, run / 2, -width / 2, width / 2
    v = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x1, y0, rise], [x1, y1, rise]], float)
    t = np.array([[0, 2, 1], [0, 3, 2],          # bottom (facing down)
                  [0, 1, 4], [3, 5, 2],          # sides
                  [1, 2, 5], [1, 5, 4],          # high end (facing +x)
                  [0, 4, 5], [0, 5, 3]])         # sloped top (facing up)
    return v, t


def _primitive_mesh(p: Primitive, scene: Scene, embed_m: float) -> tuple[np.ndarray, np.ndarray]:
    x, y = p.at_m[0], p.at_m[1]
    dz = p.at_m[2] if len(p.at_m) > 2 else 0.0
    base = float(scene.ground.height(np.array(x), np.array(y))) + dz
    sink = embed_m if dz == 0 else 0.0
    if p.kind == "box":
        v, t = _box(p.size_m[0], p.size_m[1], p.size_m[2] + sink)
        v[:, 2] -= sink
    elif p.kind == "cylinder":
        v, t = _legacy(o3d.geometry.TriangleMesh.create_cylinder(p.radius_m, p.height_m + sink,
                                                                  resolution=CYLINDER_SEGMENTS))
        v[:, 2] += (p.height_m + sink) / 2 - sink
    elif p.kind == "cone":
        v, t = _legacy(o3d.geometry.TriangleMesh.create_cone(p.radius_m, p.height_m, resolution=CYLINDER_SEGMENTS))
    elif p.kind == "sphere":
        v, t = _legacy(o3d.geometry.TriangleMesh.create_sphere(p.radius_m, resolution=SPHERE_RESOLUTION))
        v[:, 2] += p.radius_m
    elif p.kind == "ramp":
        run, width = p.size_m[0], p.size_m[1]
        v, t = _wedge(run, width, run * np.tan(np.deg2rad(p.angle_deg)))
    else:  # stairs: one box per step, each from the ground up, ascending towards +x
        vs, ts, n = [], [], 0
        for i in range(p.steps):
            bv, bt = _box(p.run_m, p.width_m, (i + 1) * p.rise_m + sink)
            bv[:, 0] += (i + 0.5) * p.run_m - p.steps * p.run_m / 2
            bv[:, 2] -= sink
            vs.append(bv)
            ts.append(bt + n)
            n += len(bv)
        v, t = np.concatenate(vs), np.concatenate(ts)
    yaw = np.deg2rad(p.yaw_deg)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return v @ R.T + np.array([x, y, base]), t
