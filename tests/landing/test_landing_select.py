"""Site selection (METHOD 2.5) on hand-made map points and masks."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from slzcli.geometry import project
from slzcli.landing.corners import square_corners
from slzcli.landing.select import SelectParams, point_normals, select_site

F, W, H = 462.137, 640, 480
K = np.array([[F, 0, 320.0], [0, F, 240.0], [0, 0, 1]])
# Camera 10 m above the origin looking straight down: optical x = world x, y = -world y, z = -world z.
T_WC = np.eye(4)
T_WC[:3, :3] = np.diag([1.0, -1.0, -1.0])
T_WC[:3, 3] = [0.0, 0.0, 10.0]


def params(**kw: Any) -> SelectParams:
    base = SelectParams(kmeans_k=2, normal_radius_m=0.5, min_cluster_points=5, footprint_m=(0.656, 0.656),
                        min_extent_factor=1.0, rule="min_normal_variance", seed=0, edge_clearance_m=0.43,
                        max_tilt_deg=15.0)
    return dataclasses.replace(base, **kw)


def patch(center_xy, size_m, n, rng, z_sigma=0.0) -> np.ndarray:
    xy = np.asarray(center_xy) + rng.uniform(-size_m / 2, size_m / 2, (n, 2))
    return np.column_stack([xy, rng.normal(0, z_sigma, n)])


def mask_from_world_boxes(boxes) -> np.ndarray:
    """A mask that is set inside world-XY boxes (cx, cy, half) on the ground plane z = 0."""
    v, u = np.mgrid[0:H, 0:W]
    x = (u - 320.0) / F * 10.0
    y = -(v - 240.0) / F * 10.0
    m = np.zeros((H, W), bool)
    for cx, cy, half in boxes:
        m |= (np.abs(x - cx) <= half) & (np.abs(y - cy) <= half)
    return m


def test_flatter_of_two_blobs_wins() -> None:
    rng = np.random.default_rng(1)
    flat = patch((-2.5, 0), 2.0, 150, rng)
    rough = patch((2.5, 0), 2.0, 150, rng, z_sigma=0.15)
    clutter = patch((0, 3), 1.0, 60, rng, z_sigma=0.5)  # off the mask: must be ignored
    xyz = np.vstack([flat, rough, clutter])
    mask = mask_from_world_boxes([(-2.5, 0, 1.1), (2.5, 0, 1.1)])
    sel = select_site(xyz, T_WC, K, mask, mask.astype(np.float32), params())
    assert sel.site is not None, sel.reason
    assert sel.site.center_world[0] == pytest.approx(-2.5, abs=0.3)
    assert sel.kept.sum() == 300 and not sel.kept[300:].any()
    u, v = sel.site.pixel
    assert mask[round(v), round(u)]
    variances = sorted(c.normal_variance for c in sel.candidates)
    assert sel.site.normal_variance == pytest.approx(variances[0])
    assert sel.site.tilt_deg < 5 and sel.site.accepted is True


def test_largest_rule_picks_the_bigger_cluster() -> None:
    rng = np.random.default_rng(2)
    small_flat = patch((-2.5, 0), 1.5, 80, rng)
    big_rough = patch((2.5, 0), 2.0, 250, rng, z_sigma=0.05)
    mask = mask_from_world_boxes([(-2.5, 0, 1.1), (2.5, 0, 1.1)])
    xyz = np.vstack([small_flat, big_rough])
    sel = select_site(xyz, T_WC, K, mask, mask.astype(np.float32), params(rule="largest"))
    assert sel.site is not None and sel.site.center_world[0] == pytest.approx(2.5, abs=0.3)


def test_blob_smaller_than_footprint_is_rejected() -> None:
    rng = np.random.default_rng(3)
    xyz = patch((0, 0), 0.4, 100, rng)
    mask = mask_from_world_boxes([(0, 0, 0.3)])
    sel = select_site(xyz, T_WC, K, mask, mask.astype(np.float32), params(kmeans_k=1))
    assert sel.site is None and "extent" in sel.reason


def test_all_zero_mask_gives_no_site() -> None:
    rng = np.random.default_rng(4)
    xyz = patch((0, 0), 4.0, 200, rng)
    mask = np.zeros((H, W), bool)
    sel = select_site(xyz, T_WC, K, mask, mask.astype(np.float32), params())
    assert sel.site is None and "0 of 200" in sel.reason


def test_ring_around_an_obstacle_does_not_put_the_site_on_the_obstacle() -> None:
    rng = np.random.default_rng(5)
    ring = patch((0, 0), 3.0, 400, rng)
    ring = ring[np.max(np.abs(ring[:, :2]), axis=1) > 0.9]
    mask = mask_from_world_boxes([(0, 0, 1.6)]) & ~mask_from_world_boxes([(0, 0, 0.9)])
    sel = select_site(ring, T_WC, K, mask, mask.astype(np.float32), params(kmeans_k=1))
    assert sel.site is None and "mask rejects" in sel.reason


def test_acceptance_test_reports_low_clearance_and_tilt() -> None:
    rng = np.random.default_rng(6)
    xyz = patch((0, 0), 2.0, 200, rng)
    xyz[:, 2] = 0.5 * xyz[:, 0]  # a 26.6 degree ramp
    mask = mask_from_world_boxes([(0, 0, 1.1)])
    edge = np.full((H, W), 0.2, np.float32)
    sel = select_site(xyz, T_WC, K, mask, mask.astype(np.float32), params(kmeans_k=1), edge_distance_m=edge)
    assert sel.site is not None
    assert sel.site.tilt_deg == pytest.approx(np.degrees(np.arctan(0.5)), abs=1.0)
    assert not sel.site.accepted and "tilt" in sel.site.acceptance_reason and "clearance" in sel.site.acceptance_reason


def test_normals_of_a_plane_and_corners() -> None:
    rng = np.random.default_rng(7)
    xyz = patch((100.0, -50.0), 3.0, 300, rng)  # far from the origin: centring keeps the maths exact
    n = point_normals(xyz, 0.5, np.array([0, 0, 1.0]))
    assert np.nanmax(np.abs(n[:, 2] - 1.0)) < 1e-9
    c = square_corners(np.array([1.0, 2.0, 3.0]), (0.656, 0.656))
    assert c.tolist()[0] == pytest.approx([1.656, 2.656, 3.0]) and c.tolist()[3] == pytest.approx([0.344, 1.344, 3.0])


def test_projection_matches_pinhole() -> None:
    uv, inside = project(np.array([[1.0, 1.0, 0.0], [0, 0, 20.0]]), T_WC, K, (H, W))
    assert uv[0] == pytest.approx([320 + F * 0.1, 240 - F * 0.1]) and inside.tolist() == [True, False]
