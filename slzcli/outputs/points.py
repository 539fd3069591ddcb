"""points.ply: the run's SLAM map points, each once, with its role in the site selection and its cluster.

Vertex properties: ``x y z`` (float, metres, the run's world frame), ``red green blue`` (uchar,
the role's colour, for viewers that show only colour), ``role`` (uchar, ``ROLES``: 0 map point,
1 under the landing mask, 2 in the chosen cluster, 3 a corner of the Eq. 10 square) and
``cluster`` (int, the k-means cluster of a point under the mask in the committed detection,
-1 for the rest). A point that has several roles (every point under the mask is a map point
too) is written once, with its highest role; points at the same coordinates are one point.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slzcli.outputs import palette
from slzcli.outputs.files import atomic_path

# role byte = position in ROLES (the PLY header comment says the same); a later role outranks an earlier one.
ROLES = ("map", "kept", "chosen", "corner")
# RGB, the overlay's colours (outputs/palette.py): every map point grey, under the mask sky blue, the chosen
# cluster yellow, the Eq. 10 corners white.
ROLE_COLOURS = {"map": palette.UNDECIDED, "kept": palette.KEPT, "chosen": palette.CHOSEN, "corner": palette.SITE}
NO_CLUSTER = -1
VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                   ("role", "u1"), ("cluster", "<i4")])
HEADER = ("ply\nformat binary_little_endian 1.0\n"
          "comment slz map points, each once: role 0 map point (grey), 1 under the landing mask (sky blue), "
          "2 chosen cluster (yellow), 3 corner of the landing square (white)\n"
          "comment cluster: k-means cluster of a point under the mask in the committed detection, -1 none\n"
          "element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
          "property uchar green\nproperty uchar blue\nproperty uchar role\nproperty int cluster\nend_header\n")


def point_vertices(xyz_by_role: dict[str, np.ndarray],
                   cluster_by_role: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """The PLY vertices (``VERTEX``): each distinct point once with its highest role, in role then input order."""
    clusters = cluster_by_role or {}
    xyz_parts, role_parts, cluster_parts = [], [], []
    for role, v in xyz_by_role.items():
        xyz = np.asarray(v, np.float64).reshape(-1, 3)
        xyz_parts.append(xyz)
        role_parts.append(np.full(len(xyz), ROLES.index(role), np.uint8))
        c = clusters.get(role)
        cluster_parts.append(np.full(len(xyz), NO_CLUSTER, np.int32) if c is None else np.asarray(c, np.int32))
    if not xyz_parts:
        return np.empty(0, VERTEX)
    xyz, roles, cluster = np.vstack(xyz_parts), np.concatenate(role_parts), np.concatenate(cluster_parts)
    # Highest role first, so that np.unique's first occurrence of each coordinate triple is its highest role.
    by_role = np.argsort(-roles.astype(np.int16), kind="stable")
    _, first = np.unique(xyz[by_role], axis=0, return_index=True)
    keep = by_role[first]
    keep = keep[np.lexsort((keep, roles[keep]))]  # role order, then input order
    out = np.empty(len(keep), VERTEX)
    out["x"], out["y"], out["z"] = xyz[keep, 0], xyz[keep, 1], xyz[keep, 2]
    rgb = np.array([ROLE_COLOURS[r] for r in ROLES], np.uint8)[roles[keep]]
    out["red"], out["green"], out["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    out["role"], out["cluster"] = roles[keep], cluster[keep]
    return out


def write_points_ply(path: Path, xyz_by_role: dict[str, np.ndarray],
                     cluster_by_role: dict[str, np.ndarray] | None = None) -> None:
    """One binary little-endian PLY (see the module docstring); roles may be empty.

    Written with plyfile (the same bytes as ``HEADER`` + the vertex records) rather than Open3D, whose
    writer refuses an empty cloud (a run with no map points still gets a valid, empty points.ply) and
    writes no extra properties.
    """
    from plyfile import PlyData, PlyElement

    vertices = point_vertices(xyz_by_role, cluster_by_role)
    comments = [ln[len("comment "):] for ln in HEADER.splitlines() if ln.startswith("comment ")]
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<", comments=comments).write(fh)


def read_points_ply(path: Path) -> np.ndarray:
    """The vertices of a points.ply (``VERTEX`` fields; plyfile reads any PLY with those properties)."""
    from plyfile import PlyData

    data = PlyData.read(str(path))["vertex"].data
    return np.asarray(data).astype(VERTEX)
