"""A ``Recording`` over any time-ordered message log (ROS 1/2 bags, MCAP): the two phases tied together.

The format readers (rosbag.py, mcap.py) only list topics, stream raw messages and deserialise one on
request (``message_log.MessageLog``). Opening chooses the streams; what is decided once before streaming
is the setup scan's (``camera_setup.CameraSetup``); ``frames()`` is the stream's
(``frame_stream.FrameStream``); ``info()`` is one pass over stamps, pairing without decoding images.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

from slzcli.config import Config
from slzcli.errors import DatasetError, DecodeError
from slzcli.sources import decode
from slzcli.sources.camera_setup import CameraSetup, peek_encodings
from slzcli.sources.frame_stream import NS_PER_MS, FrameStream, pairing_report, stamp_of, stamp_report
from slzcli.sources.message_log import MessageLog
from slzcli.sources.presets import choose_preset
from slzcli.sources.recording import Recording, RecordingInfo
from slzcli.sources.sync import Stream, StreamPairer
from slzcli.sources.topics import choose_streams
from slzcli.sources.undistort import distortion_problem, has_distortion
from slzcli.sources.validate import StampCounts
from slzcli.sources.window import WindowFilter
from slzcli.types import Frame, Intrinsics, PairingReport, RecordedFrames, StreamInfo

log = logging.getLogger(__name__)


class MessageRecording(Recording):
    """Frames from a MessageLog, streamed with bounded memory."""

    def __init__(self, msglog: MessageLog, config: Config) -> None:
        super().__init__(msglog.path)
        self.log = msglog
        self.config = config
        self.cfg = config.sources
        self.setup: CameraSetup | None = None  # set by open()

    # ------------------------------------------------------------------ open / close
    def open(self) -> None:
        self.log.open()
        topics = self.log.topics()
        if not topics:
            why = self.log.warnings[0] if self.log.warnings else "empty or not a recording"
            raise DatasetError(self.path, f"the recording has no readable topics ({why})")
        preset = choose_preset(self.config.camera.preset, topics=list(topics))
        choices = choose_streams(topics, self.cfg, str(self.path), peek_encodings(self.log, topics), preset.preset)
        self.setup = CameraSetup(self.log, self.config, topics, choices, preset)

    def close(self) -> None:
        self.log.close()

    def camera_setup(self) -> CameraSetup:
        """What the setup scan decided (DatasetError before the recording is opened)."""
        if self.setup is None:
            raise DatasetError(self.path, "recording is not open (use it as a context manager)")
        return self.setup

    # ------------------------------------------------------------------ info
    def info(self) -> RecordingInfo:
        setup = self.camera_setup()
        ch = setup.choices
        counts: dict[str, list[int]] = {t: [0, 0, 0] for t in setup.topics}  # count, first, last
        pairer = StreamPairer[bytes | memoryview](int(self.cfg.sync_tolerance_ms * NS_PER_MS),
                                                  int(self.cfg.reorder_window_ms * NS_PER_MS))
        intrinsics: Intrinsics | None = None
        undecodable = 0
        info_failed = False
        first = last = None
        stamps = {"color": StampCounts(), "depth": StampCounts()}
        win = WindowFilter(self.config.sources.window)  # info counts the frames within the window
        for msg in self.log.read(()):
            c = counts.setdefault(msg.topic, [0, 0, 0])
            c[1] = msg.log_ns if c[0] == 0 else min(c[1], msg.log_ns)
            c[2] = max(c[2], msg.log_ns)
            c[0] += 1
            first = msg.log_ns if first is None else min(first, msg.log_ns)
            last = msg.log_ns if last is None else max(last, msg.log_ns)
            if msg.topic in (ch.color.topic, ch.depth.topic):
                role: Stream = "color" if msg.topic == ch.color.topic else "depth"
                try:
                    stamped = stamp_of(self.log, msg, stamps[role])
                except DecodeError:
                    undecodable += 1
                    continue
                if stamped is not None:
                    for pair in pairer.push(role, stamped[0], msg.data):
                        win.keep(pair.stamp_ns)
            elif msg.topic == ch.camera_info.topic and intrinsics is None:
                try:
                    intrinsics = setup.check_info(msg.topic, decode.decode_camera_info(
                        self.log.deserialize(msg.topic, msg.data)))
                except DecodeError as err:  # reported once (a later CameraInfo may still be good), not fatal
                    if not info_failed:
                        log.warning("%s: CameraInfo on %s not decodable: %s", self.path, msg.topic, err)
                    info_failed = True
        for pair in pairer.flush():
            win.keep(pair.stamp_ns)
        streams = tuple(StreamInfo(t, setup.topics.get(t, "?"), c[0], c[1] if c[0] else None, c[2] if c[0] else None)
                        for t, c in sorted(counts.items()))
        source = f"CameraInfo on {ch.camera_info.topic}" if intrinsics is not None else ""
        if intrinsics is None:
            intrinsics, source = setup.fallback_intrinsics()
        problem = distortion_problem(intrinsics)
        if problem is not None:
            setup.warn(f"{source}: {problem}")
        elif has_distortion(intrinsics):
            source += f"; {intrinsics.distortion_model} distortion removed from every frame"
        d2c = setup.depth_to_color()
        stamp_lines = stamp_report(ch, stamps, pairer)
        for line in stamp_lines:
            log.warning("%s: %s", self.path, line)
        report = pairing_report(self.log, pairer, 0, undecodable, tuple(stamp_lines), win)
        return RecordingInfo(str(self.path), self.log.format, ((last or 0) - (first or 0)) * 1e-9, streams,
                             ch.all(), intrinsics, source, report,
                             tuple(self.log.warnings) + tuple(setup.warnings), setup.preset.name,
                             setup.preset.reason, d2c.describe)

    # ------------------------------------------------------------------ frames
    def frames(self) -> Iterator[Frame]:
        """The frames (see Recording); a configured points topic missing from the recording is refused here."""
        setup = self.camera_setup()
        points = self.config.slam.points_topic
        if points and points not in setup.topics:
            raise DatasetError(self.path, f"slam.points_topic {points!r} is not in the recording")
        # Settled before the pass: both read messages of their own, which must not happen inside it.
        setup.depth_to_color()
        setup.depth_unit_m()
        return FrameStream(setup, self.quiet_frames, self._set_report).frames(points)

    def _set_report(self, report: PairingReport) -> None:
        self.report = report

    def recorded_frames(self) -> RecordedFrames:
        """The recording's camera, static tf chain and pose frame ids (``sources.tf``), in short passes."""
        return self.camera_setup().recorded_frames()

    def pose_stamps(self, limit: int) -> list[int]:
        """The header stamps of the first ``limit`` poses on the pose topic (every transform's, for /tf)."""
        return self.camera_setup().pose_stamps(limit)
