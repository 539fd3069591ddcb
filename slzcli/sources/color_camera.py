"""Every frame in the colour camera's geometry: colour undistorted, depth on its pixel grid.

``DepthToColor`` says how the depth image reaches the colour pixel grid (decided once per
recording from the first CameraInfos and ``/tf_static``): ``aligned`` (the driver registered
it already: undistorted with the colour maps), ``register`` (its own CameraInfo and the
depth->colour extrinsics: registration.py), or ``resize`` (nothing to register with: a
nearest-neighbour resize, approximate; the reader warns). ``to_color_camera`` applies it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from slzcli.sources import decode
from slzcli.sources.registration import register_depth
from slzcli.sources.undistort import undistort_color, undistort_depth, undistort_maps
from slzcli.types import Intrinsics

Mode = Literal["aligned", "register", "resize"]


@dataclass(frozen=True, eq=False)
class DepthToColor:
    mode: Mode
    k_depth: Intrinsics | None = None
    T_color_depth: np.ndarray | None = None
    describe: str = "depth aligned to colour by the driver"


ALIGNED = DepthToColor("aligned")


def extrinsics(tree: Mapping[str, tuple[str, np.ndarray]], color_frame: str,
               depth_frame: str) -> tuple[np.ndarray | None, str]:
    """T_color_depth from a tf tree (child -> (parent, T_parent_child)), and where it came from.

    (None, why) when the two frames are not linked. The same frame: identity.
    """
    color_frame, depth_frame = color_frame.lstrip("/"), depth_frame.lstrip("/")
    if not color_frame or not depth_frame:
        return None, "the images' headers name no frame_id"
    if color_frame == depth_frame:
        return np.eye(4), f"colour and depth share the frame {color_frame!r}"
    top_c, T_top_color = decode.compose_chain(tree, color_frame) or (color_frame, np.eye(4))
    top_d, T_top_depth = decode.compose_chain(tree, depth_frame) or (depth_frame, np.eye(4))
    if top_c != top_d:
        return None, f"no /tf_static link between {depth_frame!r} and {color_frame!r}"
    return np.linalg.inv(T_top_color) @ T_top_depth, f"/tf_static {depth_frame} -> {color_frame}"


def same_camera(k_depth: Intrinsics, k_color: Intrinsics, T_color_depth: np.ndarray) -> bool:
    """Whether the depth CameraInfo and extrinsics describe the colour camera itself (already aligned)."""
    return (k_depth == k_color and np.allclose(T_color_depth, np.eye(4), atol=1e-9))


def to_color_camera(rgb: np.ndarray, depth_m: np.ndarray, k_color: Intrinsics,
                    d2c: DepthToColor) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """(rgb, depth, intrinsics) of the undistorted colour camera; ``k_color`` fits ``rgb``'s size.

    Distortion slz cannot undo is left in place (the reader has warned once).
    """
    h, w = rgb.shape[:2]
    maps = undistort_maps(k_color)
    if maps is not None:
        rgb = undistort_color(rgb, maps)
        k_color = maps.intrinsics
    if d2c.mode == "register" and d2c.k_depth is not None and d2c.T_color_depth is not None:
        dh, dw = depth_m.shape
        kd = d2c.k_depth if (d2c.k_depth.width, d2c.k_depth.height) == (dw, dh) else d2c.k_depth.scaled(dw, dh)
        return rgb, register_depth(depth_m, kd, d2c.T_color_depth, k_color), k_color
    depth_m = decode.match_depth_to_color(depth_m, (h, w))
    if maps is not None and d2c.mode == "aligned":
        depth_m = undistort_depth(depth_m, maps)
    return rgb, depth_m, k_color
