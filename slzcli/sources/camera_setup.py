"""The setup scan of a message recording: what is decided once, before the frames stream, from the
recording's first messages: the streams (``peek_encodings`` when names do not settle it), the CameraInfo
checks and the fallback intrinsics, the depth unit (a RealSense recorder's Depth_Units), how depth reaches
the colour grid (aligned, registered with the depth CameraInfo and the extrinsics of /tf_static or the
recorder's stream extrinsics, or resized), and the recording's own frame ids (camera, static tf, poses).

Each is read in a short pass of its own (within ``SETUP_SCAN_NS`` of log time after the first image where
the answer is at the start) and kept: the stream (``frame_stream.py``) asks for it per frame, and no
short pass runs inside the stream's own.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Generator
from contextlib import closing

import numpy as np

from slzcli.config import Config
from slzcli.errors import DatasetError, DecodeError
from slzcli.sources import decode, tf, tf_tree
from slzcli.sources.color_camera import ALIGNED, DepthToColor, extrinsics, same_camera
from slzcli.sources.message_log import MessageLog
from slzcli.sources.presets import PresetChoice
from slzcli.sources.ros_types import Message
from slzcli.sources.topics import COMPRESSED, IMAGE, TF, TRANSFORM, Choices, normalise_msgtype
from slzcli.sources.undistort import distortion_problem
from slzcli.sources.validate import info_frame_problem, intrinsics_problem, pixel_aspect_problem
from slzcli.types import Intrinsics, RecordedFrames

log = logging.getLogger(__name__)
TF_STATIC = "/tf_static"
# How far (log time) past the first image the pre-pass looks for the depth CameraInfo and /tf_static
# (both are published at start-up, tf_static latched); project decision.
SETUP_SCAN_NS = 5 * 1_000_000_000
# A RealSense recorder's depth unit (std_msgs/Float32, metres per count): librealsense's ros-bag format.
DEPTH_UNITS_TOPIC = re.compile(r"/device_\d+/sensor_\d+/option/Depth_Units/value")


def peek_encodings(log: MessageLog, topics: dict[str, str]) -> dict[str, str]:
    """The encoding of the first message of each Image topic, when there are more image topics
    than the colour and the depth stream (so that the choice cannot go by name alone)."""
    types = {t: normalise_msgtype(m) for t, m in topics.items()}
    images = [t for t, m in types.items() if m == IMAGE]
    if sum(m in (IMAGE, COMPRESSED) for m in types.values()) <= 2 or not images:
        return {}
    found: dict[str, str] = {}
    with closing(log.read(images)) as messages:
        for msg in messages:
            if msg.topic not in found:
                try:
                    found[msg.topic] = str(getattr(log.deserialize(msg.topic, msg.data), "encoding", ""))
                except DecodeError:
                    found[msg.topic] = ""
            if len(found) == len(images):
                break
    return found


class CameraSetup:
    """What one open message recording decided before streaming; each answer read once, on first use.
    ``warnings``: the fallbacks taken (each logged once; RecordingInfo.warnings)."""

    def __init__(self, msglog: MessageLog, config: Config, topics: dict[str, str], choices: Choices,
                 preset: PresetChoice) -> None:
        self.log = msglog
        self.path = msglog.path
        self.config = config
        self.cfg = config.sources
        self.topics = topics
        self.choices = choices
        self.preset = preset
        self.warnings: list[str] = []
        self._d2c: DepthToColor | None = None
        self._unit: float | None = None

    def warn(self, text: str) -> None:
        """A fallback: one warning line on stderr and in RecordingInfo.warnings (run.json), however often met."""
        if text not in self.warnings:
            self.warnings.append(text)
            log.warning("%s: %s", self.path, text)

    def depth_unit_m(self) -> float:
        """Metres per 16-bit depth count: the recording's own (a RealSense recorder's Depth_Units option),
        else ``sources.depth_unit_16u_m``."""
        if self._unit is None:
            self._unit = self.cfg.depth_unit_16u_m
            topic = next((t for t in sorted(self.topics) if DEPTH_UNITS_TOPIC.fullmatch(t)), None)
            if topic is not None:
                with closing(self.log.read([topic])) as messages:
                    for msg in messages:
                        try:
                            value = float(self.log.deserialize(msg.topic, msg.data).data)
                        except (DecodeError, AttributeError, TypeError, ValueError) as err:
                            self.warn(f"{topic}: not a depth unit ({err}): sources.depth_unit_16u_m used")
                            break
                        if 0 < value < 1:
                            self._unit = value
                        else:
                            self.warn(f"{topic}: depth unit {value!r} m is not usable: sources.depth_unit_16u_m used")
                        break
        return self._unit

    def depth_to_color(self) -> DepthToColor:
        """How depth reaches the colour grid, decided once from the first messages (warnings for fallbacks)."""
        if self._d2c is None:
            self._check_info_frames(self.choices)
            self._d2c = self._find_depth_to_color(self.choices)
        return self._d2c

    def _check_info_frames(self, ch: Choices) -> None:
        """DatasetError when a chosen CameraInfo names another optical frame than its image stream: the colour
        (or aligned) intrinsics against the colour image, the depth's own against the depth image. Read from
        the first message of each (raw headers), within SETUP_SCAN_NS of log time after the first image."""
        pairs = [(info, image) for info, image in ((ch.camera_info.topic, ch.color.topic),
                                                   (ch.depth_info.topic, ch.depth.topic)) if info and image]
        if not pairs:
            return
        wanted = {t for pair in pairs for t in pair}
        frames: dict[str, str] = {}
        first_image: int | None = None
        with closing(self.log.read(sorted(wanted))) as messages:
            for msg in messages:
                if msg.topic not in frames:
                    try:
                        frames[msg.topic] = decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))[1]
                    except DecodeError:
                        frames[msg.topic] = ""  # undecodable: reported where the message is used
                if msg.topic in (ch.color.topic, ch.depth.topic) and first_image is None:
                    first_image = msg.log_ns
                if len(frames) == len(wanted) or (first_image is not None
                                                  and msg.log_ns - first_image > SETUP_SCAN_NS):
                    break
        for info, image in pairs:
            problem = info_frame_problem(info, frames.get(info, ""), image, frames.get(image, ""))
            if problem is not None:
                raise DatasetError(self.path, problem)

    def _find_depth_to_color(self, ch: Choices) -> DepthToColor:
        if ch.aligned:
            return ALIGNED
        if ch.depth_info.topic is None:
            self.warn(f"{ch.depth.topic} is not aligned to colour and has no CameraInfo of its own: resized "
                       "nearest-neighbour to the colour image (geometry approximate); set sources.topics.depth_info")
            return DepthToColor("resize", describe="resized nearest-neighbour (no depth CameraInfo)")
        k_depth, k_color, frames, tree, stream_tf = self._scan_setup(ch)
        if k_depth is None:
            self.warn(f"no usable CameraInfo on {ch.depth_info.topic}: depth resized nearest-neighbour to the "
                       "colour image (geometry approximate)")
            return DepthToColor("resize", describe="resized nearest-neighbour (depth CameraInfo unusable)")
        problem = distortion_problem(k_depth)
        if problem is not None:
            self.warn(f"CameraInfo on {ch.depth_info.topic}: {problem}")
        T, source = self._depth_extrinsics(ch, frames, tree, stream_tf)
        if T is None:
            self.warn(f"no depth->colour extrinsics ({source}): depth reprojected as if both cameras shared "
                       "one optical centre (off by their baseline); record /tf_static")
            T, source = np.eye(4), "identity (no extrinsics)"
        if k_color is not None and same_camera(k_depth, k_color, T):
            return DepthToColor("aligned", describe=f"depth CameraInfo equals the colour one ({source}): aligned")
        return DepthToColor("register", k_depth, T, f"registered to colour: {k_depth.width}x{k_depth.height} depth "
                                                    f"camera, extrinsics from {source}")

    def _depth_extrinsics(self, ch: Choices, frames: dict[str, str], tree: dict[str, tuple[str, np.ndarray]],
                          stream_tf: dict[str, np.ndarray]) -> tuple[np.ndarray | None, str]:
        """T_color_depth: the recorder's per-stream extrinsics (RealSense .bag), else /tf_static by frame_id."""
        prefix = {role: _stream_prefix(topic) for role, topic in (("color", ch.color.topic), ("depth", ch.depth.topic))}
        ref = {role: T for role, p in prefix.items() if p
               for topic, T in sorted(stream_tf.items(), reverse=True) if topic.startswith(p + "/tf/")}
        if "color" in ref and "depth" in ref:
            # each maps the group's reference stream into the stream (T_stream_ref): librealsense's recorder writes
            # device::get_extrinsics(stream), the extrinsics from the reference ("pin") stream to the stream
            return ref["color"] @ np.linalg.inv(ref["depth"]), "the recorded stream extrinsics (.../tf/0)"
        return extrinsics(tree, frames.get("color", ""), frames.get("depth", ""))

    def _scan_setup(self, ch: Choices) -> tuple[Intrinsics | None, Intrinsics | None, dict[str, str],
                                                 dict[str, tuple[str, np.ndarray]], dict[str, np.ndarray]]:
        """One short pass: the first depth and colour CameraInfo, the images' frame ids, /tf_static, and the
        per-stream extrinsics a RealSense recorder writes. Stops once all are in hand, or SETUP_SCAN_NS of
        log time after the first image."""
        stream_topics = [t for t, m in self.topics.items() if normalise_msgtype(m) == TRANSFORM and "/tf/" in t]
        wanted = {t for t in (ch.depth_info.topic, ch.camera_info.topic, ch.color.topic, ch.depth.topic) if t}
        wanted |= set(stream_topics) | ({TF_STATIC} if TF_STATIC in self.topics else set())
        k_depth = k_color = None
        frames: dict[str, str] = {}
        tree: dict[str, tuple[str, np.ndarray]] = {}
        stream_tf: dict[str, np.ndarray] = {}
        first_image: int | None = None
        with closing(self.log.read(sorted(wanted))) as messages:
            for msg in messages:
                try:
                    if msg.topic in (ch.color.topic, ch.depth.topic):
                        role = "color" if msg.topic == ch.color.topic else "depth"
                        frames.setdefault(role, decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))[1])
                        first_image = msg.log_ns if first_image is None else first_image
                    elif msg.topic == ch.depth_info.topic and k_depth is None:
                        k_depth = self.check_info(msg.topic, decode.decode_camera_info(
                            self.log.deserialize(msg.topic, msg.data)))
                    elif msg.topic == ch.camera_info.topic and k_color is None:
                        k_color = decode.decode_camera_info(self.log.deserialize(msg.topic, msg.data))
                    elif msg.topic == TF_STATIC:
                        tf_tree.add_edges(tree, decode.decode_tf(self.log.deserialize(msg.topic, msg.data)))
                    elif msg.topic in stream_topics and msg.topic not in stream_tf:
                        m = self.log.deserialize(msg.topic, msg.data)
                        stream_tf[msg.topic] = decode.transform_matrix(m.translation, m.rotation)
                except DecodeError as err:
                    self.warn(f"{msg.topic}: {err} (while reading the camera set-up)")
                except tf_tree.TfTreeError as err:
                    raise DatasetError(self.path, f"{msg.topic}: {err}") from err
                have_all = k_depth is not None and len(frames) == 2 and (k_color or not ch.camera_info.topic)
                if have_all and (len(stream_tf) >= 2 or extrinsics(tree, frames["color"], frames["depth"])[0]
                                 is not None):
                    break
                if first_image is not None and msg.log_ns - first_image > SETUP_SCAN_NS:
                    break
        return k_depth, k_color, frames, tree, stream_tf

    def check_info(self, topic: str, k: Intrinsics) -> Intrinsics:
        """A decoded CameraInfo, checked: DatasetError naming the topic when it cannot be used."""
        lim = self.cfg.intrinsics
        problem = intrinsics_problem(k, lim.min_fov_deg, lim.max_fov_deg)
        if problem is not None:
            raise DatasetError(self.path, f"CameraInfo on {topic}: {problem}; fix the camera's calibration, or set "
                                          "sources.topics.camera_info to another CameraInfo topic")
        problem = pixel_aspect_problem(k, lim.max_pixel_aspect)
        if problem is not None:
            self.warn(f"CameraInfo on {topic}: {problem}")
        return k

    def fallback_intrinsics(self) -> tuple[Intrinsics, str]:
        """Intrinsics without a CameraInfo: the camera preset's, else the config camera section (a warning)."""
        preset = self.preset.preset
        if preset is not None and preset.intrinsics is not None:
            return preset.intrinsics, f"camera preset {preset.name} (no CameraInfo)"
        cam = self.config.camera
        k = Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        self.warn(f"no usable CameraInfo: intrinsics from the config camera section (fx {cam.fx:g} px, {cam.width}x"
                   f"{cam.height}), not this camera's calibration; set camera.fx/fy/cx/cy or --camera NAME")
        return k, "config camera section"

    def recorded_frames(self) -> RecordedFrames:
        """The recording's camera, static tf chain and pose frame ids (``sources.tf``), in short passes."""
        ch = self.choices
        camera = self.first_color_frame_id() or ""
        try:
            static = tf.static_tree(self.decoded(TF_STATIC)) if TF_STATIC in self.topics else {}
        except tf_tree.TfTreeError as err:
            raise DatasetError(self.path, f"{TF_STATIC}: {err}") from err
        pose_frame = ""
        if ch.pose.topic and ch.pose_type == TF:
            try:
                pose_frame = tf.tf_root(self.decoded(ch.pose.topic), static, self.cfg.pose_frame or camera)
            except tf_tree.TfTreeError as err:
                raise DatasetError(self.path, f"{ch.pose.topic}: {err}") from err
        elif ch.pose.topic:
            pose_frame = tf.first_pose_frame(self.decoded(ch.pose.topic))
        return tf.recorded_frames(camera, static, pose_frame, ch.pose_type == TF)

    def pose_stamps(self, limit: int) -> list[int]:
        """The header stamps of the first ``limit`` poses on the pose topic (every transform's, for /tf)."""
        ch = self.choices
        out: list[int] = []
        if not ch.pose.topic:
            return out
        messages = self.decoded(ch.pose.topic)
        try:
            for m in messages:
                try:
                    out += [s for s, *_ in decode.decode_tf(m)] if ch.pose_type == TF else [decode.decode_pose(m)[0]]
                except (DecodeError, AttributeError):
                    continue
                if len(out) >= limit:
                    break
        finally:
            messages.close()  # its recording pass ends here
        return out[:limit]

    def decoded(self, topic: str) -> Generator[Message, None, None]:
        """The deserialised messages of one topic (undecodable ones skipped), closed when left early."""
        with closing(self.log.read([topic])) as messages:
            for msg in messages:
                try:
                    yield self.log.deserialize(msg.topic, msg.data)
                except DecodeError:
                    continue

    def first_color_frame_id(self) -> str | None:
        """The colour header's frame_id, read from the first colour message (for tf composition)."""
        ch = self.choices
        for msg in self.log.read([ch.color.topic] if ch.color.topic else []):
            try:
                return decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))[1] or None
            except DecodeError:
                return None
        return None


def _stream_prefix(topic: str | None) -> str:
    """``/device_0/sensor_0/Depth_0/image/data`` -> ``/device_0/sensor_0/Depth_0`` (a RealSense recorder's
    stream), else ''."""
    return topic[: -len("/image/data")] if topic and topic.endswith("/image/data") else ""
