"""The recorded backend: poses and map points that a SLAM system already published in the recording.

Frame poses arrive through ``Frame.T_world_camera`` (the sources layer reads PoseStamped,
Odometry or /tf); map points come from a ``sensor_msgs/PointCloud2`` topic (what ORB-SLAM3 ROS
wrappers publish), decoded here with ``decode_pointcloud2`` (kept here, not in
sources/decode.py, while that module is being written). A cloud is attached to the frame
nearest in time (within ``sources.pose_tolerance_ms``); that frame is a keyframe and its
map points are the cloud's points that project into its image. Clouds are read as the
frames advance (``CloudStream``), so memory does not grow with the recording.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from slzcli.errors import DatasetError, DecodeError
from slzcli.geometry import project
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.keyframes import is_new_keyframe
from slzcli.types import Frame

if TYPE_CHECKING:
    from slzcli.config import Config

# sensor_msgs/PointField datatypes -> numpy kinds
_POINTFIELD = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def _get(msg: Any, name: str) -> Any:
    return getattr(msg, name)


def decode_pointcloud2(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """XYZ (N,3) float64 of the finite points of a PointCloud2 and their ids (int64, -1 without an id field).

    Works on rosbags ROS 1 and ROS 2 message objects (same field names). DecodeError when x/y/z are
    missing or the byte count does not match the declared layout.
    """
    fields = {f.name: f for f in _get(msg, "fields")}
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise DecodeError(f"PointCloud2 has no {'/'.join(missing)} field (fields: {', '.join(fields) or 'none'})")
    endian = ">" if _get(msg, "is_bigendian") else "<"
    names, formats, offsets = [], [], []
    for name in ("x", "y", "z", "id"):
        f = fields.get(name)
        if f is None:
            continue
        if f.datatype not in _POINTFIELD:
            raise DecodeError(f"PointCloud2 field {name!r} has unknown datatype {f.datatype}")
        names.append(name)
        formats.append(endian + _POINTFIELD[f.datatype])
        offsets.append(f.offset)
    step = int(_get(msg, "point_step"))
    n = int(_get(msg, "width")) * int(_get(msg, "height"))
    data = np.frombuffer(bytes(_get(msg, "data")) if not isinstance(_get(msg, "data"), np.ndarray)
                         else _get(msg, "data").tobytes(), dtype=np.uint8)
    row_step = int(_get(msg, "row_step"))
    height = int(_get(msg, "height"))
    if n == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    if step <= 0 or len(data) < row_step * (height - 1) + step * int(_get(msg, "width")):
        raise DecodeError(f"PointCloud2 data has {len(data)} bytes, too few for {n} points of {step} bytes")
    if row_step != step * int(_get(msg, "width")):
        rows = data[: row_step * height].reshape(height, row_step)[:, : step * int(_get(msg, "width"))]
        data = np.ascontiguousarray(rows).reshape(-1)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    pts = np.frombuffer(data[: n * step].tobytes(), dtype=dtype, count=n)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    ids = pts["id"].astype(np.int64) if "id" in names else np.full(n, -1, np.int64)
    ok = np.all(np.isfinite(xyz), axis=1)
    return xyz[ok], ids[ok]


class CloudStream:
    """The PointCloud2 messages of ``topic``, read as the frames advance, never all at once.

    Frames come in stamp order, so the stream reads ahead only to ``lookahead_ns`` past the
    current frame and forgets clouds older than it by more than the tolerance: memory holds
    the clouds near one frame however long the recording (the whole list used to be read
    before the first frame). Each cloud goes to one frame at most. A context manager.
    """

    def __init__(self, path: str | Path, topic: str, lookahead_ns: int) -> None:
        from slzcli.sources import guess_format

        self.path, self.topic, self.lookahead_ns = Path(path), topic, lookahead_ns
        fmt = guess_format(self.path)
        if fmt == "tum":
            raise DatasetError(self.path, f"slam.points_topic {topic!r}: TUM folders carry no point clouds")
        if fmt == "mcap":
            from slzcli.sources.mcap import McapLog
            self._log: Any = McapLog(self.path)
        else:
            from slzcli.sources.rosbag import RosbagLog
            self._log = RosbagLog(self.path if self.path.is_dir() or fmt == "ros1" else self.path.parent)
        self._log.open()
        try:
            if topic not in self._log.topics():
                raise DatasetError(self.path, f"slam.points_topic {topic!r} is not in the recording")
            self._messages = self._log.messages([topic])
            self._buffer: list[tuple[int, np.ndarray, np.ndarray]] = []  # by stamp
            self._done = False
            self._read_one()
        except BaseException:
            self._log.close()
            raise
        self.empty = not self._buffer

    def _read_one(self) -> None:
        from slzcli.sources.decode import stamp_ns

        raw = next(self._messages, None)
        if raw is None:
            self._done = True
            return
        msg = self._log.deserialize(self.topic, raw.data)
        try:
            xyz, ids = decode_pointcloud2(msg)
        except DecodeError as err:
            raise DatasetError(self.path, f"{self.topic}: {err}") from err
        cloud = (stamp_ns(msg.header), xyz, ids)
        self._buffer.insert(bisect.bisect_right([c[0] for c in self._buffer], cloud[0]), cloud)

    def nearest(self, stamp: int, tolerance_ns: int) -> tuple[int, np.ndarray, np.ndarray] | None:
        """The unused cloud nearest in stamp to ``stamp`` within ``tolerance_ns``, taken out of the stream."""
        while not self._done and (not self._buffer or self._buffer[-1][0] <= stamp + self.lookahead_ns):
            self._read_one()
        self._buffer = [c for c in self._buffer if c[0] >= stamp - tolerance_ns]
        if not self._buffer:
            return None
        best = min(range(len(self._buffer)), key=lambda j: abs(self._buffer[j][0] - stamp))
        if abs(self._buffer[best][0] - stamp) > tolerance_ns:
            return None
        return self._buffer.pop(best)

    def close(self) -> None:
        self._messages.close()  # a generator: closes the file it reads
        self._log.close()

    def __enter__(self) -> CloudStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_clouds(path: str | Path, config: Config) -> CloudStream | None:
    """The recorded map clouds of ``slam.points_topic``, or None when no topic is configured.

    Read-ahead: the pose tolerance plus the reorder window (a cloud may be logged after
    clouds of later stamps by up to that window, as frames are).
    """
    topic = config.slam.points_topic
    if not topic:
        return None
    ms = config.sources.pose_tolerance_ms + config.sources.reorder_window_ms
    return CloudStream(path, topic, int(ms * 1e6))


class RecordedBackend(BackendBase):
    """Replays recorded poses exactly; keyframes are the frames a recorded map cloud belongs to.

    Without any recorded cloud, keyframes follow the shared motion rule (slam.keyframe) and
    carry no points: the pipeline then samples map points from the keyframe's depth.
    """

    name = "recorded"
    poses_are_recorded = True
    map_points_from_depth = True

    def __init__(self, config: Config, clouds: CloudStream | None = None) -> None:
        self.clouds = clouds if clouds is not None and not clouds.empty else None
        self.tolerance_ns = int(config.sources.pose_tolerance_ms * 1e6)
        self._keyframe: MapPoints | None = None
        self._n_kf = 0
        self._kf_cfg = config.slam.keyframe
        self._last_kf_pose: np.ndarray | None = None

    def track(self, frame: Frame) -> TrackResult:
        self._keyframe = None
        if frame.T_world_camera is None:
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.LOST, None, False, 0)
        pose = np.asarray(frame.T_world_camera, np.float64)
        cloud = self.clouds.nearest(frame.stamp_ns, self.tolerance_ns) if self.clouds is not None else None
        if cloud is not None:
            _, xyz, ids = cloud
            uv, ok = project(xyz, pose, frame.K, (frame.intrinsics.height, frame.intrinsics.width))
            self._keyframe = MapPoints(ids[ok], xyz[ok], uv[ok], self._n_kf, frame.stamp_ns, pose)
            self._n_kf += 1
        elif self.clouds is None and is_new_keyframe(self._last_kf_pose, pose, 1, 1, self._kf_cfg.min_translation_m,
                                                 self._kf_cfg.min_rotation_deg, 0.0):
            self._keyframe = MapPoints.empty(self._n_kf, frame.stamp_ns, pose)
            self._last_kf_pose = pose
            self._n_kf += 1
        n = 0 if self._keyframe is None else len(self._keyframe)
        return TrackResult(frame.index, frame.stamp_ns, TrackingState.OK, pose, self._keyframe is not None, n)

    def keyframe(self) -> MapPoints | None:
        return self._keyframe
