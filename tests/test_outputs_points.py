"""points.ply round trip through Open3D, and a valid file when there are no points."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from slzcli.outputs.points import ROLE_COLOURS, write_points_ply


def test_roles_read_back_with_their_colours(tmp_path) -> None:
    xyz = {"map": np.random.default_rng(0).random((10, 3)), "kept": np.zeros((0, 3)), "corner": np.ones((4, 3))}
    write_points_ply(tmp_path / "p.ply", xyz)
    cloud = o3d.io.read_point_cloud(tmp_path / "p.ply")
    pts, colours = np.asarray(cloud.points), np.asarray(cloud.colors)
    assert pts.shape == (14, 3)
    np.testing.assert_allclose(pts[:10], xyz["map"], atol=1e-6)
    np.testing.assert_allclose(colours[-1] * 255, ROLE_COLOURS["corner"], atol=0.5)


def test_empty_cloud_is_a_valid_file(tmp_path) -> None:
    write_points_ply(tmp_path / "e.ply", {"map": np.zeros((0, 3))})
    data = (tmp_path / "e.ply").read_bytes()
    assert data.startswith(b"ply\n") and b"element vertex 0\n" in data and data.endswith(b"end_header\n")
