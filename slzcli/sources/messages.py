"""A ``Recording`` over any time-ordered message log (ROS 1/2 bags, MCAP): the two phases tied together.

The format readers (rosbag.py, mcap.py) only list topics, stream raw messages and deserialise one on
request (``message_log.MessageLog``). Opening chooses the streams; what is decided once before streaming
is the setup scan's (``camera_setup.CameraSetup``); ``frames()`` is the stream's
(``frame_stream.FrameStream``); ``info()`` is one pass over stamps, pairing without decoding images;
``run_info()`` what a run needs before its first frame, from the file's index where it has one.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import closing
from dataclasses import replace

import numpy as np

from slzcli.config import Config, WindowCfg
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
from slzcli.sources.window import WindowFilter, is_whole
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
        self._stamps_warned: set[str] = set()

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
        """Every message read once (``slz info``): each topic's count and span, the first usable CameraInfo,
        every colour/depth stamp paired within the window; no image decoded."""
        setup = self.camera_setup()
        ch = setup.choices
        counts: dict[str, list[int]] = {t: [0, 0, 0] for t in setup.topics}  # count, first, last
        pairer = StreamPairer[bytes | memoryview](int(self.cfg.sync_tolerance_ms * NS_PER_MS),
                                                  int(self.cfg.reorder_window_ms * NS_PER_MS))
        intrinsics: Intrinsics | None = None
        undecodable = 0
        info_failed = False
        stamps = {"color": StampCounts(), "depth": StampCounts()}
        win = WindowFilter(self.config.sources.window)  # info counts the frames within the window
        for msg in self.log.read(()):
            c = counts.setdefault(msg.topic, [0, 0, 0])
            c[1] = msg.log_ns if c[0] == 0 else min(c[1], msg.log_ns)
            c[2] = max(c[2], msg.log_ns)
            c[0] += 1
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
                intrinsics, info_failed = self._camera_info(msg.topic, msg.data, info_failed)
        for pair in pairer.flush():
            win.keep(pair.stamp_ns)
        streams = tuple(StreamInfo(t, setup.topics.get(t, "?"), c[0], c[1] if c[0] else None, c[2] if c[0] else None)
                        for t, c in sorted(counts.items()))
        stamp_lines = stamp_report(ch, stamps, pairer)
        self._warn_stamps(stamp_lines)
        report = pairing_report(self.log, pairer, 0, undecodable, tuple(stamp_lines), win)
        return self._info(streams, intrinsics, report)

    def run_info(self) -> RecordingInfo:
        """What a run needs before its first frame, without reading every message where the file's own index
        gives each message's log time (``MessageLog.log_times``: an MCAP's summary, a ROS 1 bag's index):
        counts, spans and rates from it, the first usable CameraInfo read, and the frames estimated by log time
        within the window (the progress total); the frames pass pairs the stamps and reports that
        (``after_frames``). Without such an index, ``info()``."""
        times = self.log.log_times()
        if times is None:
            return self.info()
        setup = self.camera_setup()
        ch = setup.choices
        streams = tuple(StreamInfo(t, setup.topics.get(t, "?"), len(ts), int(ts[0]), int(ts[-1])) if len(ts) else
                        StreamInfo(t, setup.topics.get(t, "?"), 0)
                        for t, ts in sorted({**{t: _NONE for t in setup.topics}, **times}.items()))
        estimate = min(_in_window(times.get(t, _NONE), self.config.sources.window)
                       for t in (ch.color.topic, ch.depth.topic) if t)
        return self._info(streams, self._first_camera_info(), PairingReport(paired=estimate))

    def after_frames(self, info: RecordingInfo) -> RecordingInfo:
        """``info`` with what a finished frames pass found: its pairing report (the frames the run read) and
        the warnings met since (a file damaged past its index)."""
        if not self.pairing_final:
            return info
        setup = self.camera_setup()
        warnings = tuple(dict.fromkeys((*info.warnings, *self.log.warnings, *setup.warnings)))
        return replace(info, pairing=self.report, warnings=warnings)

    def _info(self, streams: tuple[StreamInfo, ...], intrinsics: Intrinsics | None,
              report: PairingReport) -> RecordingInfo:
        setup = self.camera_setup()
        ch = setup.choices
        source = f"CameraInfo on {ch.camera_info.topic}" if intrinsics is not None else ""
        if intrinsics is None:
            intrinsics, source = setup.fallback_intrinsics()
        problem = distortion_problem(intrinsics)
        if problem is not None:
            setup.warn(f"{source}: {problem}")
        elif has_distortion(intrinsics):
            source += f"; {intrinsics.distortion_model} distortion removed from every frame"
        d2c = setup.depth_to_color()
        firsts = [s.first_ns for s in streams if s.first_ns is not None]
        lasts = [s.last_ns for s in streams if s.last_ns is not None]
        duration_s = (max(lasts) - min(firsts)) * 1e-9 if firsts else 0.0
        return RecordingInfo(str(self.path), self.log.format, duration_s, streams, ch.all(), intrinsics, source,
                             report, tuple(self.log.warnings) + tuple(setup.warnings), setup.preset.name,
                             setup.preset.reason, d2c.describe)

    def _first_camera_info(self) -> Intrinsics | None:
        """The first decodable CameraInfo of the chosen topic (checked: DatasetError when unusable), read
        until one is found; None without one."""
        setup = self.camera_setup()
        topic = setup.choices.camera_info.topic
        if not topic:
            return None
        failed = False
        with closing(self.log.read([topic])) as messages:
            for msg in messages:
                k, failed = self._camera_info(topic, msg.data, failed)
                if k is not None:
                    return k
        return None

    def _camera_info(self, topic: str, data: bytes | memoryview, failed: bool) -> tuple[Intrinsics | None, bool]:
        """One CameraInfo message decoded and checked (DatasetError when unusable); (None, True) when it cannot be
        decoded, warned of once (``failed``: already warned): a later one may still be good."""
        try:
            k = decode.decode_camera_info(self.log.deserialize(topic, data))
        except DecodeError as err:
            if not failed:
                log.warning("%s: CameraInfo on %s not decodable: %s", self.path, topic, err)
            return None, True
        return self.camera_setup().check_info(topic, k), failed

    def _warn_stamps(self, lines: list[str]) -> None:
        """The stamp problems of a pass on stderr, each once per recording (info pass and frames pass)."""
        for line in lines:
            if line not in self._stamps_warned:
                self._stamps_warned.add(line)
                log.warning("%s: %s", self.path, line)

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

    def _set_report(self, report: PairingReport, stamp_lines: list[str]) -> None:
        self.report = report
        self.pairing_final = True
        if not self.quiet_frames:
            self._warn_stamps(stamp_lines)

    def recorded_frames(self) -> RecordedFrames:
        """The recording's camera, static tf chain and pose frame ids (``sources.tf``), in short passes."""
        return self.camera_setup().recorded_frames()

    def pose_stamps(self, limit: int) -> list[int]:
        """The header stamps of the first ``limit`` poses on the pose topic (every transform's, for /tf)."""
        return self.camera_setup().pose_stamps(limit)


_NONE = np.empty(0, np.int64)  # a topic without messages


def _in_window(log_ns: np.ndarray, window: WindowCfg) -> int:
    """How many of these stamps (log times, in order) ``window`` keeps: the frames a run will read, estimated
    before the pass that pairs the header stamps."""
    if is_whole(window):
        return len(log_ns)
    win = WindowFilter(window)
    kept = 0
    for t in log_ns.tolist():
        kept += win.keep(t)
        if win.done():
            break
    return kept
