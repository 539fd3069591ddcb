"""The recorded backend: poses and map points that a SLAM system already published in the recording.

Frame poses arrive through ``Frame.T_world_camera`` (the sources layer reads PoseStamped,
Odometry or /tf); map points through ``Frame.map_points``: the reader decodes the
``sensor_msgs/PointCloud2`` topic ``slam.points_topic`` (what ORB-SLAM3 ROS wrappers publish)
in the same pass as the images and hands each cloud to the posed frame nearest in time
(within ``sources.pose_tolerance_ms``). That frame is a keyframe and its map points are the
cloud's points that project into its image. The recording is read once, streamed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from slzcli.geometry import project
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.keyframes import is_new_keyframe
from slzcli.types import Frame

if TYPE_CHECKING:
    from slzcli.config import SlamCfg
    from slzcli.sources import RecordingInfo


def has_recorded_clouds(info: RecordingInfo, slam: SlamCfg) -> bool:
    """Whether the frames of this recording carry map clouds: ``slam.points_topic`` is set and has messages.

    A points topic missing from the recording is refused by the reader's ``frames()``.
    """
    topic = slam.points_topic
    return bool(topic) and any(s.topic == topic and s.count > 0 for s in info.streams)


class RecordedBackend(BackendBase):
    """Replays recorded poses exactly; keyframes are the frames a recorded map cloud belongs to.

    Without any recorded cloud, keyframes follow the shared motion rule (slam.keyframe) and
    carry no points: the pipeline then samples map points from the keyframe's depth.
    """

    name = "recorded"
    poses_are_recorded = True
    map_points_from_depth = True

    def __init__(self, slam: SlamCfg, clouds: bool = False) -> None:
        """``clouds``: whether the frames carry recorded map clouds (``has_recorded_clouds``)."""
        self.clouds = clouds
        self._keyframe: MapPoints | None = None
        self._n_kf = 0
        self._kf_cfg = slam.keyframe
        self._last_kf_pose: np.ndarray | None = None

    def track(self, frame: Frame) -> TrackResult:
        self._keyframe = None
        if frame.T_world_camera is None:
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.LOST, None, False, 0)
        pose = np.asarray(frame.T_world_camera, np.float64)
        cloud = frame.map_points if self.clouds else None
        if cloud is not None:
            xyz, ids = cloud.xyz, cloud.ids
            uv, ok = project(xyz, pose, frame.K, (frame.intrinsics.height, frame.intrinsics.width))
            self._keyframe = MapPoints(ids[ok], xyz[ok], uv[ok], self._n_kf, frame.stamp_ns, pose)
            self._n_kf += 1
        elif not self.clouds and is_new_keyframe(self._last_kf_pose, pose, 1, 1, self._kf_cfg.min_translation_m,
                                                 self._kf_cfg.min_rotation_deg, 0.0):
            self._keyframe = MapPoints.empty(self._n_kf, frame.stamp_ns, pose)
            self._last_kf_pose = pose
            self._n_kf += 1
        n = 0 if self._keyframe is None else len(self._keyframe)
        return TrackResult(frame.index, frame.stamp_ns, TrackingState.OK, pose, self._keyframe is not None, n)

    def keyframe(self) -> MapPoints | None:
        return self._keyframe
