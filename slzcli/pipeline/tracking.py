"""Tracking: SLAM over the frames of a source, each map segment gravity-aligned, the pose and keyframe logs.

World frame. Recorded poses are taken as given (REP 103, z up). A SLAM backend's world is
its first camera frame; it is turned into a gravity-aligned frame (z up from the recording's
gravity at that frame, ``slzcli/gravity.py``, x along the first camera's x, origin at the first
camera) so that the slope test and the Eq. 10 square mean what they say. After a map reset the backend's poses are in a
new world frame (a new map segment, ``slzcli.slam.segments``): each segment is aligned
the same way from its own first tracked frame, and its map points never serve a frame of
another segment.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Generator, Iterator
from contextlib import ExitStack, closing
from dataclasses import replace
from pathlib import Path

import numpy as np

from slzcli.config import Config, SlamCfg
from slzcli.errors import DatasetError
from slzcli.evaluate.timing import StageTimer
from slzcli.geometry import invert_pose, transform_points
from slzcli.outputs.trajectory import KeyframeLog, PoseLog
from slzcli.pipeline.source import Source
from slzcli.slam import MapPoints, SlamBackend, TrackingState, get_backend
from slzcli.sources.read_ahead import read_ahead
from slzcli.terrain.geometry import back_project
from slzcli.terrain.maps import frame_up
from slzcli.timeout import StageLimit
from slzcli.types import Frame, TrackedFrame


def gravity_alignment(first_camera_up: np.ndarray) -> np.ndarray:
    """4x4 ``T_world_slam`` for a SLAM world that is the first camera frame: z up, x along camera x."""
    z = first_camera_up / np.linalg.norm(first_camera_up)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-6:  # camera x points along gravity: use camera z instead
        x = np.array([0.0, 0.0, 1.0]) - z[2] * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z])
    return T


def depth_points(frame: Frame, T_world_camera: np.ndarray, stride_px: int) -> MapPoints:
    """Map points from the depth image on a pixel grid, for poses recorded without a map cloud."""
    xyz_cam = back_project(frame.depth_m[::stride_px, ::stride_px],
                           frame.intrinsics.scaled(*frame.depth_m[::stride_px, ::stride_px].shape[::-1]))
    v, u = np.mgrid[0:frame.depth_m.shape[0]:stride_px, 0:frame.depth_m.shape[1]:stride_px]
    ok = np.all(np.isfinite(xyz_cam), axis=2)
    pc = xyz_cam[ok]
    xyz = transform_points(T_world_camera, pc)
    pixels = np.stack([u[ok], v[ok]], axis=1).astype(np.float64)
    return MapPoints(np.arange(len(xyz), dtype=np.int64), xyz, pixels, frame.index, frame.stamp_ns, T_world_camera)


def open_slam(source: Source, slam: SlamCfg, stack: ExitStack) -> SlamBackend:
    """The source's SLAM backend (``slam.get_backend``: its recorded poses and clouds decide), closed with
    ``stack`` and started at once for the source's camera, so that a slow start (ORB-SLAM3's worker loading
    its vocabulary) overlaps the rest of the run's set-up instead of holding up the first frame."""
    backend = stack.enter_context(get_backend(slam, source.has_poses, clouds=source.clouds))
    intrinsics = source.info().intrinsics
    if intrinsics is not None:
        backend.prepare(intrinsics)
    return backend


class Tracker:
    """SLAM over the frames of one source: the backend, the gravity alignment of each map segment,
    the pose and keyframe logs and the latest keyframe's map points; nothing about detection."""

    def __init__(self, config: Config, slam: SlamBackend, keyframes: KeyframeLog | None = None,
                 timer: StageTimer | None = None) -> None:
        """``keyframes``: a log with a spool folder (else a count only); ``timer``: where the ``slam`` stage
        is timed (a run's timer, so its stages keep their order; else its own)."""
        self.config = config
        self.slam = slam
        self.timer = StageTimer() if timer is None else timer
        self.trajectory = PoseLog()  # every frame's stamp, pose (None: not tracked), segment
        self.keyframes = KeyframeLog() if keyframes is None else keyframes
        self.tracking: dict[str, int] = {}  # frames per tracking state
        self.frames = 0
        self.align: dict[int, np.ndarray] = {}  # T_world_slam of each map segment, from its first pose
        self._segment = 0  # map segment of the latest frame
        self._t_submit: deque[float] = deque()  # when each frame in SLAM's hands was submitted
        self._points: MapPoints | None = None  # the latest keyframe's map points (of the current segment)

    @property
    def slam_name(self) -> str:
        return self.slam.name

    @property
    def poses_are_recorded(self) -> bool:
        return self.slam.poses_are_recorded

    @property
    def segment(self) -> int:
        """The SLAM map segment of the latest tracked frame."""
        return self._segment

    @property
    def points(self) -> MapPoints | None:
        """The latest keyframe's map points in the world frame (None: none yet in this map segment)."""
        return self._points

    def latest_slam_ms(self) -> float:
        """The tracking time of the latest frame (ms)."""
        return self.timer.samples_ms["slam"][-1]

    def _world(self, T_slam_camera: np.ndarray | None, segment: int, frame: Frame) -> np.ndarray | None:
        if T_slam_camera is None:
            return None
        if segment not in self.align:  # the frame's own gravity (frame_up: no pose yet, so the recording's)
            self.align[segment] = np.eye(4) if self.poses_are_recorded else \
                gravity_alignment(frame_up(replace(frame, T_world_camera=None), self.config.camera.mount)) @ \
                invert_pose(T_slam_camera)
        return self.align[segment] @ T_slam_camera

    def track(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """SLAM on one frame: the gravity-aligned pose and whether it is a keyframe with map points."""
        self.submit(frame)
        return self.collect(frame)

    def submit(self, frame: Frame) -> None:
        """Start tracking ``frame``: a backend in a worker process tracks it while this process computes."""
        self.slam.submit(frame)
        self._t_submit.append(time.perf_counter())

    def collect(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """The submitted frame's gravity-aligned pose and whether it is a keyframe with map points.

        Timed as ``slam`` (the tracking time where it ran: the worker's own for ORB-SLAM3) and ``slam_wait``
        (how long this process waited for it, less when the worker tracked while the maps were computed)."""
        slam = self.slam
        t0 = time.perf_counter()
        result = slam.collect()
        points = slam.keyframe() if result.is_keyframe else None
        waited = _lap(t0)
        own = slam.last_track_ms()
        submitted = self._t_submit.popleft()
        self.timer.add("slam", _lap(submitted) if own is None else own)
        self.timer.add("slam_wait", waited)
        if result.segment != self._segment:  # a new map: the old map's points are in another frame
            self._segment, self._points = result.segment, None
        T = self._world(result.T_world_camera, self._segment, frame)
        self.frames += 1
        self.trajectory.append(frame.stamp_ns, T, self._segment)
        self.tracking[result.state.value] = self.tracking.get(result.state.value, 0) + 1
        if points is not None and T is not None:
            if len(points) == 0 and slam.map_points_from_depth:
                points = depth_points(frame, T, self.config.landing.depth_points_stride_px)
            else:
                points = MapPoints(points.ids, transform_points(self.align[self._segment], points.xyz_world),
                                   points.pixels, points.keyframe_index, points.stamp_ns, T)
            self._points = points
            self.keyframes.append(points, self._segment)
        return T, points is not None and result.state == TrackingState.OK


def track(source: Source, tracker: Tracker, limit: StageLimit) -> Generator[TrackedFrame, None, None]:
    """The frames of a source with their SLAM pose, map segment, map points and whether detection is due.

    Frames are decoded in a thread (``sources.read_ahead``); reading each frame and tracking it are stages
    under ``limit``. With ``slam.track_ahead`` the next frames, as many as the backend takes (``in_flight``), are
    handed to SLAM (a worker process starts on them) before this frame is yielded, so they are tracked while this
    frame's detection runs.
    """
    config = tracker.config
    with closing(read_ahead(source.frames(), config.sources.read_ahead_frames)) as frames:
        yield from _track_each(source.path, frames, tracker, limit)


def _track_each(path: Path, frames: Iterator[Frame], tracker: Tracker, limit: StageLimit) -> Iterator[TrackedFrame]:
    config = tracker.config
    every = config.landing.every_nth_frame
    read = 0

    def next_frame() -> Frame | None:  # read, checked and handed to SLAM (a worker process starts on it)
        nonlocal read
        with limit.stage(f"reading frame {read}"):
            frame = next(frames, None)
        if frame is not None:
            read += 1
            check_frame_size(path, frame, config.sources.min_image_px)
            tracker.submit(frame)
        return frame

    # frames in SLAM's hands before the oldest is collected: with track_ahead, the next (a worker tracks it while
    # this frame's detection runs) and as many more as the backend takes (the worker's next, waiting in its queue)
    ahead = config.slam.track_ahead
    depth = tracker.slam.in_flight if ahead else 1
    pending: deque[Frame] = deque()

    def top_up() -> None:
        while len(pending) < depth and (got := next_frame()) is not None:
            pending.append(got)

    top_up()
    while pending:
        frame = pending.popleft()
        with limit.stage(f"SLAM on frame {frame.index}"):
            T, is_keyframe = tracker.collect(frame)
        slam_ms, points, segment = tracker.latest_slam_ms(), tracker.points, tracker.segment
        if ahead:
            top_up()
        due = is_keyframe if config.landing.detect_on == "keyframes" else frame.index % every == 0
        yield TrackedFrame(frame, T, segment, points, due, slam_ms)
        if not ahead:
            top_up()


def check_frame_size(path: Path, frame: Frame, min_px: tuple[int, ...]) -> None:
    """Refuse frames too small for feature tracking and the maps' windows (the native trackers throw)."""
    h, w = frame.rgb.shape[:2]
    if w < min_px[0] or h < min_px[1]:
        raise DatasetError(path, f"frame {frame.index} is {w}x{h} px, smaller than sources.min_image_px "
                                 f"{min_px[0]}x{min_px[1]}")


def _lap(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
