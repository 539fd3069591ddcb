"""Terrain maps (METHOD 2.1, 2.3): analytic scenes, Open3D as the reference, real RealSense frames."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slzcli.config import Mount, TerrainCfg, load_config
from slzcli.errors import ConfigError, DatasetError
from slzcli.terrain import geometry as geo
from slzcli.terrain import maps as tm
from slzcli.types import Frame, Intrinsics, TerrainMaps

CONFIG = load_config()
TERRAIN = CONFIG.terrain
CAM = CONFIG.camera
K = Intrinsics(CAM.fx, CAM.fy, CAM.cx, CAM.cy, CAM.width, CAM.height)
DOWN = np.array([0.0, 0.0, -1.0])          # world up for a camera looking straight down
RX, RY = geo.pixel_rays(K)
INNER = (slice(20, -20), slice(20, -20))   # away from the image border
MPL = 0.01                                 # m per Canny level where a test sets the depth scaling itself


# ----------------------------------------------------------------------------- scenes
def plane_depth(normal: np.ndarray, dist_m: float, intr: Intrinsics = K) -> np.ndarray:
    """Depth of the plane n . P = d (camera frame) at every pixel; NaN where the ray misses."""
    rx, ry = geo.pixel_rays(intr)
    den = normal[0] * rx + normal[1] * ry + normal[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = dist_m / den
    return np.where(z > 0, z, np.nan).astype(np.float32)


def ramp_normal(slope_deg: float) -> np.ndarray:
    """Plane normal (pointing away from a nadir camera) of ground sloping by slope_deg about x."""
    a = math.radians(slope_deg)
    return np.array([0.0, math.sin(a), math.cos(a)])


def box_scene(ground_m: float = 10.0, box: tuple[float, ...] = (-1.5, 1.5, -1.0, 1.0), height_m: float = 1.5,
              offset: tuple[float, float] = (1.5, 0.0)) -> np.ndarray:
    """Nadir camera over level ground with an axis-aligned box (x0, x1, y0, y1 in metres, camera frame).

    Ray-cast analytically (slab test) so the box's vertical sides are visible off-centre.
    """
    x0, x1, y0, y1 = box[0] + offset[0], box[1] + offset[0], box[2] + offset[1], box[3] + offset[1]
    z0, z1 = ground_m - height_m, ground_m
    d = np.stack(np.broadcast_arrays(RX, RY, np.ones_like(RX)), axis=-1).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = np.stack([x0 / d[..., 0], y0 / d[..., 1], z0 / d[..., 2]], -1)
        t_hi = np.stack([x1 / d[..., 0], y1 / d[..., 1], z1 / d[..., 2]], -1)
    t_near = np.nanmax(np.minimum(t_lo, t_hi), axis=-1)
    t_far = np.nanmin(np.maximum(t_lo, t_hi), axis=-1)
    hit = (t_near <= t_far) & (t_far > 0)
    return np.where(hit, t_near, ground_m).astype(np.float32)   # ray direction has z = 1: t = depth


def terrain(**sections: dict) -> TerrainCfg:
    """TERRAIN with some keys replaced, e.g. terrain(steepness={"normal_px": 9})."""
    out = TERRAIN
    for name, values in sections.items():
        out = dataclasses.replace(out, **{name: dataclasses.replace(getattr(out, name), **values)})
    return out


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


# ----------------------------------------------------------------------------- geometry
def test_back_project_is_eq1_with_nan_holes() -> None:
    depth = np.full((K.height, K.width), 4.0, np.float32)
    depth[10, 20] = np.nan
    depth[11, 20] = 0.0
    pts = geo.back_project(depth, K)
    assert pts.shape == (K.height, K.width, 3) and pts.dtype == np.float32
    v, u = 300, 500
    np.testing.assert_allclose(pts[v, u], [(u - K.cx) * 4 / K.fx, (v - K.cy) * 4 / K.fy, 4.0], rtol=1e-6)
    assert np.isnan(pts[10, 20]).all() and np.isnan(pts[11, 20]).all()


@pytest.mark.parametrize("slope_deg", [0.0, 30.0, 60.0])
def test_normals_are_exact_on_planes(slope_deg: float) -> None:
    n_true = ramp_normal(slope_deg)
    normals = geo.image_normals(plane_depth(n_true, 10.0), K, 5, 0.5)
    ang = angle_deg(normals[INNER], -n_true)
    assert np.nanmax(ang) < 0.05
    # oriented towards the camera: n . P < 0
    pts = geo.back_project(plane_depth(n_true, 10.0), K)
    assert np.nanmax(np.sum(normals * pts, axis=-1)[INNER]) < 0


@pytest.mark.parametrize("slope_deg", [0.0, 30.0])
def test_normals_agree_with_open3d_on_noisy_surfaces(slope_deg: float) -> None:
    """Same neighbourhood size (k x k window vs k*k nearest neighbours), 2 mm noise at 3 m."""
    rng = np.random.default_rng(1)
    depth = plane_depth(ramp_normal(slope_deg), 3.0)
    depth = (depth + rng.normal(0, 0.002, depth.shape)).astype(np.float32)
    k = TERRAIN.steepness.normal_px
    crop = (slice(180, 300), slice(260, 380))
    mine = geo.image_normals(depth, K, k, 0.5)[crop].reshape(-1, 3)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
        geo.back_project(depth, K)[crop].reshape(-1, 3).astype(np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k * k))
    ref = np.asarray(pc.normals)
    diff = angle_deg(mine, ref)
    assert np.median(diff) < 2.0 and np.percentile(diff, 90) < 3.0
    truth = -ramp_normal(slope_deg)
    assert abs(np.median(angle_deg(mine, truth)) - np.median(angle_deg(ref, truth))) < 0.5


def test_normals_ignore_holes_and_need_enough_support() -> None:
    depth = plane_depth(ramp_normal(20.0), 5.0)
    depth[200:260, 300:360] = np.nan
    depth[100, 100] = np.nan                       # a single missing pixel: neighbours still fine
    normals = geo.image_normals(depth, K, 5, 0.5)
    ok = np.isfinite(normals[..., 0])
    assert not ok[200:260, 300:360].any()
    ang = angle_deg(normals[INNER][ok[INNER]], -ramp_normal(20.0))
    assert ang.max() < 0.05                        # partial windows (hole borders) fitted exactly
    assert ok[99, 100] and ok[101, 101]
    isolated = np.full_like(depth, np.nan)
    isolated[50:52, 50:52] = 5.0                   # 4 pixels: less than half of a 5x5 window
    assert not np.isfinite(geo.image_normals(isolated, K, 5, 0.5)).any()


def test_eigvalsh3_matches_numpy() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(size=(500, 3, 3))
    a = a @ np.swapaxes(a, 1, 2)
    a[:5] = np.diag([1.0, 1.0, 1.0])               # repeated eigenvalues
    mine = geo.eigvalsh3(a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 1, 1], a[:, 1, 2], a[:, 2, 2])
    np.testing.assert_allclose(mine, np.linalg.eigvalsh(a), atol=1e-9 * np.abs(a).max())


def test_patch_curvature_small_on_planes_large_on_steps_at_any_altitude() -> None:
    for altitude in (10.0, 100.0):                 # float32 E[xx]-E[x]^2 would lose it at 100 m
        pca = geo.patch_pca(plane_depth(ramp_normal(25.0), altitude), K, 0.5, 160, 6, DOWN)
        assert np.nanmax(pca.curvature_work) < 1e-6
        eig = pca.eigenvalues[np.isfinite(pca.eigenvalues[..., 0])]
        assert (np.diff(eig, axis=-1) >= 0).all()
    for step_m in (0.3, 1.5):
        depth = box_scene(height_m=step_m)
        curv = geo.patch_pca(depth, K, 0.5, 160, 6, DOWN).curvature
        edge = np.abs(cv2.Laplacian(depth, cv2.CV_32F)) > 0.1
        assert np.nanmedian(curv[edge]) > 0.01, step_m       # patches straddling the step
        assert np.nanmax(curv[400:470, 20:120]) < 1e-4, step_m  # ground far from the box


def test_patch_curvature_agrees_with_open3d_covariances() -> None:
    """Reference: Open3D radius-0.5 m covariances (every 2nd pixel's point), at sample pixels.

    A 0.3 m step, lower than the radius, so a 3-D ball at its edge holds both levels. (At a
    step taller than the radius the ball holds one level and Open3D calls the edge flat; the
    image window still straddles it and flags it: the conservative side.)
    """
    depth = box_scene(height_m=0.3)
    pca = geo.patch_pca(depth, K, 0.5, 160, 6, DOWN)
    pts = geo.back_project(depth, K)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[::2, ::2].reshape(-1, 3).astype(np.float64)))
    tree = o3d.geometry.KDTreeFlann(pc)
    cloud = np.asarray(pc.points)

    def reference(v: int, u: int) -> float:
        _, idx, _ = tree.search_radius_vector_3d(pts[v, u].astype(np.float64), 0.5)
        ev = np.linalg.eigvalsh(np.cov(cloud[np.asarray(idx)].T))
        return float(ev[0] / ev.sum())

    for v, u in [(450, 60), (60, 60), (240, 120), (240, 560), (140, 420)]:     # ground / box top
        assert reference(v, u) < 1e-3 and pca.curvature[v, u] < 1e-3, (v, u)
    for v, u in [(240, 320), (192, 320), (274, 319), (288, 326)]:              # on the step edge
        ref, mine = reference(v, u), float(pca.curvature[v, u])
        assert ref > 0.02 and 0.3 < mine / ref < 2.0, (v, u, mine, ref)


# ----------------------------------------------------------------------------- maps: analytic
def test_level_plane_scores_high_everywhere_away_from_borders() -> None:
    maps = tm.compute_maps(plane_depth(np.array([0, 0, 1.0]), 10.0), K, DOWN, TERRAIN)
    assert isinstance(maps, TerrainMaps)
    for name, m in maps.as_dict().items():
        assert m.dtype == np.float32 and m.shape == (K.height, K.width), name
        assert m.min() >= 0 and m.max() <= 1, name
        assert m[INNER].min() > 0.99, name
    assert np.nanmax(maps.slope_deg) < 0.1
    assert maps.valid.all()


def test_ramp_30_deg_raw_slope_and_absolute_steepness() -> None:
    maps = tm.compute_maps(plane_depth(ramp_normal(30.0), 10.0), K, DOWN, TERRAIN)
    np.testing.assert_allclose(maps.slope_deg[INNER], 30.0, atol=0.05)
    expected = math.exp(-(30.0 / load_config().uav.max_slope_deg) ** 2)
    np.testing.assert_allclose(maps.steepness[INNER], expected, atol=1e-3)
    assert maps.inclination[INNER].min() > 0.99       # a ramp is still a plane


def test_steepness_takes_psi_ref_from_uav_max_slope_deg() -> None:
    """The map's psi_ref is the UAV's slope limit carried by the working scale (no key of its own)."""
    depth = plane_depth(ramp_normal(30.0), 10.0)
    uav = load_config(overrides=["uav.max_slope_deg=20"]).uav
    maps = tm.compute_maps(depth, K, DOWN, TERRAIN, tm.noise_free_working(depth, K, TERRAIN, uav))
    np.testing.assert_allclose(maps.steepness[INNER], math.exp(-(30.0 / 20.0) ** 2), atol=1e-3)


def test_steepness_modes() -> None:
    psi = np.radians(np.array([[0.0, 10.0], [30.0, np.nan]], np.float32))
    frame = tm.steepness_map(psi, terrain(steepness={"normalise": "frame"}).steepness, 15.0)
    raw = np.exp(-psi[np.isfinite(psi)] ** 2)
    expected = (raw - raw.min()) / (raw.max() - raw.min())
    np.testing.assert_allclose(frame[np.isfinite(psi)], expected, rtol=1e-5)
    assert frame[1, 1] == 0
    absolute = tm.steepness_map(psi, TERRAIN.steepness, load_config().uav.max_slope_deg)
    assert absolute[0, 1] == pytest.approx(math.exp(-(10 / 15) ** 2), rel=1e-5)


def test_box_on_plane_edges_are_bad() -> None:
    """A 3 m box (x 1..4 m, y -1..1 m) on ground 10 m below a nadir camera; its -x side is visible."""
    depth = box_scene(box=(1.0, 4.0, -1.0, 1.0), height_m=3.0, offset=(0.0, 0.0))
    maps = tm.compute_maps(depth, K, DOWN, TERRAIN)  # noise-free scene: no working scale, no noise removed
    step = np.abs(cv2.Laplacian(depth, cv2.CV_32F)) > 0.5        # the occluding outline (3 m steps)
    near = cv2.dilate(step.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert step.sum() > 300
    assert maps.flatness[near].mean() < 0.1
    # the occluding outline is rough; the visible -x side (columns 366..386) is a plane, steepness's business
    outline = step.copy()
    outline[:, 360:392] = False
    assert outline.sum() > 200 and maps.depth_variance[outline].max() < 0.05
    # farther from the box than the clearance (on the ground) flatness saturates at 1
    box_px = (depth < 9.99).astype(np.uint8)
    ground_px = TERRAIN.flatness.clearance_m * K.fx / 10.0
    far = cv2.distanceTransform(1 - box_px, cv2.DIST_L2, 5) > ground_px + 3
    far[:3] = far[-3:] = False
    far[:, :3] = far[:, -3:] = False
    assert far.sum() > 100000 and maps.flatness[far].min() > 0.99
    assert maps.depth_variance[far].min() > 0.99
    # the box top is level and planar
    top = (slice(200, 280), slice(420, 560))
    assert maps.steepness[top].min() > 0.99 and maps.slope_deg[top].max() < 0.5
    # the visible -x side (x = 1 m, depth 7..10 m -> columns 366..386) is vertical
    side = (slice(200, 280), slice(371, 382))
    assert np.isfinite(maps.slope_deg[side]).all()
    assert maps.slope_deg[side].min() > 85 and maps.steepness[side].max() < 0.01


def test_flatness_absolute_is_ground_metres_to_the_edge() -> None:
    depth = np.full((K.height, K.width), 5.0, np.float32)
    depth[:, 400:] = 4.0                                             # a 1 m step at column 400
    flat = tm.flatness_map(depth, K, TERRAIN.flatness, MPL)
    edges = tm.depth_edges(depth, TERRAIN.flatness, MPL)
    cols = np.nonzero(edges[240])[0]
    assert cols.min() >= 398 and cols.max() <= 401
    u = 300
    d_px = cols.min() - u
    expected = min(d_px * 5.0 / K.fx / TERRAIN.flatness.clearance_m, 1.0)
    assert flat[240, u] == pytest.approx(expected, abs=0.02)
    frame = tm.flatness_map(depth, K, terrain(flatness={"normalise": "frame"}).flatness, MPL)
    assert frame.max() == pytest.approx(1.0) and frame[edges].max() == 0


def test_canny_on_derivatives_equals_canny_on_the_8bit_image() -> None:
    """The fixed-scale depth -> Canny realisation matches cv2.Canny on the 8-bit image (in range)."""
    rng = np.random.default_rng(3)
    grey = cv2.GaussianBlur(rng.integers(0, 256, (120, 160)).astype(np.uint8), (7, 7), 0)
    grey[40:80, 60:100] = 250
    mpl = 0.01                                                         # m per grey level
    cfg = dataclasses.replace(TERRAIN.flatness, blur_px=1, detrend_px=0)   # the paper's Canny on depth
    ours = tm.depth_edges(grey.astype(np.float32) * np.float32(mpl) + np.float32(1.0), cfg, mpl)
    ref = cv2.Canny(grey, cfg.canny_low, cfg.canny_high) > 0
    assert ours.sum() > 100
    assert (ours != ref).sum() <= 0.005 * ref.sum()


def test_depth_variance_keeps_millimetres_at_altitude() -> None:
    """The residual about each 3x3 window's plane (in inverse depth, metres out), against a direct
    least-squares reference: float64 sums keep a 3 mm residual at 30 m."""
    rng = np.random.default_rng(4)
    depth = (30.0 + rng.normal(0, 0.003, (60, 80))).astype(np.float32)
    cfg = TERRAIN.depth_variance                                       # no noise removed
    got = tm.depth_variance_map(depth, cfg)
    w = np.lib.stride_tricks.sliding_window_view(1.0 / depth.astype(np.float64), (3, 3)).reshape(58, 78, 9)
    vv, uu = np.mgrid[-1:2, -1:2]
    X = np.stack([np.ones(9), uu.ravel(), vv.ravel()], axis=1)
    resid = w - w @ (X @ np.linalg.pinv(X)).T                          # (I - H) w per window
    ref = np.exp(-np.sqrt((resid ** 2).mean(axis=-1)) * depth[1:-1, 1:-1].astype(np.float64) ** 2 / cfg.s0_m)
    np.testing.assert_allclose(got[1:-1, 1:-1], ref, atol=2e-4)
    tilted = (30.0 + 0.05 * np.arange(80)[None, :] + 0.0 * depth).astype(np.float32)   # a ramp is not rough
    assert tm.depth_variance_map(tilted, cfg)[1:-1, 1:-1].min() > 0.99


def test_holes_do_not_bleed_beyond_the_window() -> None:
    """A hole across the box's edge changes nothing beyond each map's reach (and does change the
    wide-reach maps near it, so the comparison is not vacuous)."""
    base = box_scene(height_m=0.3)
    holed = base.copy()
    holed[220:260, 300:340] = np.nan              # straddles the box's x = 0 edge (column 320)
    a = tm.compute_maps(base, K, DOWN, TERRAIN).as_dict()
    b = tm.compute_maps(holed, K, DOWN, TERRAIN).as_dict()
    hole = np.isnan(holed).astype(np.uint8)
    dist = cv2.distanceTransform(1 - hole, cv2.DIST_L2, 5)
    pca = geo.patch_pca(base, K, 0.5, 160, 6, DOWN)
    scale = K.width / 160
    reach = {                                     # how far each map looks, in pixels
        "depth_variance": TERRAIN.depth_variance.kernel_px,
        "steepness": TERRAIN.steepness.normal_px,
        "flatness": TERRAIN.flatness.clearance_m * K.fx / 9.7 + 3,    # holes are edges, by design
        "inclination": (pca.window_half_px.max() + 3) * scale * math.sqrt(2),
    }
    for name, r in reach.items():
        assert (b[name][hole > 0] == 0).all(), name
        if name in ("flatness", "inclination"):   # wide reach: the hole must matter nearby
            near = (dist > 0) & (dist <= r)
            assert np.abs(b[name][near] - a[name][near]).max() > 1e-3, name
        far = dist > r
        assert far.sum() > 10000, name
        np.testing.assert_allclose(b[name][far], a[name][far], atol=1e-4, err_msg=name)


def test_invalid_pixels_score_zero_and_frame_mode_is_min_max() -> None:
    depth = box_scene()
    depth[::7, ::5] = np.nan
    cfg = terrain(**{s: {"normalise": "frame"} for s in ("depth_variance", "flatness", "inclination", "steepness")})
    for c in (TERRAIN, cfg):
        maps = tm.compute_maps(depth, K, DOWN, c)
        for name, m in maps.as_dict().items():
            assert (m[~maps.valid] == 0).all(), name
            assert m.min() >= 0 and m.max() <= 1, name
    maps = tm.compute_maps(depth, K, DOWN, cfg)
    for name in ("depth_variance", "flatness", "steepness"):
        assert maps.as_dict()[name].max() == pytest.approx(1.0), name


def test_normalise_frame_constant_and_empty() -> None:
    v = np.full((3, 3), 0.4, np.float32)
    assert (tm.normalise_frame(v, np.ones((3, 3), bool)) == 1).all()
    assert (tm.normalise_frame(v, np.zeros((3, 3), bool)) == 0).all()


# ----------------------------------------------------------------------------- gravity
def pitched_pose(pitch_deg: float, height_m: float = 10.0) -> np.ndarray:
    """T_world_camera of a camera at height_m, looking down and tilted forward by pitch_deg."""
    p = math.radians(pitch_deg)
    r_x = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ r_x
    T[2, 3] = height_m
    return T


def test_gravity_from_mount_and_pose_agree() -> None:
    np.testing.assert_allclose(tm.gravity_up_in_camera(None, Mount(0.0, 0.0)), DOWN, atol=1e-12)
    for pitch, roll in [(30.0, 0.0), (64.4, 19.0), (-20.0, -10.0)]:
        up = tm.gravity_up_in_camera(None, Mount(pitch, roll))
        assert np.linalg.norm(up) == pytest.approx(1.0)
        assert tm.mount_from_up(up) == pytest.approx((pitch, roll))
    np.testing.assert_allclose(tm.gravity_up_in_camera(pitched_pose(30.0), Mount(0.0, 0.0)),
                               tm.gravity_up_in_camera(None, Mount(30.0, 0.0)), atol=1e-12)
    # positive roll tilts the view to the image right: up gets a +x component
    assert tm.gravity_up_in_camera(None, Mount(0.0, 10.0))[0] > 0
    with pytest.raises(DatasetError, match="T_world_camera"):
        tm.gravity_up_in_camera(np.eye(3), Mount(0.0, 0.0))


def test_pitched_camera_over_level_ground_needs_the_right_gravity() -> None:
    pose = pitched_pose(30.0)
    up = tm.gravity_up_in_camera(pose, Mount(0.0, 0.0))
    depth = plane_depth(-up, 10.0)          # ground: up . P = -10 m, i.e. (-up) . P = 10
    frame = Frame(index=0, stamp_ns=0, rgb=np.zeros((K.height, K.width, 3), np.uint8), depth_m=depth,
                  intrinsics=K, T_world_camera=pose)
    with_pose = tm.frame_maps(frame, tm.MapParams.of(CONFIG))
    assert with_pose.steepness[INNER].min() > 0.99
    mounted = dataclasses.replace(CONFIG, camera=dataclasses.replace(CAM, mount=Mount(30.0, 0.0)))
    no_pose = dataclasses.replace(frame, T_world_camera=None)
    assert tm.frame_maps(no_pose, tm.MapParams.of(mounted)).steepness[INNER].min() > 0.99
    wrong = tm.frame_maps(no_pose, tm.MapParams.of(CONFIG))                        # assumes straight down
    np.testing.assert_allclose(wrong.slope_deg[INNER], 30.0, atol=0.05)
    assert wrong.steepness[INNER].max() < 0.02


# ----------------------------------------------------------------------------- errors and config
def test_bad_inputs_raise_slz_errors() -> None:
    with pytest.raises(DatasetError, match="2-D"):
        tm.compute_maps(np.zeros((4, 4, 3), np.float32), K, DOWN, TERRAIN)
    with pytest.raises(DatasetError, match="gravity"):
        tm.compute_maps(np.ones((8, 8), np.float32), K, np.zeros(3), TERRAIN)
    with pytest.raises(DatasetError, match="intrinsics"):
        tm.compute_maps(np.ones((8, 8), np.float32), None, DOWN, TERRAIN)


def test_terrain_config_keys_are_checked() -> None:
    cfg = load_config(overrides=["terrain.steepness.min_valid_fraction=0.8"])
    assert cfg.terrain.steepness.min_valid_fraction == 0.8
    with pytest.raises(ConfigError, match=re.escape("terrain.depth_variance.min_valid_fraction")):
        load_config(overrides=["terrain.depth_variance.min_valid_fraction=0"])
    with pytest.raises(ConfigError, match=re.escape("terrain.steepness.normalise")):
        load_config(overrides=["terrain.steepness.normalise=relative"])


def test_depth_of_another_size_uses_scaled_intrinsics() -> None:
    small = plane_depth(ramp_normal(30.0), 10.0, K.scaled(320, 240))
    maps = tm.compute_maps(small, K, DOWN, TERRAIN)
    np.testing.assert_allclose(maps.slope_deg[10:-10, 10:-10], 30.0, atol=0.05)


# ----------------------------------------------------------------------------- real frames
def load_realsense(root: Path, index: int) -> tuple[np.ndarray, Intrinsics]:
    cam = json.loads((root / "cam_params_realsense.json").read_text())
    k = np.array(cam["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T   # column-major
    intr = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], int(cam["width"]), int(cam["height"]))
    raw = cv2.imread(str(root / "depth" / f"{index:06d}.png"), cv2.IMREAD_UNCHANGED)
    assert raw is not None and raw.dtype == np.uint16
    depth = np.where(raw > 0, raw.astype(np.float32) * np.float32(CONFIG.sources.depth_unit_16u_m), np.nan)
    return depth.astype(np.float32), intr


def fit_floor_up(depth: np.ndarray, intr: Intrinsics, region: tuple[slice, slice]) -> tuple[np.ndarray, float]:
    """Plane fit (SVD) to a floor region: its normal towards the camera = world up; and the rms residual."""
    pts = geo.back_project(depth, intr)[region].reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)].astype(np.float64)
    centre = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - centre, full_matrices=False)
    n = vt[2] if vt[2] @ centre < 0 else -vt[2]
    return n, float(s[2] / math.sqrt(len(pts)))


# Regions of frame 000000 (640x480), chosen by looking at the colour image and the maps
# written to /tmp/terrain_real: the camera is ~0.7-2 m from a wooden floor, a cardboard box
# stands left of centre with its front face towards the camera, a white wall is behind it
# (top of the image) and a door is open on the right.
FLOOR_FIT = (slice(400, 470), slice(220, 420))     # bottom centre: floor only
FLOOR_LEFT = (slice(380, 470), slice(20, 150))     # bottom left: floor only
BOX_FACE = (slice(200, 300), slice(160, 300))      # the box's front face (white label)
WALL = (slice(10, 60), slice(200, 380))            # wall above the box
DOOR = (slice(60, 200), slice(480, 560))           # door panel on the right


def test_realsense_floor_scores_well_with_the_measured_tilt(realsense_dir: Path) -> None:
    depth, intr = load_realsense(realsense_dir, 0)
    up, rms = fit_floor_up(depth, intr, FLOOR_FIT)
    pitch, roll = tm.mount_from_up(up)
    # measured on this frame: pitch ~64.4 deg, roll ~19.0 deg, floor rms ~1.7 mm
    assert 55 < pitch < 75 and 10 < roll < 28 and rms < 0.005
    mount = Mount(round(pitch, 1), round(roll, 1))
    # The scene is 0.7-2 m away; the paper's 0.5 m patch is for 7-10 m altitude (~20 px there),
    # here it would span most of the image, so the test uses a patch of the same pixel scale.
    cfg = dataclasses.replace(CONFIG, camera=dataclasses.replace(CAM, mount=mount),
                              terrain=terrain(inclination={"radius_m": 0.15}))
    frame = Frame(index=0, stamp_ns=0, rgb=np.zeros((*depth.shape, 3), np.uint8), depth_m=depth,
                  intrinsics=intr)
    maps = tm.frame_maps(frame, tm.MapParams.of(cfg))
    # measured: floor steepness medians 0.70 / 0.64 (per-pixel slope noise of the 5 px normals on
    # RealSense depth: median 9-10 deg), inclination 0.95 / 0.99; hazards' slope medians 72-82 deg
    for floor in (FLOOR_FIT, FLOOR_LEFT):
        assert np.median(maps.steepness[floor]) > 0.5
        assert np.median(maps.inclination[floor]) > 0.8
        assert np.nanmedian(maps.slope_deg[floor]) < 12
    for hazard in (BOX_FACE, WALL, DOOR):
        assert np.median(maps.steepness[hazard]) < 0.05
        assert np.nanmedian(maps.slope_deg[hazard]) > 60
    # the box's patches straddle its edges: its face is far less planar-looking than the floor
    assert np.median(maps.inclination[BOX_FACE]) < 0.5
    # without the tilt the floor is "steep" (measured against the optical axis)
    nadir = tm.frame_maps(frame, tm.MapParams.of(dataclasses.replace(cfg, camera=CAM)))
    assert np.median(nadir.steepness[FLOOR_FIT]) < 0.05


# ----------------------------------------------------------------------------- properties
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), hole_fraction=st.floats(0.0, 0.6),
       base_m=st.floats(0.3, 80.0), frame_mode=st.booleans())
def test_maps_are_float32_in_unit_range_and_zero_without_depth(seed: int, hole_fraction: float, base_m: float,
                                                               frame_mode: bool) -> None:
    rng = np.random.default_rng(seed)
    intr = K.scaled(80, 60)
    depth = (base_m + rng.normal(0, 0.05 * base_m, (60, 80)).cumsum(axis=1) * 0.1).astype(np.float32)
    depth[rng.random(depth.shape) < hole_fraction] = np.nan
    depth[rng.random(depth.shape) < 0.02] = 0.0           # raw zeros mean "no measurement" too
    cfg = terrain(**{s: {"normalise": "frame" if frame_mode else "absolute"}
                     for s in ("depth_variance", "flatness", "inclination", "steepness")})
    maps = tm.compute_maps(depth, intr, DOWN, cfg)
    assert (maps.valid == (np.isfinite(depth) & (depth > 0))).all()
    for name, m in maps.as_dict().items():
        assert m.dtype == np.float32 and m.shape == depth.shape, name
        assert np.isfinite(m).all() and m.min() >= 0 and m.max() <= 1, name
        assert (m[~maps.valid] == 0).all(), name
    assert np.isnan(maps.slope_deg[~maps.valid]).all()
    assert np.nanmax(maps.slope_deg, initial=0.0) <= 90.0


def test_depth_variance_removes_the_sensor_noise_it_is_told_about() -> None:
    """Level ground at 10 m with RealSense-like noise sigma = a z^2: noise alone is not "variation"."""
    rng = np.random.default_rng(5)
    a = 0.0005
    depth = (10.0 + rng.normal(0, a * 100.0, (120, 160))).astype(np.float32)
    with_model = tm.depth_variance_map(depth, TERRAIN.depth_variance, noise_a_per_m=a)
    without = tm.depth_variance_map(depth, TERRAIN.depth_variance)
    assert np.median(without[1:-1, 1:-1]) < 0.5          # 5 cm of noise reads as 5 cm of roughness
    assert np.median(with_model[1:-1, 1:-1]) > 0.9       # the model takes it out
    step = depth.copy()
    step[:, 80:] -= 1.0                                  # a 1 m step still scores as bad
    edge = tm.depth_variance_map(step, TERRAIN.depth_variance, noise_a_per_m=a)
    assert edge[1:-1, 79:81].max() < 0.05   # the window's plane takes up part of a step: s = 0.236 h, exp(-4.7)


def test_normal_window_is_metric_so_slope_noise_does_not_grow_with_altitude() -> None:
    rng = np.random.default_rng(6)
    for z in (3.0, 10.0):
        depth = (z + rng.normal(0, 0.0005 * z * z, (K.height, K.width))).astype(np.float32)
        maps = tm.compute_maps(depth, K, DOWN, TERRAIN)
        assert np.nanpercentile(maps.slope_deg[20:-20, 20:-20], 90) < 5.0, z
    assert tm.normal_window_px(np.full((48, 64), 10.0, np.float32), K, TERRAIN.steepness) > TERRAIN.steepness.normal_px



# The documented mount of the real frames (datasets/README.md): the floor plane of frame 0 gives
# pitch 64.4 deg, roll 19.0 deg (test above). D435 RMS from Intel's tuning guide: a = s / (f B) with
# s 0.08 px, f 424 px (848 px wide, ~90 deg), B 50 mm: 0.0038 1/m.
REALSENSE_MOUNT = Mount(64.4, 19.0)
D435_A_PER_M = 0.0038


def test_realsense_noise_is_measured_and_near_the_d435_figure(realsense_dir: Path) -> None:
    from slzcli.terrain.noise import SCALES_PX, estimate_noise

    for i in range(10):
        depth, _ = load_realsense(realsense_dir, i)
        est = estimate_noise(depth, TERRAIN.noise_estimate)
        assert est is not None
        a8 = est.a_per_m[SCALES_PX.index(8)]
        # measured on the 10 frames (0.7-1.5 m): a_1 0.0010-0.0032, a_8 0.0020-0.0036 = 0.53-0.95 x the
        # D435 figure (Intel's RMS is a whole-ROI plane fit, so the coarse scale is the comparable one);
        # the stereo error is correlated: a_8 >= 0.77 a_1 on every frame, white noise would give a_1 / 8
        assert 0.25 * D435_A_PER_M < a8 < 2.0 * D435_A_PER_M, (i, est.a_per_m)
        assert a8 > 0.5 * est.a1_per_m, (i, est.a_per_m)


def test_realsense_floor_at_the_papers_altitude_scores_safe_and_the_hazards_do_not(realsense_dir: Path) -> None:
    """Frame 0 with the documented mount, its depth scaled by 10: the scene as the paper's UAV sees it from
    ~10 m (slopes kept, the box 3 m high, the real sensor's noise structure kept at 1/10 of a)."""
    from slzcli.scoring import MaskParams, get_scorer, score_frame

    depth, intr = load_realsense(realsense_dir, 0)
    depth = depth * np.float32(10.0)
    cfg = dataclasses.replace(CONFIG, camera=dataclasses.replace(CAM, mount=REALSENSE_MOUNT))
    frame = Frame(index=0, stamp_ns=0, rgb=np.zeros((*depth.shape, 3), np.uint8), depth_m=depth, intrinsics=intr)
    maps = tm.frame_maps(frame, tm.MapParams.of(cfg))
    assert maps.work is not None and maps.work.vouched
    sm = score_frame(get_scorer(cfg.scoring, cfg.mask), maps, depth, intr, MaskParams.of(cfg))
    # measured: floor score medians 0.73 / 0.73, 69 % / 88 % of the regions in the mask (the footprint
    # does not fit right next to the box); box, wall, door scores 0.06 and never in the mask
    for floor in (FLOOR_FIT, FLOOR_LEFT):
        assert np.median(sm.score[floor]) > cfg.mask.threshold
    assert sm.mask[FLOOR_LEFT].mean() > 0.4
    for hazard in (BOX_FACE, WALL, DOOR):
        assert np.median(sm.score[hazard]) < 0.2 and not sm.mask[hazard].any()


def test_flatness_scaling_follows_the_derivatives_spread_exactly() -> None:
    """_within_spread skips the median when a count shows it cannot pass the level; the result must be the
    direct formula's (k x MAD spread <= Canny's low threshold) bit for bit, on either side of the level."""
    from slzcli.terrain.maps import _within_spread
    from slzcli.terrain.noise import MAD_TO_SIGMA

    rng = np.random.default_rng(0)
    k, low = 2.0, 10.0
    scaled = 0
    for scale in np.linspace(1.0, 6.0, 60):   # the level sits at MAD-sigma ~3.4 (a median |g| of ~3.4 x 0.67)
        g = [(rng.standard_normal((60, 80)) * scale).astype(np.float32) for _ in range(2)]
        seen = rng.random((60, 80)) > 0.1
        spread = MAD_TO_SIGMA * float(np.median(np.abs(np.concatenate([x[seen] for x in g]))))
        want = [x * np.float32(low / (k * spread)) for x in g] if k * spread > low else g
        got = _within_spread(g, seen, k, low)
        assert all(np.array_equal(a, b) for a, b in zip(want, got, strict=True))
        scaled += got[0] is not g[0]
    assert 10 < scaled < 50   # both sides of the level were exercised
