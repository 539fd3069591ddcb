"""A ``Recording`` over any time-ordered message log (ROS 1/2 bags, MCAP): choose, pair, decode.

The format readers (rosbag.py, mcap.py) only list topics, stream raw messages and
deserialise one on request. Here: colour and depth stamps are read from the raw
header bytes, paired in a bounded window (sync.StreamPairer), and only paired
messages are deserialised and decoded into a ``Frame``. Poses (PoseStamped,
Odometry, tf with tf_static) are kept in a pruned PoseTrack; recorded map clouds
(``slam.points_topic``) are decoded in the same pass and carried by the frame they belong
to (clouds.CloudBuffer), so nothing else opens the recording again to read them.
"""

from __future__ import annotations

import abc
import logging
import re
from collections import deque
from collections.abc import Collection, Generator, Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slzcli.config import Config
from slzcli.errors import DatasetError, DecodeError, SlzError
from slzcli.sources import decode, tf, tf_tree
from slzcli.sources.clouds import CloudBuffer
from slzcli.sources.color_camera import ALIGNED, DepthToColor, extrinsics, same_camera, to_color_camera
from slzcli.sources.image_limits import FrameTooLarge
from slzcli.sources.presets import PresetChoice, choose_preset
from slzcli.sources.recording import Recording, RecordingInfo
from slzcli.sources.sync import Pair, PoseTrack, Stream, StreamPairer
from slzcli.sources.topics import (
    COMPRESSED,
    IMAGE,
    ODOMETRY,
    POSE_STAMPED,
    TF,
    TRANSFORM,
    Choices,
    choose_streams,
    normalise_msgtype,
)
from slzcli.sources.undistort import distortion_problem, has_distortion
from slzcli.sources.validate import (
    StampCounts,
    depth_shape_problem,
    info_frame_problem,
    intrinsics_problem,
    pixel_aspect_problem,
    size_problem,
    stamp_problem,
)
from slzcli.sources.window import WindowFilter
from slzcli.types import Frame, Intrinsics, MapCloud, PairingReport, RecordedFrames, StreamInfo

log = logging.getLogger(__name__)
NS_PER_MS = 1_000_000
TF_STATIC = "/tf_static"
# How far (log time) past the first image the pre-pass looks for the depth CameraInfo and /tf_static
# (both are published at start-up, tf_static latched); project decision.
SETUP_SCAN_NS = 5 * 1_000_000_000
# A RealSense recorder's depth unit (std_msgs/Float32, metres per count): librealsense's ros-bag format.
DEPTH_UNITS_TOPIC = re.compile(r"/device_\d+/sensor_\d+/option/Depth_Units/value")


@dataclass(frozen=True)
class RawMessage:
    """One serialised message as stored; ``log_ns`` is the recording (receive) time."""

    topic: str
    log_ns: int
    data: Any


class MessageLog(abc.ABC):
    """The format-specific part: topics, raw messages in log-time order, deserialisation."""

    format: str = ""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.warnings: list[str] = []

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def topics(self) -> dict[str, str]:
        """topic -> message type name as stored."""

    @abc.abstractmethod
    def is_ros1(self, topic: str) -> bool:
        """Whether the topic's messages use the ROS 1 wire format (else CDR)."""

    @abc.abstractmethod
    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        """Messages of ``topics`` (all when empty) in log-time order, streamed."""

    @abc.abstractmethod
    def deserialize(self, topic: str, data: Any) -> Any: ...


class MessageRecording(Recording):
    """Frames from a MessageLog, streamed with bounded memory."""

    def __init__(self, msglog: MessageLog, config: Config) -> None:
        super().__init__(msglog.path)
        self.log = msglog
        self.config = config
        self.cfg = config.sources
        self.choices: Choices | None = None
        self._topics: dict[str, str] = {}
        self._camera_frame: str | None = None
        self.preset = PresetChoice(None, "")
        self.camera_warnings: list[str] = []   # fallbacks: each logged once and listed in RecordingInfo.warnings
        self._d2c: DepthToColor | None = None
        self._unit: float | None = None

    # ------------------------------------------------------------------ open / close
    def open(self) -> None:
        self.log.open()
        self._topics = self.log.topics()
        if not self._topics:
            why = self.log.warnings[0] if self.log.warnings else "empty or not a recording"
            raise DatasetError(self.path, f"the recording has no readable topics ({why})")
        self.preset = choose_preset(self.config.camera.preset, topics=list(self._topics))
        self.choices = choose_streams(self._topics, self.cfg, str(self.path), self._peek_encodings(),
                                      self.preset.preset)

    def close(self) -> None:
        self.log.close()

    def _warn(self, text: str) -> None:
        """A fallback: one warning line on stderr and in RecordingInfo.warnings (run.json), however often met."""
        if text not in self.camera_warnings:
            self.camera_warnings.append(text)
            log.warning("%s: %s", self.path, text)

    def _depth_unit_m(self) -> float:
        """Metres per 16-bit depth count: the recording's own (a RealSense recorder's Depth_Units option),
        else ``sources.depth_unit_16u_m``."""
        if self._unit is None:
            self._unit = self.cfg.depth_unit_16u_m
            topic = next((t for t in sorted(self._topics) if DEPTH_UNITS_TOPIC.fullmatch(t)), None)
            if topic is not None:
                with closing(self._wrap(self.log.messages([topic]))) as messages:
                    for msg in messages:
                        try:
                            value = float(self.log.deserialize(msg.topic, msg.data).data)
                        except (DecodeError, AttributeError, TypeError, ValueError) as err:
                            self._warn(f"{topic}: not a depth unit ({err}): sources.depth_unit_16u_m used")
                            break
                        if 0 < value < 1:
                            self._unit = value
                        else:
                            self._warn(f"{topic}: depth unit {value!r} m is not usable: sources.depth_unit_16u_m used")
                        break
        return self._unit

    def _depth_to_color(self) -> DepthToColor:
        """How depth reaches the colour grid, decided once from the first messages (warnings for fallbacks)."""
        if self._d2c is None:
            self._check_info_frames(self._need_choices())
            self._d2c = self._find_depth_to_color(self._need_choices())
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
        with closing(self._wrap(self.log.messages(sorted(wanted)))) as messages:
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
            self._warn(f"{ch.depth.topic} is not aligned to colour and has no CameraInfo of its own: resized "
                       "nearest-neighbour to the colour image (geometry approximate); set sources.topics.depth_info")
            return DepthToColor("resize", describe="resized nearest-neighbour (no depth CameraInfo)")
        k_depth, k_color, frames, tree, stream_tf = self._scan_setup(ch)
        if k_depth is None:
            self._warn(f"no usable CameraInfo on {ch.depth_info.topic}: depth resized nearest-neighbour to the "
                       "colour image (geometry approximate)")
            return DepthToColor("resize", describe="resized nearest-neighbour (depth CameraInfo unusable)")
        problem = distortion_problem(k_depth)
        if problem is not None:
            self._warn(f"CameraInfo on {ch.depth_info.topic}: {problem}")
        T, source = self._depth_extrinsics(ch, frames, tree, stream_tf)
        if T is None:
            self._warn(f"no depth->colour extrinsics ({source}): depth reprojected as if both cameras shared "
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
        stream_topics = [t for t, m in self._topics.items() if normalise_msgtype(m) == TRANSFORM and "/tf/" in t]
        wanted = {t for t in (ch.depth_info.topic, ch.camera_info.topic, ch.color.topic, ch.depth.topic) if t}
        wanted |= set(stream_topics) | ({TF_STATIC} if TF_STATIC in self._topics else set())
        k_depth = k_color = None
        frames: dict[str, str] = {}
        tree: dict[str, tuple[str, np.ndarray]] = {}
        stream_tf: dict[str, np.ndarray] = {}
        first_image: int | None = None
        with closing(self._wrap(self.log.messages(sorted(wanted)))) as messages:
            for msg in messages:
                try:
                    if msg.topic in (ch.color.topic, ch.depth.topic):
                        role = "color" if msg.topic == ch.color.topic else "depth"
                        frames.setdefault(role, decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))[1])
                        first_image = msg.log_ns if first_image is None else first_image
                    elif msg.topic == ch.depth_info.topic and k_depth is None:
                        k_depth = self._check_info(msg.topic, decode.decode_camera_info(
                            self.log.deserialize(msg.topic, msg.data)))
                    elif msg.topic == ch.camera_info.topic and k_color is None:
                        k_color = decode.decode_camera_info(self.log.deserialize(msg.topic, msg.data))
                    elif msg.topic == TF_STATIC:
                        tf_tree.add_edges(tree, decode.decode_tf(self.log.deserialize(msg.topic, msg.data)))
                    elif msg.topic in stream_topics and msg.topic not in stream_tf:
                        m = self.log.deserialize(msg.topic, msg.data)
                        stream_tf[msg.topic] = decode.transform_matrix(m.translation, m.rotation)
                except DecodeError as err:
                    self._warn(f"{msg.topic}: {err} (while reading the camera set-up)")
                except tf_tree.TfTreeError as err:
                    raise DatasetError(self.path, f"{msg.topic}: {err}") from err
                have_all = k_depth is not None and len(frames) == 2 and (k_color or not ch.camera_info.topic)
                if have_all and (len(stream_tf) >= 2 or extrinsics(tree, frames["color"], frames["depth"])[0]
                                 is not None):
                    break
                if first_image is not None and msg.log_ns - first_image > SETUP_SCAN_NS:
                    break
        return k_depth, k_color, frames, tree, stream_tf

    def _need_choices(self) -> Choices:
        if self.choices is None:
            raise DatasetError(self.path, "recording is not open (use it as a context manager)")
        return self.choices

    def _wrap(self, it: Iterator[RawMessage]) -> Generator[RawMessage, None, None]:
        try:
            yield from it
        except SlzError:
            raise
        except Exception as err:  # third-party reader errors, wrapped once here
            raise DatasetError(self.path, f"cannot read messages ({type(err).__name__}: {err})") from err

    def _peek_encodings(self) -> dict[str, str]:
        """The encoding of the first message of each Image topic, when there are more image topics
        than the colour and the depth stream (so that the choice cannot go by name alone)."""
        types = {t: normalise_msgtype(m) for t, m in self._topics.items()}
        images = [t for t, m in types.items() if m == IMAGE]
        if sum(m in (IMAGE, COMPRESSED) for m in types.values()) <= 2 or not images:
            return {}
        found: dict[str, str] = {}
        with closing(self._wrap(self.log.messages(images))) as messages:
            for msg in messages:
                if msg.topic not in found:
                    try:
                        found[msg.topic] = str(getattr(self.log.deserialize(msg.topic, msg.data), "encoding", ""))
                    except DecodeError:
                        found[msg.topic] = ""
                if len(found) == len(images):
                    break
        return found

    def _stamp(self, msg: RawMessage, counts: StampCounts | None = None) -> tuple[int, str] | None:
        """(stamp, frame_id) of a colour or depth message; None (counted) when the stamp is unusable.

        Header stamp 0: the log time. Negative, or beyond int64 ns: skipped. DecodeError when the
        message is too short to hold a header.
        """
        stamp, frame = decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))
        counts = counts if counts is not None else StampCounts()
        counts.messages += 1
        if stamp == 0:
            counts.zero += 1
            stamp = msg.log_ns
        problem = stamp_problem(stamp)
        if problem is not None:
            counts.out_of_range += 1
            counts.first_out_of_range = counts.first_out_of_range or problem
            return None
        return stamp, frame

    def _check_info(self, topic: str, k: Intrinsics) -> Intrinsics:
        """A decoded CameraInfo, checked: DatasetError naming the topic when it cannot be used."""
        lim = self.cfg.intrinsics
        problem = intrinsics_problem(k, lim.min_fov_deg, lim.max_fov_deg)
        if problem is not None:
            raise DatasetError(self.path, f"CameraInfo on {topic}: {problem}; fix the camera's calibration, or set "
                                          "sources.topics.camera_info to another CameraInfo topic")
        problem = pixel_aspect_problem(k, lim.max_pixel_aspect)
        if problem is not None:
            self._warn(f"CameraInfo on {topic}: {problem}")
        return k

    def _stamp_report(self, ch: Choices, counts: dict[str, StampCounts], pairer: StreamPairer) -> list[str]:
        """One line per stream and kind of stamp problem, with its count."""
        lines = []
        for role, topic in (("color", ch.color.topic), ("depth", ch.depth.topic)):
            c = counts[role]
            c.repeated = pairer.repeated[role]
            lines += [f"{topic}: {p}" for p in c.problems()]
        if pairer.late:
            lines.append(f"{pairer.late} colour/depth message(s) arrived later than sources.reorder_window_ms "
                         "allows and were not paired")
        return lines

    # ------------------------------------------------------------------ info
    def info(self) -> RecordingInfo:
        ch = self._need_choices()
        counts: dict[str, list[int]] = {t: [0, 0, 0] for t in self._topics}  # count, first, last
        pairer = StreamPairer(int(self.cfg.sync_tolerance_ms * NS_PER_MS), int(self.cfg.reorder_window_ms * NS_PER_MS))
        intrinsics: Intrinsics | None = None
        undecodable = 0
        info_failed = False
        first = last = None
        stamps = {"color": StampCounts(), "depth": StampCounts()}
        win = WindowFilter(self.config.sources.window)  # info counts the frames within the window
        for msg in self._wrap(self.log.messages(())):
            c = counts.setdefault(msg.topic, [0, 0, 0])
            c[1] = msg.log_ns if c[0] == 0 else min(c[1], msg.log_ns)
            c[2] = max(c[2], msg.log_ns)
            c[0] += 1
            first = msg.log_ns if first is None else min(first, msg.log_ns)
            last = msg.log_ns if last is None else max(last, msg.log_ns)
            if msg.topic in (ch.color.topic, ch.depth.topic):
                role: Stream = "color" if msg.topic == ch.color.topic else "depth"
                try:
                    stamped = self._stamp(msg, stamps[role])
                except DecodeError:
                    undecodable += 1
                    continue
                if stamped is not None:
                    for pair in pairer.push(role, stamped[0], msg.data):
                        win.keep(pair.stamp_ns)
            elif msg.topic == ch.camera_info.topic and intrinsics is None:
                try:
                    intrinsics = self._check_info(msg.topic, decode.decode_camera_info(
                        self.log.deserialize(msg.topic, msg.data)))
                except DecodeError as err:  # reported once (a later CameraInfo may still be good), not fatal
                    if not info_failed:
                        log.warning("%s: CameraInfo on %s not decodable: %s", self.path, msg.topic, err)
                    info_failed = True
        for pair in pairer.flush():
            win.keep(pair.stamp_ns)
        streams = tuple(StreamInfo(t, self._topics.get(t, "?"), c[0], c[1] if c[0] else None, c[2] if c[0] else None)
                        for t, c in sorted(counts.items()))
        source = f"CameraInfo on {ch.camera_info.topic}" if intrinsics is not None else ""
        if intrinsics is None:
            intrinsics, source = self._fallback_intrinsics()
        problem = distortion_problem(intrinsics)
        if problem is not None:
            self._warn(f"{source}: {problem}")
        elif has_distortion(intrinsics):
            source += f"; {intrinsics.distortion_model} distortion removed from every frame"
        d2c = self._depth_to_color()
        stamp_lines = self._stamp_report(ch, stamps, pairer)
        for line in stamp_lines:
            log.warning("%s: %s", self.path, line)
        report = self._report(pairer, 0, undecodable, tuple(stamp_lines), win)
        return RecordingInfo(str(self.path), self.log.format, ((last or 0) - (first or 0)) * 1e-9, streams,
                             ch.all(), intrinsics, source, report,
                             tuple(self.log.warnings) + tuple(self.camera_warnings), self.preset.name,
                             self.preset.reason, d2c.describe)

    def _fallback_intrinsics(self) -> tuple[Intrinsics, str]:
        """Intrinsics without a CameraInfo: the camera preset's, else the config camera section (a warning)."""
        preset = self.preset.preset
        if preset is not None and preset.intrinsics is not None:
            return preset.intrinsics, f"camera preset {preset.name} (no CameraInfo)"
        cam = self.config.camera
        k = Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        self._warn(f"no usable CameraInfo: intrinsics from the config camera section (fx {cam.fx:g} px, {cam.width}x"
                   f"{cam.height}), not this camera's calibration; set camera.fx/fy/cx/cy or --camera NAME")
        return k, "config camera section"

    def _report(self, pairer: StreamPairer, without_pose: int, undecodable: int,
                notes: tuple[str, ...], win: WindowFilter) -> PairingReport:
        extra: tuple[str, ...] = ()
        if pairer.duplicates:
            extra += (f"{pairer.duplicates} duplicated colour/depth message(s) (same topic and stamp) were dropped",)
        window_note = win.note()
        extra += (window_note,) if window_note else ()
        apart = pairer.never_paired()
        extra += (apart,) if apart else ()
        return PairingReport(pairer.paired - win.left_out, pairer.unpaired["color"], pairer.unpaired["depth"],
                             without_pose, undecodable, tuple(notes) + extra + tuple(self.log.warnings),
                             win.left_out)

    # ------------------------------------------------------------------ frames
    def frames(self) -> Iterator[Frame]:
        """The frames (see Recording); a configured points topic missing from the recording is refused here."""
        ch = self._need_choices()
        points = self.config.slam.points_topic
        if points and points not in self._topics:
            raise DatasetError(self.path, f"slam.points_topic {points!r} is not in the recording")
        # Settled before the pass: both read messages of their own, which must not happen inside it.
        self._depth_to_color()
        self._depth_unit_m()
        return self._frames(ch, points)

    def _frames(self, ch: Choices, points_topic: str) -> Iterator[Frame]:
        cfg = self.cfg
        tol_pose = int(cfg.pose_tolerance_ms * NS_PER_MS)
        window = int(cfg.reorder_window_ms * NS_PER_MS)
        pairer = StreamPairer(int(cfg.sync_tolerance_ms * NS_PER_MS), window)
        state = _FrameState(CloudBuffer(tol_pose) if points_topic else None, self.quiet_frames)
        poses = _PoseSource(self, ch, PoseTrack(tol_pose), state)
        topics = {t for t in (ch.color.topic, ch.depth.topic, ch.camera_info.topic, ch.pose.topic, points_topic) if t}
        if ch.pose_type in (TF, ODOMETRY) and TF_STATIC in self._topics:
            topics.add(TF_STATIC)
        pending: deque[Pair] = deque()
        newest: int | None = None
        # A frame waits until no pose (nor cloud) within the pose tolerance of its stamp can still arrive.
        has_pose = ch.pose.topic is not None or state.clouds is not None
        stamps = {"color": StampCounts(), "depth": StampCounts()}
        win = WindowFilter(self.config.sources.window)  # pairs outside it are never decoded
        for msg in self._wrap(self.log.messages(topics)):
            if msg.topic in (ch.color.topic, ch.depth.topic):
                is_color = msg.topic == ch.color.topic
                try:
                    stamped = self._stamp(msg, stamps["color" if is_color else "depth"])
                except DecodeError as err:
                    state.undecodable(self.path, msg.topic, err)
                    continue
                if stamped is None:
                    continue
                stamp, frame_id = stamped
                if is_color and poses.camera_frame is None:
                    poses.camera_frame = cfg.pose_frame or frame_id
                pending.extend(p for p in pairer.push("color" if is_color else "depth", stamp, msg)
                               if win.keep(p.stamp_ns))
                newest = stamp if newest is None else max(newest, stamp)
            elif msg.topic == ch.camera_info.topic:
                try:
                    state.info = self._check_info(msg.topic, decode.decode_camera_info(
                        self.log.deserialize(msg.topic, msg.data)))
                    state.info_source = f"CameraInfo on {msg.topic}"
                except DecodeError as err:
                    state.note(f"CameraInfo on {msg.topic} not usable: {err}")
            elif msg.topic == points_topic and state.clouds is not None:
                state.clouds.add(self._cloud(msg))
            else:
                poses.feed(msg)
            horizon = None if newest is None else newest - window - (tol_pose if has_pose else 0)
            while pending and (not has_pose or (horizon is not None and pending[0].stamp_ns < horizon)):
                frame = self._decode(pending.popleft(), state, poses)
                if frame is not None:
                    yield frame
            if has_pose and newest is not None:
                # Poses older than any frame still to come are not needed (memory stays bounded).
                keep = [newest - window, *([pending[0].stamp_ns] if pending else []),
                        *([pairer.oldest_ns] if pairer.oldest_ns is not None else [])]
                poses.track.prune(min(keep) - tol_pose)
                if state.clouds is not None:
                    state.clouds.prune(min(keep) - tol_pose)
            if not pending and win.done():  # pairs come out in stamp order: none to come is in the window
                break
        pending.extend(p for p in pairer.flush() if win.keep(p.stamp_ns))
        while pending:
            frame = self._decode(pending.popleft(), state, poses)
            if frame is not None:
                yield frame
        state.pose_summary()
        state.note_too_large(cfg.max_image_px)
        if state.clouds is not None and state.clouds.late:
            state.note(f"{state.clouds.late} map cloud(s) on {points_topic} were logged later than "
                       "sources.reorder_window_ms after the images of their time and went to no frame")
        notes = tuple(state.notes) + tuple(self._stamp_report(ch, stamps, pairer))
        self.report = self._report(pairer, state.without_pose, state.n_undecodable, notes, win)
        if self.log.warnings:
            log.warning("%s: %d frames recovered (%s)", self.path, state.yielded, "; ".join(self.log.warnings))
        if state.yielded == 0 and state.first_error is not None:
            raise DatasetError(self.path, f"no frame could be decoded: {state.first_error}")
        bad_stamps = [c.first_out_of_range for c in stamps.values() if c.out_of_range]
        if state.yielded == 0 and bad_stamps:
            raise DatasetError(self.path, f"no frame has a usable stamp (first: {bad_stamps[0]})")

    def _cloud(self, msg: RawMessage) -> MapCloud:
        """One recorded map cloud, decoded; DatasetError naming the topic when it cannot be."""
        try:
            m = self.log.deserialize(msg.topic, msg.data)
            xyz, ids = decode.decode_pointcloud2(m)
            return MapCloud(decode.stamp_ns(m.header), xyz, ids)
        except DecodeError as err:
            raise DatasetError(self.path, f"{msg.topic}: {err}") from err

    def recorded_frames(self) -> RecordedFrames:
        """The recording's camera, static tf chain and pose frame ids (``sources.tf``), in short passes."""
        ch = self._need_choices()
        camera = self._first_color_frame_id() or ""
        try:
            static = tf.static_tree(self._decoded(TF_STATIC)) if TF_STATIC in self._topics else {}
        except tf_tree.TfTreeError as err:
            raise DatasetError(self.path, f"{TF_STATIC}: {err}") from err
        pose_frame = ""
        if ch.pose.topic and ch.pose_type == TF:
            try:
                pose_frame = tf.tf_root(self._decoded(ch.pose.topic), static, self.cfg.pose_frame or camera)
            except tf_tree.TfTreeError as err:
                raise DatasetError(self.path, f"{ch.pose.topic}: {err}") from err
        elif ch.pose.topic:
            pose_frame = tf.first_pose_frame(self._decoded(ch.pose.topic))
        return tf.recorded_frames(camera, static, pose_frame, ch.pose_type == TF)

    def pose_stamps(self, limit: int) -> list[int]:
        """The header stamps of the first ``limit`` poses on the pose topic (every transform's, for /tf)."""
        ch = self._need_choices()
        out: list[int] = []
        if not ch.pose.topic:
            return out
        messages = self._decoded(ch.pose.topic)
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

    def _decoded(self, topic: str) -> Generator[Any, None, None]:
        """The deserialised messages of one topic (undecodable ones skipped), closed when left early."""
        with closing(self._wrap(self.log.messages([topic]))) as messages:
            for msg in messages:
                try:
                    yield self.log.deserialize(msg.topic, msg.data)
                except DecodeError:
                    continue

    def _first_color_frame_id(self) -> str | None:
        """The colour header's frame_id, read from the first colour message (for tf composition)."""
        ch = self._need_choices()
        for msg in self._wrap(self.log.messages([ch.color.topic] if ch.color.topic else [])):
            try:
                return decode.header_stamp(msg.data, self.log.is_ros1(msg.topic))[1] or None
            except DecodeError:
                return None
        return None

    def _decode(self, pair: Pair, state: _FrameState, poses: _PoseSource) -> Frame | None:
        ch = self._need_choices()
        try:
            max_px = self.cfg.max_image_px
            rgb = decode.decode_color(self.log.deserialize(pair.color.topic, pair.color.data), max_px)
            depth = decode.decode_depth(self.log.deserialize(pair.depth.topic, pair.depth.data),
                                        self._depth_unit_m(), self.cfg.max_depth_m, max_px)
        except DecodeError as err:
            where = f"{ch.color.topic} / {ch.depth.topic}"
            if isinstance(err, FrameTooLarge):
                where += f", frame at stamp {pair.stamp_ns // 10**9}.{pair.stamp_ns % 10**9:09d}"
            state.undecodable(self.path, where, err)
            return None
        h, w = rgb.shape[:2]
        d2c = self._depth_to_color()
        problem = None if d2c.mode == "register" else depth_shape_problem(
            depth.shape[1], depth.shape[0], w, h, self.cfg.intrinsics.aspect_tolerance)
        if problem is not None:
            raise DatasetError(self.path, f"frame {state.yielded} ({ch.depth.topic}): {problem}")
        if depth.shape != (h, w) and d2c.mode != "register":
            state.note(f"depth {depth.shape[1]}x{depth.shape[0]} resized nearest-neighbour to colour {w}x{h} "
                       f"({d2c.describe})")
        intr = state.info
        if intr is None:
            intr, state.info_source = self._fallback_intrinsics()
            state.note(f"no CameraInfo before the first frame: intrinsics from the {state.info_source}")
        problem = distortion_problem(intr)
        if problem is not None:
            self._warn(f"{state.info_source}: {problem}")
        problem = size_problem(intr, w, h, self.cfg.intrinsics.aspect_tolerance)
        if problem is not None:
            raise DatasetError(self.path, f"frame {state.yielded} ({ch.color.topic}): {state.info_source}: {problem}")
        if (intr.width, intr.height) != (w, h):
            state.note(f"intrinsics for {intr.width}x{intr.height} scaled to the colour size {w}x{h}")
            intr = intr.scaled(w, h)
        if d2c.mode == "register" and d2c.k_depth is not None:
            problem = size_problem(d2c.k_depth, depth.shape[1], depth.shape[0], self.cfg.intrinsics.aspect_tolerance)
            if problem is not None:
                raise DatasetError(self.path, f"frame {state.yielded} ({ch.depth.topic}): CameraInfo on "
                                              f"{ch.depth_info.topic}: {problem}")
        rgb, depth, intr = to_color_camera(rgb, depth, intr, d2c)
        T = poses.track.at(pair.stamp_ns) if ch.pose.topic else None
        if ch.pose.topic and T is None:
            state.without_pose += 1
        # A cloud is placed with its frame's pose: a frame without one leaves it to the next.
        cloud = state.clouds.take(pair.stamp_ns) if state.clouds is not None and T is not None else None
        frame = Frame(state.yielded, pair.stamp_ns, rgb, depth, intr, T, str(self.path), cloud)
        state.yielded += 1
        return frame


class _FrameState:
    """Mutable bookkeeping of one ``frames()`` pass (notes are de-duplicated, in order)."""

    def __init__(self, clouds: CloudBuffer | None = None, quiet: bool = False) -> None:
        self.clouds = clouds
        self.quiet = quiet  # a look-ahead pass (Recording.quiet_frames): count, warn nothing
        self.info: Intrinsics | None = None
        self.info_source = ""
        self.yielded = 0
        self.bad_poses = 0
        self.first_bad_pose = ""
        self.without_pose = 0
        self.n_undecodable = 0
        self.n_too_large = 0
        self.first_error: str | None = None
        self.notes: list[str] = []

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)
            log.info("%s", text)

    def bad_pose(self, path: Path, topic: str, err: Exception) -> None:
        """A pose message that cannot be used: warned about once, then counted (pose_summary)."""
        self.bad_poses += 1
        if not self.first_bad_pose:
            self.first_bad_pose = f"pose on {topic} not usable: {err}"
            self._warning("%s: %s (the frames it would pose carry none; further unusable poses are counted, not "
                          "shown)", path, self.first_bad_pose)

    def pose_summary(self) -> None:
        if self.bad_poses:
            self.note(f"{self.bad_poses} pose message(s) not usable (first: {self.first_bad_pose})")

    def undecodable(self, path: Path, topic: str, err: Exception) -> None:
        self.n_undecodable += 1
        if self.first_error is None:
            self.first_error = f"{topic}: {err}"
        if isinstance(err, FrameTooLarge):  # its own one warning: an oversized frame is not a torn message
            self.n_too_large += 1
            if self.n_too_large == 1:
                self._warning("%s: %s: %s; skipped (further frames over the bound are counted, not shown)", path,
                              topic, err)
        elif self.n_undecodable - self.n_too_large == 1:
            self._warning("%s: %s: %s (further decode errors are counted, not shown)", path, topic, err)

    def _warning(self, fmt: str, *args: object) -> None:
        if not self.quiet:
            log.warning(fmt, *args)

    def note_too_large(self, max_px: int) -> None:
        """The count of frames skipped for their size, in the run's notes (run.json summary.pairing)."""
        if self.n_too_large:
            self.note(f"{self.n_too_large} frame(s) over sources.max_image_px {max_px} px were skipped")


class _PoseSource:
    """Turns pose messages into T_world_camera samples on a PoseTrack (tf chains composed)."""

    def __init__(self, rec: MessageRecording, ch: Choices, track: PoseTrack, state: _FrameState) -> None:
        self.rec = rec
        self.state = state
        self.ch = ch
        self.track = track
        self.camera_frame: str | None = rec.cfg.pose_frame or None
        self.static: dict[str, tuple[str, np.ndarray]] = {}
        self.dynamic: dict[str, tuple[str, np.ndarray]] = {}
        if ch.pose_type in (TF, ODOMETRY) and self.camera_frame is None:
            self.camera_frame = rec._first_color_frame_id()

    def _tree(self) -> dict[str, tuple[str, np.ndarray]]:
        return {**self.dynamic, **self.static}

    def feed(self, msg: RawMessage) -> None:
        try:
            m = self.rec.log.deserialize(msg.topic, msg.data)
            if msg.topic == TF_STATIC:
                for _, parent, child, T in decode.decode_tf(m):
                    tf_tree.add_edge(self._tree(), parent, child, T)  # checked against /tf too; the copy is dropped
                    self.static[child] = (parent, T)
            elif self.ch.pose_type == TF:
                self._feed_tf(decode.decode_tf(m))
            elif self.ch.pose_type in (POSE_STAMPED, ODOMETRY):
                self._feed_pose(*decode.decode_pose(m))
        except DecodeError as err:
            self.state.bad_pose(self.rec.path, msg.topic, err)
        except tf_tree.TfTreeError as err:
            raise DatasetError(self.rec.path, f"{msg.topic}: {err}; fix the recording's tf broadcasters "
                                              "(see docs/FAILURE_MODES.md)") from err

    def _feed_tf(self, transforms: list[tuple[int, str, str, np.ndarray]]) -> None:
        if not self.camera_frame:
            return
        for _, parent, child, T in transforms:
            tf_tree.add_edge(self._tree(), parent, child, T)  # checked against /tf and /tf_static together
            self.dynamic[child] = (parent, T)
        tree = self._tree()
        chain = _chain_frames(tree, self.camera_frame)
        stamps = [s for s, _, child, _ in transforms if child in chain]
        if stamps:
            top, T = decode.compose_chain(tree, self.camera_frame)  # type: ignore[misc]
            if top != self.camera_frame:
                self.track.add(max(stamps), T)

    def _feed_pose(self, stamp: int, parent: str, child: str, T: np.ndarray) -> None:
        if child and self.camera_frame and child != self.camera_frame:
            link = decode.compose_chain(self._tree(), self.camera_frame, stop_at=child)
            if link is not None:
                T = T @ link[1]
            else:
                self.state.note(f"pose frame {child!r} has no tf link to camera frame {self.camera_frame!r}: "
                                "its pose is used as the camera pose")
        self.track.add(stamp, T)


def _stream_prefix(topic: str | None) -> str:
    """``/device_0/sensor_0/Depth_0/image/data`` -> ``/device_0/sensor_0/Depth_0`` (a RealSense recorder's
    stream), else ''."""
    return topic[: -len("/image/data")] if topic and topic.endswith("/image/data") else ""


def _chain_frames(tree: dict[str, tuple[str, np.ndarray]], frame: str) -> set[str]:
    out, node = set(), frame
    while node in tree and node not in out:
        out.add(node)
        node = tree[node][0]
    return out
