"""The recorded backend: poses and map points that a SLAM system already published in the recording.

Frame poses arrive through ``Frame.T_world_camera`` (the sources layer reads PoseStamped,
Odometry or /tf); map points come from a ``sensor_msgs/PointCloud2`` topic (what ORB-SLAM3 ROS
wrappers publish), decoded here with ``decode_pointcloud2`` (kept here, not in
sources/decode.py, while that module is being written). A cloud is attached to the frame
nearest in time (within ``sources.pose_tolerance_ms``); that frame is a keyframe and its
map points are the cloud's points that project into its image.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from slzcli.errors import DatasetError, DecodeError
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.keyframes import is_new_keyframe, project
from slzcli.types import Frame

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


def read_point_clouds(path: str | Path, topic: str, config: Any) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(stamp_ns, xyz, ids) of every PointCloud2 on ``topic`` of a message recording, in time order."""
    from slzcli.sources import guess_format
    from slzcli.sources.decode import stamp_ns

    p = Path(path)
    fmt = guess_format(p)
    if fmt == "tum":
        raise DatasetError(p, f"slam.points_topic {topic!r}: TUM folders carry no point clouds")
    if fmt == "mcap":
        from slzcli.sources.mcap import McapLog
        log = McapLog(p)
    else:
        from slzcli.sources.rosbag import RosbagLog
        log = RosbagLog(p if p.is_dir() or fmt == "ros1" else p.parent)
    log.open()
    try:
        if topic not in log.topics():
            raise DatasetError(p, f"slam.points_topic {topic!r} is not in the recording")
        out = []
        for raw in log.messages([topic]):
            msg = log.deserialize(topic, raw.data)
            try:
                xyz, ids = decode_pointcloud2(msg)
            except DecodeError as err:
                raise DatasetError(p, f"{topic}: {err}") from err
            out.append((stamp_ns(msg.header), xyz, ids))
    finally:
        log.close()
    return sorted(out, key=lambda c: c[0])


class RecordedBackend(BackendBase):
    """Replays recorded poses exactly; keyframes are the frames a recorded map cloud belongs to.

    Without any recorded cloud, keyframes follow the shared motion rule (slam.keyframe) and
    carry no points: the pipeline then samples map points from the keyframe's depth.
    """

    name = "recorded"

    def __init__(self, config: Any, clouds: Sequence[tuple[int, np.ndarray, np.ndarray]] = ()) -> None:
        self.clouds = list(clouds)
        self.stamps = [c[0] for c in self.clouds]
        self.tolerance_ns = int(config.sources.pose_tolerance_ms * 1e6)
        self.used: set[int] = set()
        self._keyframe: MapPoints | None = None
        self._n_kf = 0
        self._kf_cfg = config.slam.keyframe
        self._last_kf_pose: np.ndarray | None = None

    def _cloud_for(self, stamp: int) -> int | None:
        i = bisect.bisect_left(self.stamps, stamp)
        best = min((j for j in (i - 1, i) if 0 <= j < len(self.stamps)),
                   key=lambda j: abs(self.stamps[j] - stamp), default=None)
        if best is None or best in self.used or abs(self.stamps[best] - stamp) > self.tolerance_ns:
            return None
        return best

    def track(self, frame: Frame) -> TrackResult:
        self._keyframe = None
        if frame.T_world_camera is None:
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.LOST, None, False, 0)
        pose = np.asarray(frame.T_world_camera, np.float64)
        j = self._cloud_for(frame.stamp_ns)
        if j is not None:
            self.used.add(j)
            _, xyz, ids = self.clouds[j]
            uv, ok = project(xyz, pose, frame.K, frame.intrinsics.width, frame.intrinsics.height)
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
