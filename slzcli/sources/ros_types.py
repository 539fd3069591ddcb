"""The fields slz reads of deserialised ROS messages, as Protocols (read-only members).

rosbags builds its message classes at run time from the recording's own definitions (a typestore), so
no static type names them; these say which fields the decoders read, and mypy holds the decoders to them.
ROS 1 and ROS 2 share the names below except the time and CameraInfo fields (``sec``/``nanosec`` vs
``secs``/``nsecs`` is hidden by rosbags' ROS 1 typestore, which uses the ROS 2 names; ``k``/``K`` and
``d``/``D`` are read by ``decode._f`` by name). ``Message`` is what a reader hands out before its type is
known (``MessageLog.deserialize``): the one place the value is untyped, narrowed by the decoder its topic
goes to.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

Message = Any  # a deserialised message of a type known only from its topic (rosbags' run-time classes)
Bytes = bytes | memoryview | np.ndarray  # a message's uint8[] field as rosbags or a test gives it


class Time(Protocol):
    @property
    def sec(self) -> int: ...
    @property
    def nanosec(self) -> int: ...


class Header(Protocol):
    @property
    def stamp(self) -> Time: ...
    @property
    def frame_id(self) -> str: ...


class Stamped(Protocol):
    """A message with a std_msgs/Header."""

    @property
    def header(self) -> Header: ...


class Image(Protocol):
    """sensor_msgs/Image."""

    @property
    def height(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def encoding(self) -> str: ...
    @property
    def is_bigendian(self) -> int: ...
    @property
    def step(self) -> int: ...
    @property
    def data(self) -> Bytes: ...


class CompressedImage(Protocol):
    """sensor_msgs/CompressedImage (and image_transport's compressedDepth in it)."""

    @property
    def format(self) -> str: ...
    @property
    def data(self) -> Bytes: ...


class Vector3(Protocol):
    """geometry_msgs/Vector3 or Point."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def z(self) -> float: ...


class Quaternion(Vector3, Protocol):
    @property
    def w(self) -> float: ...


class Transform(Protocol):
    """geometry_msgs/Transform."""

    @property
    def translation(self) -> Vector3: ...
    @property
    def rotation(self) -> Quaternion: ...


class TransformStamped(Stamped, Protocol):
    @property
    def child_frame_id(self) -> str: ...
    @property
    def transform(self) -> Transform: ...


class TFMessage(Protocol):
    """tf2_msgs/TFMessage (/tf, /tf_static)."""

    @property
    def transforms(self) -> Sequence[TransformStamped]: ...


class PointField(Protocol):
    @property
    def name(self) -> str: ...
    @property
    def offset(self) -> int: ...
    @property
    def datatype(self) -> int: ...


class PointCloud2(Stamped, Protocol):
    """sensor_msgs/PointCloud2."""

    @property
    def fields(self) -> Sequence[PointField]: ...
    @property
    def is_bigendian(self) -> int: ...
    @property
    def point_step(self) -> int: ...
    @property
    def row_step(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def data(self) -> Bytes: ...


class Imu(Stamped, Protocol):
    """sensor_msgs/Imu."""

    @property
    def linear_acceleration(self) -> Vector3: ...
    @property
    def angular_velocity(self) -> Vector3: ...


class CameraInfo(Protocol):
    """sensor_msgs/CameraInfo (K and D are read by name: ``k``/``K``, ``d``/``D``)."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def distortion_model(self) -> str: ...


class Pose(Protocol):
    @property
    def position(self) -> Vector3: ...
    @property
    def orientation(self) -> Quaternion: ...


class PoseStamped(Stamped, Protocol):
    @property
    def pose(self) -> Pose: ...


class PoseWithCovariance(Protocol):
    @property
    def pose(self) -> Pose: ...


class Odometry(Stamped, Protocol):
    @property
    def child_frame_id(self) -> str: ...
    @property
    def pose(self) -> PoseWithCovariance: ...
