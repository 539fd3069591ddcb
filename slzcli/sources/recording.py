"""What every reader returns: a context-managed ``Recording`` and its ``RecordingInfo``."""

from __future__ import annotations

import abc
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from slzcli.types import Frame, GravityDoc, Intrinsics, PairingReport, RecordedFrames, StreamChoice, StreamInfo


@dataclass(frozen=True)
class RecordingInfo:
    """What ``slz info`` shows: streams, the choice of topics and why, and how many frames pair."""

    path: str
    format: str
    duration_s: float
    streams: tuple[StreamInfo, ...]
    choices: tuple[StreamChoice, ...]
    intrinsics: Intrinsics | None
    intrinsics_source: str
    pairing: PairingReport
    warnings: tuple[str, ...] = field(default_factory=tuple)
    camera_preset: str | None = None     # configs/camera/NAME.yaml in use, None: none
    camera_preset_reason: str = ""
    depth_to_color: str = ""             # how depth reaches the colour pixel grid (aligned, registered, resized)
    gravity: GravityDoc | None = None  # where world up came from (slzcli/gravity.py), None: not resolved

    @property
    def expected_frames(self) -> int:
        return self.pairing.paired

    @property
    def frame_period_s(self) -> float | None:
        """The colour stream's mean frame period; None with fewer than two stamped frames."""
        topic = next((c.topic for c in self.choices if c.role == "color"), None)
        rate = next((s.rate_hz for s in self.streams if s.topic == topic), None)
        return None if rate is None else 1.0 / rate

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready form (the ``--json`` summary of ``slz info``)."""
        k = self.intrinsics
        return {
            "path": self.path,
            "format": self.format,
            "duration_s": self.duration_s,
            "topics": [{"topic": s.topic, "type": s.msgtype, "count": s.count, "rate_hz": s.rate_hz}
                       for s in self.streams],
            "streams": {c.role: {"topic": c.topic, "reason": c.reason} for c in self.choices},
            "intrinsics": None if k is None else {
                "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height,
                "distortion_model": k.distortion_model, "distortion": list(k.distortion)},
            "intrinsics_source": self.intrinsics_source,
            "camera_preset": {"name": self.camera_preset, "reason": self.camera_preset_reason},
            "depth_to_color": self.depth_to_color,
            "gravity": self.gravity,
            "frames": self.pairing.paired,
            "pairing": {"paired": self.pairing.paired, "unpaired_color": self.pairing.unpaired_color,
                        "unpaired_depth": self.pairing.unpaired_depth, "without_pose": self.pairing.without_pose,
                        "undecodable": self.pairing.undecodable, "outside_window": self.pairing.outside_window,
                        "notes": list(self.pairing.notes)},
            "warnings": list(self.warnings),
        }


class Recording(abc.ABC):
    """A recording opened for reading. Use as a context manager; ``frames()`` streams once."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.report = PairingReport()
        self.pairing_final = False  # a frames() pass ended and ``report`` is its own
        # A frames() pass that only looks ahead (the recorded-pose check reads the first frames before the
        # run) sets this: its per-frame warnings (a torn message, an unusable pose) are the run's to give.
        self.quiet_frames = False

    def __enter__(self) -> Recording:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @abc.abstractmethod
    def open(self) -> None:
        """Open the file(s) and choose the streams; DatasetError naming the path on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release file handles."""

    @abc.abstractmethod
    def info(self) -> RecordingInfo:
        """Topics, choices and pair count from one pass over stamps (no image decoding)."""

    def run_info(self) -> RecordingInfo:
        """What a run needs before its first frame; the pairing may be an estimate that ``after_frames``
        replaces (a format that can do without the full pass says how). Default: ``info()``."""
        return self.info()

    def after_frames(self, info: RecordingInfo) -> RecordingInfo:
        """``info`` with what a finished frames pass found. Default: unchanged."""
        return info

    def recorded_frames(self) -> RecordedFrames:
        """The recording's own frame ids (camera, tf, poses); none for a format without them (TUM)."""
        return RecordedFrames()

    def pose_stamps(self, limit: int) -> list[int]:
        """The stamps (ns) of the first ``limit`` recorded poses of the chosen pose stream ([] without one)."""
        return []

    @abc.abstractmethod
    def frames(self) -> Iterator[Frame]:
        """Paired, decoded frames in stamp order; ``self.report`` is final when it ends."""
