"""Which topic slz reads for each role (color, depth, camera_info, pose), with a human reason.

Automatic choice by message type, encoding and name; ``sources.topics.*`` overrides it. Rules
(datasets/README.md): colour = an Image/CompressedImage topic whose name does not say
depth/infra/ir, preferring a colour encoding, then names with color/colour/rgb, then raw over
compressed; depth = an Image or compressedDepth topic with "depth" in its name, preferring a
depth encoding (16UC1, mono16, 32FC1), then ``aligned_depth_to_color`` (same pixel grid as
colour), then raw over compressed;
camera_info = the CameraInfo beside the depth topic when depth is aligned, else beside
the colour topic, else any; pose = PoseStamped, then Odometry, then /tf, skipping topics
named as ground truth unless ``sources.use_ground_truth_pose``. depth_info = the depth stream's
own CameraInfo (beside the depth topic) when the depth is not aligned to colour: slz registers
it to the colour camera (registration.py). A camera preset (presets.py) names each role's topic
first; ``sources.topics.*`` beats both.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass

from slzcli.config import SourcesCfg
from slzcli.errors import DatasetError
from slzcli.sources.decode import COLOR_ENCODINGS, DEPTH_ENCODINGS
from slzcli.sources.presets import CameraPreset
from slzcli.types import StreamChoice

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
TRANSFORM = "geometry_msgs/msg/Transform"   # a RealSense recorder's per-stream extrinsics
POSE_TYPES = (POSE_STAMPED, ODOMETRY, TF)
GROUND_TRUTH_TOKENS = {"ground_truth", "groundtruth", "gt"}
# Depth topic names that say the driver registered the depth to the colour camera (realsense2_camera,
# openni/openni2 and zed wrappers).
ALIGNED_NAMES = ("aligned_depth_to_color", "depth_registered", "aligned_depth_to_rgb")


def normalise_msgtype(msgtype: str) -> str:
    """``pkg/Type`` (ROS 1, MCAP ros1msg) -> ``pkg/msg/Type`` as rosbags names it."""
    parts = msgtype.strip().split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype.strip()


def is_ground_truth(topic: str) -> bool:
    low = topic.lower()
    tokens = set(re.split(r"[/_\-.]+", low))
    return bool(tokens & GROUND_TRUTH_TOKENS) or "ground_truth" in low or "groundtruth" in low


def namespace(topic: str) -> str:
    """``/camera/color/image_raw[/compressed]`` -> ``/camera/color``."""
    parts = topic.rstrip("/").split("/")
    while parts and parts[-1] in ("compressed", "compressedDepth", "image_raw", "image_rect_raw", "image",
                                  "image_rect", "image_color", "image_rect_color", "camera_info"):
        parts.pop()
    return "/".join(parts)


ALIGNED_DEPTH_INFO = StreamChoice("depth_info", None, "depth aligned to colour: no depth CameraInfo needed")


@dataclass(frozen=True)
class Choices:
    color: StreamChoice
    depth: StreamChoice
    camera_info: StreamChoice
    pose: StreamChoice
    pose_type: str | None
    depth_info: StreamChoice = ALIGNED_DEPTH_INFO
    aligned: bool = True     # the depth image is on the colour camera's pixel grid (no registration)

    def all(self) -> tuple[StreamChoice, ...]:
        return (self.color, self.depth, self.camera_info, self.depth_info, self.pose)


def is_aligned_name(topic: str | None) -> bool:
    return topic is not None and any(n in topic for n in ALIGNED_NAMES)


def choose_streams(topics: Mapping[str, str], cfg: SourcesCfg, path: str,
                   encodings: Mapping[str, str] | None = None, preset: CameraPreset | None = None) -> Choices:
    """Pick the topic for every role; DatasetError (naming ``path``) when colour or depth is missing.

    ``encodings``: the ``encoding`` of the first message of Image topics, when known; a topic
    whose encoding does not fit the role ranks after every one that does (an rgb8
    ``/camera/depth/colorized`` is not depth, whatever its name says).
    """
    types = {t: normalise_msgtype(m) for t, m in topics.items()}
    enc = dict(encodings or {})
    color = _with_misfits(_preset_pick(preset, "color", types, (IMAGE, COMPRESSED), cfg.topics.color, enc,
                                       COLOR_ENCODINGS), lambda: _pick_color(types, cfg.topics.color, path, enc))
    depth = _with_misfits(_preset_pick(preset, "depth", types, (IMAGE, COMPRESSED), cfg.topics.depth, enc,
                                       DEPTH_ENCODINGS),
                          lambda: _pick_depth(types, cfg.topics.depth, path, exclude=color.topic, encodings=enc))
    by_preset = preset is not None and depth.reason.startswith("preset")
    aligned = (preset.depth_aligned if by_preset and preset is not None else is_aligned_name(depth.topic)) \
        and not cfg.topics.depth_info
    info = _preset_pick(preset, "camera_info", types, (CAMERA_INFO,), cfg.topics.camera_info) \
        or _pick_info(types, cfg.topics.camera_info, color.topic, depth.topic if aligned else None, path)
    depth_info = ALIGNED_DEPTH_INFO
    if not aligned:
        depth_info = (_override(types, cfg.topics.depth_info, "depth_info", (CAMERA_INFO,), path)
                      if cfg.topics.depth_info else None) \
            or _preset_pick(preset, "depth_info", types, (CAMERA_INFO,), "") \
            or _pick_depth_info(types, depth.topic, info.topic)
    pose = _pick_pose(types, cfg, path)
    return Choices(color, depth, info, pose, types.get(pose.topic) if pose.topic else None, depth_info, aligned)


def _with_misfits(chosen: StreamChoice | None, generic: Callable[[], StreamChoice]) -> StreamChoice:
    """The preset's choice (keeping the generic rule's note on topics of the wrong encoding), else the generic one."""
    if chosen is None:
        return generic()
    try:
        note = generic().reason
    except DatasetError:
        return chosen
    ranked = note[note.find("ranked last"):] if "ranked last" in note else ""
    return StreamChoice(chosen.role, chosen.topic, "; ".join([chosen.reason] + ([ranked] if ranked else [])))


def _preset_pick(preset: CameraPreset | None, role: str, types: Mapping[str, str], allowed: tuple[str, ...],
                 override: str, encodings: Mapping[str, str] | None = None,
                 fit: Collection[str] = ()) -> StreamChoice | None:
    """The preset's topic for a role (None: no preset, an override, or no topic of the right type and, when
    known, encoding matches)."""
    if preset is None or override:
        return None
    topic = preset.topic_for(role, [t for t, m in types.items() if m in allowed
                                    and (not fit or _fits(encodings or {}, t, fit))])
    if topic is None:
        return None
    why = f"preset {preset.name} ({preset.topics[role]})"
    if role == "depth":
        why += ("; aligned to colour by the driver" if preset.depth_aligned
                else "; not aligned to colour: registered to it with the depth CameraInfo")
    return StreamChoice(role, topic, why)


def _pick_depth_info(types: Mapping[str, str], depth: str | None, color_info: str | None) -> StreamChoice:
    """The CameraInfo beside a depth topic that is not aligned to colour (its own intrinsics)."""
    for t in sorted(types):
        if types[t] == CAMERA_INFO and t != color_info and depth is not None and namespace(t) == namespace(depth):
            return StreamChoice("depth_info", t, "beside the depth topic (depth not aligned: registered to colour)")
    return StreamChoice("depth_info", None, "no CameraInfo beside the depth topic: depth cannot be registered to "
                                            "colour, it is resized to the colour size (approximate)")


def _override(types: Mapping[str, str], topic: str, role: str, allowed: tuple[str, ...], path: str) -> StreamChoice:
    if topic not in types:
        raise DatasetError(path, f"sources.topics.{role} = {topic!r} is not in the recording "
                                 f"(topics: {', '.join(sorted(types)) or 'none'})")
    if types[topic] not in allowed:
        raise DatasetError(path, f"sources.topics.{role} = {topic!r} has type {types[topic]}, "
                                 f"expected {' or '.join(allowed)}")
    return StreamChoice(role, topic, f"set by sources.topics.{role}")


def _is_depth_name(topic: str) -> bool:
    return "depth" in topic.lower()


def _fits(encodings: Mapping[str, str], topic: str, allowed: Collection[str]) -> bool:
    """Whether a topic's known encoding suits a role (unknown: assumed to)."""
    enc = encodings.get(topic)
    return not enc or enc in allowed


def _misfits(encodings: Mapping[str, str], cands: list[str], allowed: Collection[str], role: str) -> str | None:
    bad = [f"{t} ({encodings[t]})" for t in cands if not _fits(encodings, t, allowed)]
    return f"ranked last as not {role}: {', '.join(bad)}" if bad else None


def _pick_color(types: Mapping[str, str], override: str, path: str,
                encodings: Mapping[str, str]) -> StreamChoice:
    if override:
        return _override(types, override, "color", (IMAGE, COMPRESSED), path)
    skip = re.compile(r"depth|infra|(^|[/_])ir([/_]|\d|$)|disparity|mask|label|segment", re.I)
    cands = [t for t, m in types.items() if m in (IMAGE, COMPRESSED) and not skip.search(t)]
    if not cands:
        raise DatasetError(path, "no colour stream (no sensor_msgs/Image or CompressedImage topic without "
                                 "'depth'/'infra' in its name); set sources.topics.color")
    named = re.compile(r"colou?r|rgb", re.I)

    def rank(t: str) -> tuple[int, int, int, str]:
        return (0 if _fits(encodings, t, COLOR_ENCODINGS) else 1, 0 if named.search(t) else 1,
                0 if types[t] == IMAGE else 1, t)

    best = min(cands, key=rank)
    why = [types[best].rsplit("/", 1)[-1] + (f" {encodings[best]}" if encodings.get(best) else "")]
    why.append("name says colour" if named.search(best) else "no depth/infrared in the name")
    if types[best] == IMAGE and any(types[t] == COMPRESSED for t in cands):
        why.append("raw preferred over compressed")
    if len(cands) > 1:
        why.append(f"{len(cands) - 1} other candidate(s)")
    misfit = _misfits(encodings, cands, COLOR_ENCODINGS, "colour")
    return StreamChoice("color", best, "; ".join(why + ([misfit] if misfit else [])))


def _pick_depth(types: Mapping[str, str], override: str, path: str, exclude: str | None,
                encodings: Mapping[str, str]) -> StreamChoice:
    if override:
        return _override(types, override, "depth", (IMAGE, COMPRESSED), path)
    cands = [t for t, m in types.items() if t != exclude and _is_depth_name(t)
             and (m == IMAGE or (m == COMPRESSED and "compresseddepth" in t.lower()))]
    if not cands:
        raise DatasetError(path, "no depth stream (no Image or compressedDepth topic with 'depth' in its name); "
                                 "set sources.topics.depth")

    def rank(t: str) -> tuple[int, int, int, str]:
        return (0 if _fits(encodings, t, DEPTH_ENCODINGS) else 1, 0 if is_aligned_name(t) else 1,
                0 if types[t] == IMAGE else 1, t)

    best = min(cands, key=rank)
    why = ["aligned to colour (aligned_depth_to_color preferred)" if is_aligned_name(best)
           else "depth in the name; not aligned to colour: registered to it with the depth CameraInfo"]
    why.append(f"raw Image {encodings.get(best, '')}".rstrip() if types[best] == IMAGE else "compressedDepth")
    if len(cands) > 1:
        why.append(f"{len(cands) - 1} other candidate(s)")
    misfit = _misfits(encodings, cands, DEPTH_ENCODINGS, "depth (16UC1, mono16, 32FC1 or compressedDepth)")
    return StreamChoice("depth", best, "; ".join(why + ([misfit] if misfit else [])))


def _pick_info(types: Mapping[str, str], override: str, color: str | None, depth: str | None,
               path: str) -> StreamChoice:
    if override:
        return _override(types, override, "camera_info", (CAMERA_INFO,), path)
    infos = [t for t, m in types.items() if m == CAMERA_INFO]
    if not infos:
        return StreamChoice("camera_info", None, "no CameraInfo topic: intrinsics from the config camera section")
    order = ([("depth", depth)] if depth is not None else []) + [("colour", color)]
    for label, stream in order:
        if stream is None:
            continue
        for t in infos:
            if namespace(t) == namespace(stream):
                return StreamChoice("camera_info", t, f"beside the {label} topic"
                                    + (" (aligned depth shares the colour intrinsics)" if label == "depth" else ""))
    best = sorted(infos)[0]
    return StreamChoice("camera_info", best, "the only CameraInfo topic" if len(infos) == 1
                        else f"first of {len(infos)} CameraInfo topics (none beside the colour topic)")


def _pick_pose(types: Mapping[str, str], cfg: SourcesCfg, path: str) -> StreamChoice:
    if cfg.topics.pose:
        return _override(types, cfg.topics.pose, "pose", POSE_TYPES, path)
    cands = [t for t, m in types.items() if m in POSE_TYPES and t != "/tf_static"]
    gt = [t for t in cands if is_ground_truth(t)]
    usable = cands if cfg.use_ground_truth_pose else [t for t in cands if t not in gt]
    if not usable:
        if gt:
            return StreamChoice("pose", None, f"skipped {', '.join(sorted(gt))} (named as ground truth; "
                                              "set sources.use_ground_truth_pose to use it): frames carry no pose")
        return StreamChoice("pose", None, "no PoseStamped, Odometry or /tf topic: frames carry no pose")
    best = min(usable, key=lambda t: (POSE_TYPES.index(types[t]), t))
    why = [types[best].rsplit("/", 1)[-1] + " (PoseStamped > Odometry > tf)"]
    if gt and not cfg.use_ground_truth_pose:
        why.append(f"skipped ground truth {', '.join(sorted(gt))}")
    if types[best] == TF:
        why.append("camera pose composed along the tf chain to the root frame")
    return StreamChoice("pose", best, "; ".join(why))
