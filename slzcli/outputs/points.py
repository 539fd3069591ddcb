"""points.ply: SLAM map points coloured by their role in the site selection."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from slzcli.errors import OutputError
from slzcli.outputs.files import atomic_path

# RGB in [0, 1]: every map point grey, under the mask blue, the chosen cluster green, Eq. 10 corners red.
ROLE_COLOURS = {"map": (0.6, 0.6, 0.6), "kept": (0.15, 0.35, 0.95), "chosen": (0.1, 0.8, 0.2),
                "corner": (0.95, 0.1, 0.1)}


def write_points_ply(path: Path, xyz_by_role: dict[str, np.ndarray]) -> None:
    """One binary PLY with a colour per role (see ROLE_COLOURS); roles may be empty."""
    xyz = [np.asarray(v, np.float64).reshape(-1, 3) for v in xyz_by_role.values()]
    rgb = [np.tile(ROLE_COLOURS[role], (len(v), 1)) for role, v in zip(xyz_by_role, xyz)]
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.vstack(xyz) if xyz else np.zeros((0, 3)))
    cloud.colors = o3d.utility.Vector3dVector(np.vstack(rgb) if rgb else np.zeros((0, 3)))
    with atomic_path(path) as tmp:
        if not o3d.io.write_point_cloud(str(tmp), cloud, format="ply"):
            raise OutputError(path, "open3d could not write the PLY file")
