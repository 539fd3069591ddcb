"""points.ply: each point once with its role and cluster, read back by Open3D and by plain numpy."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from slzcli.outputs.points import NO_CLUSTER, ROLE_COLOURS, ROLES, read_points_ply, write_points_ply


def test_roles_read_back_with_their_colours(tmp_path) -> None:
    xyz = {"map": np.random.default_rng(0).random((10, 3)), "kept": np.zeros((0, 3)), "corner": np.ones((4, 3)) * 5}
    xyz["corner"] += np.arange(4)[:, None]
    write_points_ply(tmp_path / "p.ply", xyz)
    cloud = o3d.io.read_point_cloud(tmp_path / "p.ply")
    pts, colours = np.asarray(cloud.points), np.asarray(cloud.colors)
    assert pts.shape == (14, 3)
    np.testing.assert_allclose(pts[:10], xyz["map"], atol=1e-6)
    np.testing.assert_allclose(colours[-1] * 255, ROLE_COLOURS["corner"], atol=0.5)


def test_each_point_once_with_its_highest_role_and_cluster(tmp_path) -> None:
    """Points under the mask are map points too (and the chosen cluster is under the mask): one vertex each."""
    rng = np.random.default_rng(1)
    grid = rng.random((20, 3))
    kept, labels = grid[5:15], np.array([0, 0, 1, 1, 1, 2, 2, 0, 1, 2])
    chosen = kept[labels == 1]
    corners = rng.random((4, 3)) + 10.0
    write_points_ply(tmp_path / "p.ply", {"map": np.vstack([grid, grid[:3]]), "kept": kept, "chosen": chosen,
                                          "corner": corners},
                     {"kept": labels, "chosen": np.full(len(chosen), 1)})
    v = read_points_ply(tmp_path / "p.ply")
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    assert len(v) == 24 and len(np.unique(xyz, axis=0)) == 24        # 20 distinct map points + 4 corners
    assert np.bincount(v["role"], minlength=4).tolist() == [10, 6, 4, 4]
    assert ROLES[v["role"][-1]] == "corner" and v["cluster"][-1] == NO_CLUSTER
    assert set(v["cluster"][v["role"] == 0]) == {NO_CLUSTER}
    assert set(v["cluster"][v["role"] == 2]) == {1}
    assert sorted(v["cluster"][v["role"] == 1]) == [0, 0, 0, 2, 2, 2]
    np.testing.assert_allclose(xyz[v["role"] == 2], chosen, atol=1e-6)
    # Open3D reads the same file (extra properties ignored) with the same points.
    cloud = o3d.io.read_point_cloud(tmp_path / "p.ply")
    np.testing.assert_allclose(np.asarray(cloud.points), xyz, atol=1e-6)
    header = (tmp_path / "p.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property uchar role" in header and "property int cluster" in header and "2 chosen cluster" in header


def test_empty_cloud_is_a_valid_file(tmp_path) -> None:
    write_points_ply(tmp_path / "e.ply", {"map": np.zeros((0, 3))})
    data = (tmp_path / "e.ply").read_bytes()
    assert data.startswith(b"ply\n") and b"element vertex 0\n" in data and data.endswith(b"end_header\n")
    assert len(read_points_ply(tmp_path / "e.ply")) == 0
