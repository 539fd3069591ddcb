"""What a run reads: a recording (opened once, its info and pairing report) or frames already in memory.

Both are a ``Source``: its frames, whether they carry recorded poses and map clouds, and, once the frames
are read, the pairing report and the recording info that run.json and the API's result hold.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

from slzcli import gravity
from slzcli.config import Config
from slzcli.errors import DatasetError
from slzcli.gravity import RecordingGravity
from slzcli.slam import with_frame_period
from slzcli.slam.pose_checks import vet_recorded_poses
from slzcli.slam.recorded import has_recorded_clouds
from slzcli.sources import Recording, RecordingInfo, open_recording
from slzcli.sources.presets import with_noise_prior
from slzcli.types import Frame, PairingReport

FRAMES_SOURCE = "<frames>"  # the source named in a result made from frames in memory


@dataclass(eq=False)
class RecordingSource:
    """An open recording (closed with the stack it was opened on)."""

    path: Path
    recording: Recording
    opened: RecordingInfo
    clouds: bool  # its frames carry recorded map clouds
    gravity: RecordingGravity | None = None  # each frame's own gravity, where the recording gives one

    @property
    def has_poses(self) -> bool:
        return any(c.role == "pose" and c.topic for c in self.opened.choices)

    @property
    def expected_frames(self) -> int | None:
        return self.opened.expected_frames

    def frames(self) -> Iterator[Frame]:
        frames = self.recording.frames()
        return frames if self.gravity is None else self.gravity.frames(frames)

    def report(self) -> PairingReport:
        return self.recording.report

    def info(self) -> RecordingInfo:
        """The info the run opened with; once the frames are read, with their pairing (``after_frames``)."""
        return self.recording.after_frames(self.opened)


@dataclass(eq=False)
class FramesSource:
    """Frames in memory (any iterable of ``Frame``): nothing read from disk; the info is made from the frames."""

    first: Frame
    rest: Iterator[Frame]
    path: Path = Path(FRAMES_SOURCE)
    clouds: bool = False
    expected_frames: int | None = None
    stamps: list[int] = field(default_factory=list)

    @classmethod
    def of(cls, frames: Iterator[Frame]) -> FramesSource:
        first = next(frames, None)
        if first is None:
            raise DatasetError(FRAMES_SOURCE, "no frame given")
        return cls(first, frames)

    @property
    def has_poses(self) -> bool:
        return self.first.T_world_camera is not None

    def frames(self) -> Iterator[Frame]:
        for f in _chain(self.first, self.rest):
            self.stamps.append(f.stamp_ns)
            yield f

    def report(self) -> PairingReport:
        return PairingReport(paired=len(self.stamps))

    def info(self) -> RecordingInfo:
        span_s = (max(self.stamps) - min(self.stamps)) * 1e-9 if self.stamps else 0.0
        return RecordingInfo(FRAMES_SOURCE, "frames", span_s, (), (), self.first.intrinsics, "Frame.intrinsics",
                             self.report())


Source = RecordingSource | FramesSource


def open_source(path: Path, config: Config, stack: ExitStack) -> tuple[RecordingSource, Config]:
    """The open recording (closed with ``stack``) and ``config`` with what the recording decides: the backend
    when the recorded poses contradict the frames (``slam.pose_checks``; the reason is in the info's
    warnings), then its gravity (``slzcli/gravity.py``: ``camera.mount``, each frame's own; rejected poses
    are no source of it), the camera preset's depth noise prior and the frame period ORB-SLAM3 is told
    (``slam.orbslam3.nominal_period_s: auto``)."""
    rec = stack.enter_context(open_recording(path, config))
    slam, info = vet_recorded_poses(path, rec, rec.run_info(), config.slam, config.sources.pose_tolerance_ms)
    config = replace(config, slam=slam)  # rejected poses: an error, or another backend
    resolved, info, config = gravity.apply(path, rec, info, config)
    config = with_noise_prior(config, info.camera_preset)
    config = replace(config, slam=with_frame_period(config.slam, info))
    return RecordingSource(path, rec, info, has_recorded_clouds(info, config.slam), resolved), config


def _chain(first: Frame, rest: Iterator[Frame]) -> Iterator[Frame]:
    yield first
    yield from rest
