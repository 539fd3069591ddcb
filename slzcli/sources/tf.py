"""The recording's frame ids for results.mcap: the camera's optical frame, its /tf_static chain, the pose frame.

Read at the start of a run in short passes over few topics (``/tf_static``, the first colour
message, the first pose messages; the readers seek by topic), not in the frame pass: results.mcap
needs them before its first message. What they are used for: docs/DESIGN.md "results.mcap frames".
"""

from __future__ import annotations

import logging
from collections.abc import Iterable

import numpy as np

from slzcli.errors import DecodeError
from slzcli.sources import decode, tf_tree
from slzcli.sources import ros_types as ros
from slzcli.types import RecordedFrames

log = logging.getLogger(__name__)
TF_STATIC = "/tf_static"
# How many /tf messages are read to find the root of the camera's chain: the tree is complete after
# the first round of each broadcaster (tens of messages at 10-200 Hz); a bound keeps a tree that
# never reaches the camera from reading the whole recording. Project decision.
MAX_TF_MESSAGES = 2000

Transforms = list[tuple[int, str, str, np.ndarray]]  # (stamp_ns, parent, child, T_parent_child), decode.decode_tf


def transforms(msg: ros.TFMessage) -> Transforms:
    """The transforms of one TFMessage; none (logged) when one of them cannot be decoded."""
    try:
        return decode.decode_tf(msg)
    except (DecodeError, AttributeError) as err:
        log.debug("TFMessage not usable: %s", err)
        return []


def static_tree(messages: Iterable[ros.TFMessage]) -> dict[str, tuple[str, np.ndarray]]:
    """child -> (parent, T_parent_child) of every /tf_static message (a later one for a child wins).

    ``tf_tree.TfTreeError`` when they do not make a tree (a frame with two parents, a cycle)."""
    tree: dict[str, tuple[str, np.ndarray]] = {}
    for msg in messages:
        tf_tree.add_edges(tree, transforms(msg))
    return tree


def tf_root(messages: Iterable[ros.TFMessage], static: dict[str, tuple[str, np.ndarray]], camera: str) -> str:
    """The root of ``camera``'s chain once /tf links it beyond its static chain ("" when it never does)."""
    static_top = _top(static, camera)
    tree = dict(static)
    for i, msg in enumerate(messages):
        if i >= MAX_TF_MESSAGES:
            break
        tf_tree.add_edges(tree, transforms(msg))  # TfTreeError: not a tree with the static one
        top = _top(tree, camera)
        if top != static_top:
            return top
    return ""


def _top(tree: dict[str, tuple[str, np.ndarray]], frame: str) -> str:
    """The root of ``frame``'s chain (the frame itself on a cycle, which the frame pass reports)."""
    try:
        chain = decode.compose_chain(tree, frame)
    except DecodeError:
        return frame
    return frame if chain is None else chain[0]


def recorded_frames(camera: str, static: dict[str, tuple[str, np.ndarray]], pose_frame: str,
                    from_tf: bool) -> RecordedFrames:
    """The frames of a recording from what was read (see ``RecordedFrames``)."""
    root = _top(static, camera) if camera else camera
    edges: list[tuple[str, str, np.ndarray]] = []
    T = np.eye(4)
    node = camera
    while root != camera and node != root:
        parent, T_parent_node = static[node]
        edges.append((parent, node, T_parent_node))
        T = T_parent_node @ T
        node = parent
    if root == camera:
        return RecordedFrames(camera=camera, pose_frame=pose_frame, tf_places_camera=from_tf and bool(pose_frame))
    return RecordedFrames(camera=camera, camera_root=root, T_root_camera=T, static_chain=tuple(edges),
                          pose_frame=pose_frame, tf_places_camera=from_tf and bool(pose_frame))


def first_pose_frame(messages: Iterable[ros.PoseStamped | ros.Odometry]) -> str:
    """The parent frame of the first decodable PoseStamped or Odometry ("" when none is)."""
    for msg in messages:
        try:
            return decode.decode_pose(msg)[1]
        except (DecodeError, AttributeError) as err:
            log.debug("pose message without a usable header: %s", err)
    return ""
