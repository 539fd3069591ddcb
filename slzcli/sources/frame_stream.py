"""The stream of a message recording: one pass over the chosen topics that pairs colour and depth by
stamp in a bounded window (``sync.StreamPairer``), decodes only the paired messages into ``Frame``s with
what the setup scan decided (``camera_setup.py``), poses them from a pruned ``PoseTrack`` (PoseStamped,
Odometry, tf with tf_static) and carries the recorded map clouds (``slam.points_topic``) decoded in the
same pass (``clouds.CloudBuffer``), so nothing else opens the recording again to read them. Memory stays
bounded whatever the recording's length.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from slzcli.errors import DatasetError, DecodeError
from slzcli.sources import decode, tf_tree
from slzcli.sources.camera_setup import TF_STATIC, CameraSetup
from slzcli.sources.clouds import CloudBuffer
from slzcli.sources.color_camera import to_color_camera
from slzcli.sources.image_limits import FrameTooLarge
from slzcli.sources.message_log import MessageLog, RawMessage
from slzcli.sources.sync import P, Pair, PoseTrack, StreamPairer
from slzcli.sources.topics import ODOMETRY, POSE_STAMPED, TF, Choices
from slzcli.sources.undistort import distortion_problem
from slzcli.sources.validate import StampCounts, depth_shape_problem, size_problem, stamp_problem
from slzcli.sources.window import WindowFilter
from slzcli.types import Frame, Intrinsics, MapCloud, PairingReport

log = logging.getLogger(__name__)
NS_PER_MS = 1_000_000


def stamp_of(msglog: MessageLog, msg: RawMessage, counts: StampCounts | None = None) -> tuple[int, str] | None:
    """(stamp, frame_id) of a colour or depth message; None (counted) when the stamp is unusable.

    Header stamp 0: the log time. Negative, or beyond int64 ns: skipped. DecodeError when the
    message is too short to hold a header.
    """
    stamp, frame = decode.header_stamp(msg.data, msglog.is_ros1(msg.topic))
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


def stamp_report(ch: Choices, counts: dict[str, StampCounts], pairer: StreamPairer[P]) -> list[str]:
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



def pairing_report(msglog: MessageLog, pairer: StreamPairer[P], without_pose: int, undecodable: int,
            notes: tuple[str, ...], win: WindowFilter) -> PairingReport:
    extra: tuple[str, ...] = ()
    if pairer.duplicates:
        extra += (f"{pairer.duplicates} duplicated colour/depth message(s) (same topic and stamp) were dropped",)
    window_note = win.note()
    extra += (window_note,) if window_note else ()
    apart = pairer.never_paired()
    extra += (apart,) if apart else ()
    return PairingReport(pairer.paired - win.left_out, pairer.unpaired["color"], pairer.unpaired["depth"],
                         without_pose, undecodable, tuple(notes) + extra + tuple(msglog.warnings),
                         win.left_out)



class FrameStream:
    """One ``frames()`` pass of an open message recording (``quiet``: a look-ahead pass, see
    ``Recording.quiet_frames``)."""

    def __init__(self, setup: CameraSetup, quiet: bool,
                 on_report: Callable[[PairingReport, list[str]], None]) -> None:
        self.setup = setup
        self.log = setup.log
        self.path = setup.path
        self.config = setup.config
        self.cfg = setup.cfg
        self.quiet = quiet
        self.on_report = on_report

    def frames(self, points_topic: str) -> Iterator[Frame]:
        """Paired, decoded frames in stamp order; ``on_report`` gets the pairing report and its stamp problems
        when the pass ends."""
        ch = self.setup.choices
        cfg = self.cfg
        tol_pose = int(cfg.pose_tolerance_ms * NS_PER_MS)
        window = int(cfg.reorder_window_ms * NS_PER_MS)
        pairer = StreamPairer[RawMessage](int(cfg.sync_tolerance_ms * NS_PER_MS), window)
        state = _FrameState(CloudBuffer(tol_pose) if points_topic else None, self.quiet)
        poses = _PoseSource(self, ch, PoseTrack(tol_pose), state)
        topics = {t for t in (ch.color.topic, ch.depth.topic, ch.camera_info.topic, ch.pose.topic, points_topic) if t}
        if ch.pose_type in (TF, ODOMETRY) and TF_STATIC in self.setup.topics:
            topics.add(TF_STATIC)
        pending: deque[Pair[RawMessage]] = deque()
        newest: int | None = None
        # A frame waits until no pose (nor cloud) within the pose tolerance of its stamp can still arrive.
        has_pose = ch.pose.topic is not None or state.clouds is not None
        stamps = {"color": StampCounts(), "depth": StampCounts()}
        win = WindowFilter(self.config.sources.window)  # pairs outside it are never decoded
        for msg in self.log.read(topics):
            if msg.topic in (ch.color.topic, ch.depth.topic):
                is_color = msg.topic == ch.color.topic
                try:
                    stamped = stamp_of(self.log, msg, stamps["color" if is_color else "depth"])
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
                    state.info = self.setup.check_info(msg.topic, decode.decode_camera_info(
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
        stamp_lines = stamp_report(ch, stamps, pairer)
        notes = tuple(state.notes) + tuple(stamp_lines)
        self.on_report(pairing_report(self.log, pairer, state.without_pose, state.n_undecodable, notes, win),
                       stamp_lines)
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

    def _decode(self, pair: Pair[RawMessage], state: _FrameState, poses: _PoseSource) -> Frame | None:
        ch = self.setup.choices
        try:
            max_px = self.cfg.max_image_px
            rgb = decode.decode_color(self.log.deserialize(pair.color.topic, pair.color.data), max_px)
            depth = decode.decode_depth(self.log.deserialize(pair.depth.topic, pair.depth.data),
                                        self.setup.depth_unit_m(), self.cfg.max_depth_m, max_px)
        except DecodeError as err:
            where = f"{ch.color.topic} / {ch.depth.topic}"
            if isinstance(err, FrameTooLarge):
                where += f", frame at stamp {pair.stamp_ns // 10**9}.{pair.stamp_ns % 10**9:09d}"
            state.undecodable(self.path, where, err)
            return None
        h, w = rgb.shape[:2]
        d2c = self.setup.depth_to_color()
        problem = None if d2c.mode == "register" else depth_shape_problem(
            depth.shape[1], depth.shape[0], w, h, self.cfg.intrinsics.aspect_tolerance)
        if problem is not None:
            raise DatasetError(self.path, f"frame {state.yielded} ({ch.depth.topic}): {problem}")
        if depth.shape != (h, w) and d2c.mode != "register":
            state.note(f"depth {depth.shape[1]}x{depth.shape[0]} resized nearest-neighbour to colour {w}x{h} "
                       f"({d2c.describe})")
        intr = state.info
        if intr is None:
            intr, state.info_source = self.setup.fallback_intrinsics()
            state.note(f"no CameraInfo before the first frame: intrinsics from the {state.info_source}")
        problem = distortion_problem(intr)
        if problem is not None:
            self.setup.warn(f"{state.info_source}: {problem}")
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

    def __init__(self, rec: FrameStream, ch: Choices, track: PoseTrack, state: _FrameState) -> None:
        self.rec = rec
        self.state = state
        self.ch = ch
        self.track = track
        self.camera_frame: str | None = rec.cfg.pose_frame or None
        self.static: dict[str, tuple[str, np.ndarray]] = {}
        self.dynamic: dict[str, tuple[str, np.ndarray]] = {}
        if ch.pose_type in (TF, ODOMETRY) and self.camera_frame is None:
            self.camera_frame = rec.setup.first_color_frame_id()

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



def _chain_frames(tree: dict[str, tuple[str, np.ndarray]], frame: str) -> set[str]:
    out, node = set(), frame
    while node in tree and node not in out:
        out.add(node)
        node = tree[node][0]
    return out
