"""points.ply: SLAM map points coloured by their role in the site selection."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slzcli.outputs.files import atomic_path

# RGB: every map point grey, under the mask blue, the chosen cluster green, Eq. 10 corners red.
ROLE_COLOURS = {"map": (153, 153, 153), "kept": (38, 89, 242), "chosen": (26, 204, 51), "corner": (242, 26, 26)}
_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def write_points_ply(path: Path, xyz_by_role: dict[str, np.ndarray]) -> None:
    """One binary little-endian PLY with a colour per role (see ROLE_COLOURS); roles may be empty.

    Written with numpy rather than Open3D, whose writer refuses an empty cloud (a run with no
    map points still gets a valid, empty points.ply).
    """
    parts = [(np.asarray(v, np.float64).reshape(-1, 3), ROLE_COLOURS[role]) for role, v in xyz_by_role.items()]
    n = sum(len(xyz) for xyz, _ in parts)
    vertices = np.empty(n, _VERTEX)
    i = 0
    for xyz, colour in parts:  # a handful of roles, each filled vectorised
        block = vertices[i:i + len(xyz)]
        block["x"], block["y"], block["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        block["red"], block["green"], block["blue"] = colour
        i += len(xyz)
    header = ("ply\nformat binary_little_endian 1.0\ncomment slz map points: grey map, blue under the mask, "
              f"green chosen cluster, red landing square\nelement vertex {n}\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with atomic_path(path) as tmp:
        tmp.write_bytes(header.encode() + vertices.tobytes())
