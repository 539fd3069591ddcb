"""What every SLAM backend gives the rest of slz: per-frame poses, keyframes and the map points they see.

A backend is fed frames in order (``track``) and answers with a ``TrackResult``. On a keyframe
it also answers ``keyframe()`` with the map points that keyframe sees, so the site selection
(METHOD 2.5) can project them through the landing mask. Backends hold native or large state,
so they are context managers (``close`` frees it). A tracking state is a claim, not a proof:
evaluate poses against ground truth (``slzcli.evaluate.slam``) before trusting a backend.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from types import TracebackType
from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

from slzcli.geometry import invert_pose as invert_pose  # odometry.py of older revisions imports it from here
from slzcli.types import Frame, Intrinsics
from slzcli.types import MapPoints as MapPoints  # defined with the other shared types


class TrackingState(str, enum.Enum):
    """Coarse tracking state shared by all backends (ORB-SLAM3's finer states map onto these)."""

    INITIALISING = "initialising"
    OK = "ok"
    LOST = "lost"


@dataclass(frozen=True, eq=False)
class TrackResult:
    """The answer for one frame. ``T_world_camera`` is None whenever the backend has no pose.

    ``segment`` counts the maps a backend has started: after tracking is lost and a new map is
    begun, poses of a new segment are in a world frame that need not match the earlier one.
    """

    frame_index: int
    stamp_ns: int
    state: TrackingState
    T_world_camera: np.ndarray | None
    is_keyframe: bool = False
    tracked_points: int = 0
    segment: int = 0


@dataclass(frozen=True, eq=False)
class Keyframe:
    """A keyframe as written to keyframes.npz: its pose and the map points it sees."""

    frame_index: int
    stamp_ns: int
    T_world_camera: np.ndarray
    points: MapPoints


@runtime_checkable
class SlamBackend(Protocol):
    """Frames in (in time order), poses and keyframe map points out.

    What a backend can do is said by its capabilities (``BackendBase`` holds the defaults), so
    the pipeline never asks for a backend by name:

    - ``poses_are_recorded``: its poses are the recording's, in the recording's world frame
      (REP 103, z up), taken as given; else its world is its first camera frame and the
      pipeline turns it gravity-aligned.
    - ``map_points_from_depth``: a keyframe with no map points stands for its depth image
      (poses recorded without a map cloud); the pipeline samples map points from the depth.
    - ``in_flight``: how many frames may be submitted before the first is collected (a worker process
      tracks the next while its answer for one is read; 1 where the work is done in ``collect``).
    """

    name: str
    poses_are_recorded: bool
    map_points_from_depth: bool
    in_flight: int

    def track(self, frame: Frame) -> TrackResult:
        """Consume one frame; the pose of that frame (or None) and whether it became a keyframe."""
        ...

    def submit(self, frame: Frame) -> None:
        """Hand the next frame over (at most ``in_flight`` not yet collected); ``collect`` answers for the frames in
        the order they were submitted. ``track`` is ``submit`` then ``collect``."""
        ...

    def collect(self) -> TrackResult:
        """The answer for the oldest frame submitted and not yet collected (as ``track`` gives it)."""
        ...

    def last_track_ms(self) -> float | None:
        """How long the last frame took to track where it was tracked (None: the caller's wait is that time)."""
        ...

    def prepare(self, intrinsics: Intrinsics) -> None:
        """Start what takes long to start (a worker, a vocabulary) for frames of ``intrinsics``, while the run is
        still being set up; frames of other intrinsics still work."""
        ...

    def keyframe(self) -> MapPoints | None:
        """Map points seen by the latest frame if it was a keyframe, else None."""
        ...

    def close(self) -> None:
        """Free native resources (threads, worker processes); idempotent."""
        ...

    def __enter__(self) -> SlamBackend: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


_B = TypeVar("_B", bound="BackendBase")


class BackendBase:
    """Context-manager plumbing and the default capabilities (``SlamBackend``) shared by the backends."""

    name = "base"
    poses_are_recorded = False
    map_points_from_depth = False
    in_flight = 1
    _submitted: Frame | None = None

    # A backend that tracks in a worker process overrides submit/collect so that the worker starts on a frame
    # while the caller computes on the one before (pipeline.tracking.track); here the work is done in collect.
    def track(self, frame: Frame) -> TrackResult:  # pragma: no cover - every backend defines it
        raise NotImplementedError

    def submit(self, frame: Frame) -> None:
        if self._submitted is not None:
            raise RuntimeError(f"{self.name}: frame {self._submitted.index} was submitted and never collected")
        self._submitted = frame

    def collect(self) -> TrackResult:
        frame, self._submitted = self._submitted, None
        if frame is None:
            raise RuntimeError(f"{self.name}: collect() without a submitted frame")
        return self.track(frame)

    def last_track_ms(self) -> float | None:
        return None

    def prepare(self, intrinsics: Intrinsics) -> None:
        return None

    def close(self) -> None:  # pragma: no cover - overridden where there is something to free
        return None

    def __enter__(self: _B) -> _B:
        return self

    def abort(self) -> None:
        """Free resources without waiting on them (after an error or a --timeout); default: close."""
        self.close()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
