"""Gravity of one recording: read its IMU and a few frames, resolve (``terrain.gravity``), hand it to the run.

At the start of ``slz detect``, ``slz compare`` and ``slz info``, in short passes of their own:
the IMU topics (``sources.imu``), then ``camera.gravity.scene.frames`` frames ``stride`` apart
for the recorded poses and the scene's dominant plane. The result reaches the run three ways:
``camera.mount`` in the run's config becomes the resolved gravity's (the SLAM world's alignment
and any frame without its own), each frame carries its own ``up_camera`` where the source
gives one per frame (the IMU around its stamp, the scene's plane in it), and the recording's
info (``slz info``, run.json, the summary) says which source it was, the tilt and every
disagreement, with the warnings.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slzcli.config import CameraCfg, Config
from slzcli.errors import DatasetError, SlzError
from slzcli.slam import uses_recorded_poses
from slzcli.sources import Recording, RecordingInfo, open_recording
from slzcli.sources.imu import NO_IMU, read_imu
from slzcli.terrain import gravity as g
from slzcli.terrain.maps import gravity_up_in_camera
from slzcli.types import Frame

log = logging.getLogger(__name__)
LEVEL_SPREAD_DEG = 3.0  # deg; "level under camera.mount": within this (the mount's own error is about as large)
UpOf = Callable[[Frame], "np.ndarray | None"]


@dataclass(frozen=True, eq=False)
class RecordingGravity:
    """The resolved gravity and how each frame gets its own (None: the recording's, or its pose)."""

    gravity: g.Gravity
    up_of: UpOf | None = None
    world_fix: np.ndarray | None = None  # 3x3: recorded poses' world rotated to the IMU's up (None: as recorded)

    def camera(self, camera: CameraCfg) -> CameraCfg:
        """The ``camera`` section with ``mount`` set to the gravity used (unchanged when it is the mount)."""
        if self.gravity.source == "mount":
            return camera
        return dataclasses.replace(camera, mount=self.gravity.mount())

    def info(self, info: RecordingInfo) -> RecordingInfo:
        """The recording's info with the gravity block and its warnings."""
        warnings = tuple(info.warnings) + tuple(w for w in self.gravity.warnings if w not in info.warnings)
        return dataclasses.replace(info, gravity=self.gravity.as_dict(), warnings=warnings)

    def frames(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        """Each frame with its own gravity attached (``Frame.up_camera``) where the source gives one."""
        if self.up_of is None and self.world_fix is None:
            yield from frames
            return
        for frame in frames:
            if self.world_fix is not None and frame.T_world_camera is not None:
                frame = _rotated(frame, self.world_fix)
            yield frame if self.up_of is None else dataclasses.replace(frame, up_camera=self.up_of(frame))


def apply(path: Path, rec: Recording, info: RecordingInfo,
          config: Config) -> tuple[RecordingGravity, RecordingInfo, Config]:
    """(the gravity, info, config) of a run on the open recording ``rec`` (see the module docstring): its
    frames get their own gravity through ``RecordingGravity.frames``."""
    resolved = resolve_recording(path, rec, config)
    for line in resolved.gravity.warnings:
        log.warning("%s: %s", path, line)
    log.info("%s: gravity from %s", path, resolved.gravity.line())
    return resolved, resolved.info(info), dataclasses.replace(config, camera=resolved.camera(config.camera))


def resolve_recording(path: Path, rec: Recording, config: Config) -> RecordingGravity:
    """Every source's estimate from the open recording ``rec`` (and a second reading of its first frames,
    opened again with ``config``), resolved; DatasetError naming the recording when a named source is
    missing or contradicted. Recorded poses count only when the run uses them (``slam``)."""
    camera = config.camera
    cfg = camera.gravity
    found: dict[str, g.Estimate] = {}
    unavailable: dict[str, str] = {}
    blocks = _imu(rec, camera, found, unavailable)
    reopen = lambda: open_recording(path, config)  # noqa: E731
    poses, level = _frames(reopen, camera, uses_recorded_poses(config.slam), found, unavailable)
    try:
        gravity = g.resolve(found, camera.mount, cfg, unavailable, level)
    except ValueError as err:
        raise DatasetError(path, str(err)) from None
    up_of: UpOf | None = None
    fix = None
    if gravity.source == "imu" and blocks is not None and "poses" in found and \
            g.angle_deg(found["poses"].vector, gravity.up) > cfg.max_disagreement_deg:
        # the poses' world is not level (a visual SLAM's first camera frame?): rotate it to the IMU's up, so
        # that no map runs on a gravity the IMU contradicts
        up_world = sum(R @ blocks.up_at(stamp, cfg.imu.window_s) for stamp, R in poses)
        fix = g.rotation_between(np.asarray(up_world), np.array([0.0, 0.0, 1.0]))
        turned = g.angle_deg(np.asarray(up_world), np.array([0.0, 0.0, 1.0]))
        gravity = dataclasses.replace(gravity, warnings=(*gravity.warnings, (
            f"gravity: the recorded poses' world z is {turned:.1f} deg from the IMU's up: their world is rotated "
            "about its origin to the IMU's (the site's coordinates are in that rotated frame)")))
    if gravity.source == "imu" and blocks is not None:
        window = cfg.imu.window_s
        up_of = _imu_up_of(blocks, window)
        gravity = dataclasses.replace(gravity, per_frame=f"the IMU's quiet blocks within {window:g} s of the frame")
    elif gravity.source == "scene":
        up_of = _scene_up_of(gravity.up, camera)
        gravity = dataclasses.replace(gravity, per_frame=(
            f"the frame's own dominant plane within {cfg.scene.frame_prior_deg:g} deg of the recording's, "
            "else the recording's"))
    elif gravity.source == "poses":
        gravity = dataclasses.replace(gravity, per_frame="each frame's recorded pose")
    return RecordingGravity(gravity, up_of, fix)


@contextmanager
def _quiet_readers() -> Iterator[None]:
    """The readers' warnings off while the first frames are read again: the run's own pass says them, once."""
    logger = logging.getLogger("slzcli.sources")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _rotated(frame: Frame, R: np.ndarray) -> Frame:
    """A frame's recorded pose (and map cloud) in a world rotated by ``R`` about its origin."""
    assert frame.T_world_camera is not None
    fix = np.eye(4)
    fix[:3, :3] = R
    cloud = frame.map_points
    if cloud is not None:
        cloud = dataclasses.replace(cloud, xyz=np.asarray(cloud.xyz) @ R.T)
    return dataclasses.replace(frame, T_world_camera=fix @ frame.T_world_camera, map_points=cloud)


def _imu_up_of(blocks: g.QuietBlocks, window_s: float) -> UpOf:
    return lambda frame: blocks.up_at(frame.stamp_ns, window_s)


def _scene_up_of(recording_up: np.ndarray, camera: CameraCfg) -> UpOf:
    cfg = camera.gravity.scene

    def up_of(frame: Frame) -> np.ndarray:
        plane = g.dominant_plane(frame.depth_m, frame.intrinsics, recording_up, cfg.frame_prior_deg, cfg,
                                 cfg.seed + frame.index)
        return recording_up if plane is None else plane.up

    return up_of


def _imu(rec: Recording, camera: CameraCfg, found: dict[str, g.Estimate],
         unavailable: dict[str, str]) -> g.QuietBlocks | None:
    cfg = camera.gravity.imu
    if not hasattr(rec, "log"):  # a TUM folder: no IMU slz reads
        unavailable["imu"] = "this format carries no sensor_msgs/Imu"
        return None
    try:
        samples = read_imu(rec, cfg)
    except SlzError as err:  # a damaged file: the frames' own pass says what it can still read
        samples = f"the IMU could not be read ({err})"
    if isinstance(samples, str):
        unavailable["imu"] = samples
        if samples != NO_IMU:  # there is an IMU, and it cannot be used: say so
            log.warning("IMU not used for gravity: %s", samples)
        return None
    blocks = g.quiet_blocks(samples.stamps_ns, samples.accel, samples.gyro_stamps_ns, samples.gyro, cfg)
    quiet = len(blocks.stamps_ns)
    if quiet < cfg.min_quiet_blocks:
        norm = blocks.median_norm_m_s2
        unit = ("; its specific force is not in m/s^2 (it reads ~1: in g?)" if 0.5 < norm < 2.0 else "")
        unavailable["imu"] = (f"{samples.detail}: only {quiet} of {blocks.blocks} {cfg.block_s:g} s blocks are quiet "
                              f"(|a| within {cfg.accel_tolerance_m_s2:g} m/s^2 of g, median |a| {norm:.2f} m/s^2"
                              f"{unit}), camera.gravity.imu.min_quiet_blocks is {cfg.min_quiet_blocks}: not used")
        log.warning("IMU not used for gravity: %s", unavailable["imu"])
        return None
    found["imu"] = g.estimate("imu", blocks.up, f"IMU {samples.detail}; {quiet} of {blocks.blocks} "
                                               f"{cfg.block_s:g} s blocks quiet", blocks.spread_deg())
    return blocks


def _frames(reopen: Callable[[], Recording], camera: CameraCfg, use_poses: bool, found: dict[str, g.Estimate],
            unavailable: dict[str, str]) -> tuple[list[tuple[int, np.ndarray]], float]:
    """The recorded poses' (when ``use_poses``: the run takes them as given) and the scene's estimates from the
    first frames of the recording ``reopen()`` opens again; their (stamp, R_world_camera) and the median frame's
    share of points on a plane level under camera.mount (``terrain.gravity.level_share``)."""
    cfg = camera.gravity.scene
    prior = gravity_up_in_camera(None, camera.mount)
    pose_ups: list[np.ndarray] = []
    poses: list[tuple[int, np.ndarray]] = []
    level: list[float] = []
    planes: list[g.Plane] = []
    read = 0
    last = (cfg.frames - 1) * cfg.stride
    try:
        with _quiet_readers(), reopen() as other:
            frames = other.frames()
            for frame in frames:
                if frame.index > last:
                    break
                if frame.index % cfg.stride:
                    continue
                read += 1
                if use_poses and frame.T_world_camera is not None:
                    pose_ups.append(np.asarray(frame.T_world_camera, np.float64)[2, :3])
                    poses.append((frame.stamp_ns, np.asarray(frame.T_world_camera, np.float64)[:3, :3]))
                plane = g.dominant_plane(frame.depth_m, frame.intrinsics, prior, cfg.max_prior_deg, cfg,
                                         cfg.seed + frame.index)
                if plane is not None:
                    planes.append(plane)
                level.append(g.level_share(frame.depth_m, frame.intrinsics, prior, cfg, LEVEL_SPREAD_DEG))
            getattr(frames, "close", lambda: None)()  # stop its decoding before the recording closes
    except SlzError as err:  # the run's own pass over the frames reports it, once
        unavailable["scene"] = unavailable["poses"] = f"the first frames could not be read ({err})"
        return [], 0.0
    if pose_ups:
        up, members = g.agreeing(pose_ups, cfg.cluster_deg)
        spread = max(g.angle_deg(u, up) for u in pose_ups)
        found["poses"] = g.estimate("poses", up, f"recorded poses of {len(pose_ups)} of the first frames",
                                    spread)
    else:
        unavailable["poses"] = "no recorded pose (or none chosen)"
    if planes:
        up, members = g.agreeing([p.up for p in planes], cfg.cluster_deg)
        share = float(np.mean([planes[i].share for i in members]))
        spread = max(g.angle_deg(planes[i].up, up) for i in members)
        found["scene"] = g.estimate("scene", up, f"dominant plane of {len(members)} of {read} frames read "
                                                 f"({share:.0%} of their points)", spread)
    else:
        unavailable["scene"] = (f"no plane holding {cfg.min_inlier_share:.0%} of the points within "
                                f"{cfg.max_prior_deg:g} deg of camera.mount's up in {read} frames read")
    return poses, float(np.median(level)) if level else 0.0
