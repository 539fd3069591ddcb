"""The one recording writer (tests, ``slz synth``, benchmarks): Frames and poses -> a ROS recording.

Formats: ``mcap`` (ROS 2 CDR MCAP), ``mcap-ros1`` (ROS 1 encoded MCAP), ``ros1`` (.bag),
``ros2-sqlite`` and ``ros2-mcap`` (rosbag2 folders). Colour encodings: rgb8, bgr8, rgba8,
bgra8, mono8, jpeg, png (CompressedImage on ``<color>/compressed``). Depth encodings:
16UC1, mono16 (millimetres, 0 = no data), 32FC1 (metres, NaN = no data), compressedDepth
(image_transport, 16UC1 PNG) and compressedDepth-32FC1 (inverse-depth PNG) on
``<depth>/compressedDepth``. Writes go to a temporary name beside the target and are
renamed into place on a clean close; on an exception the temporary is removed. A rosbag2
folder is written under its final name inside a temporary parent folder, because rosbag2
names its storage files and ``metadata.yaml`` entries after the bag folder: the bytes then
do not depend on the temporary name (same frames -> same files).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, ClassVar, Literal, Protocol

import cv2
import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from slzcli.errors import OutputError
from slzcli.geometry import Pose
from slzcli.outputs import safe_output
from slzcli.sources.decode import COMPRESSED_DEPTH_HEADER
from slzcli.sources.ros_types import Message
from slzcli.types import Frame, Intrinsics

if TYPE_CHECKING:
    from rosbags.interfaces import Connection
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

FORMATS = ("mcap", "mcap-ros1", "ros1", "ros2-sqlite", "ros2-mcap")
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8", "jpeg", "png")
MCAP_COMPRESSIONS = ("zstd", "lz4", "none")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1", "compressedDepth", "compressedDepth-32FC1")
# image_transport compressedDepth publisher defaults (CompressedDepthPublisher.cfg): the
# inverse-depth code of 32FC1 depth is q = A / d + B with A = z0 (z0 + 1), B = 1 - A / depth_max.
COMPRESSED_DEPTH_MAX_M = 10.0
COMPRESSED_DEPTH_QUANTIZATION = 100.0
REP118_DEPTH_UNIT_M = 0.001  # 16UC1 depth is millimetres (REP 118)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
POSE_TYPES = {"PoseStamped": "geometry_msgs/msg/PoseStamped", "Odometry": "nav_msgs/msg/Odometry",
              "tf": "tf2_msgs/msg/TFMessage"}
TF_MESSAGE_DEF = "geometry_msgs/TransformStamped[] transforms"  # tf2_msgs/TFMessage.msg


@dataclass(frozen=True)
class TopicLayout:
    """Topic names and the optical frame id a writer uses (RealSense ROS wrapper names by default)."""

    color: str = "/camera/color/image_raw"
    color_info: str = "/camera/color/camera_info"
    depth: str = "/camera/aligned_depth_to_color/image_raw"
    depth_info: str = "/camera/aligned_depth_to_color/camera_info"
    frame_id: str = "camera_color_optical_frame"


REALSENSE = TopicLayout()


class RosMessage(Protocol):
    """A message object this writer builds: an instance of a class its rosbags typestore made at run time from the
    message definition (``typestore.types[msgtype]``), named by its type; serialised by the typestore."""

    __msgtype__: ClassVar[str]


class RecordingWriter:
    """Context manager writing frames, poses and raw messages to one recording, atomically."""

    def __init__(self, path: str | Path, fmt: str = "mcap", *, color_encoding: str = "rgb8",
                 depth_encoding: str = "16UC1", layout: TopicLayout = REALSENSE, big_endian: bool = False,
                 depth_unit_m: float = REP118_DEPTH_UNIT_M, chunk_bytes: int | None = None,
                 compression: str = "zstd") -> None:
        """``compression``: of an MCAP file's chunks, ``zstd`` (mcap's default), ``lz4`` or ``none``; both
        compressions are in the MCAP spec and read by Foxglove, ``mcap`` and rosbags (ignored by .bag/sqlite)."""
        if fmt not in FORMATS:
            raise OutputError(path, f"unknown recording format {fmt!r} (one of {', '.join(FORMATS)})")
        if color_encoding not in COLOR_ENCODINGS:
            raise OutputError(path, f"unknown colour encoding {color_encoding!r} (one of {', '.join(COLOR_ENCODINGS)})")
        if depth_encoding not in DEPTH_ENCODINGS:
            raise OutputError(path, f"unknown depth encoding {depth_encoding!r} (one of {', '.join(DEPTH_ENCODINGS)})")
        if compression not in MCAP_COMPRESSIONS:
            raise OutputError(path, f"unknown MCAP compression {compression!r} (one of {', '.join(MCAP_COMPRESSIONS)})")
        self.path = Path(path)
        self.fmt = fmt
        self.color_encoding = color_encoding
        self.depth_encoding = depth_encoding
        self.layout = layout
        self.big_endian = big_endian
        self.depth_unit_m = depth_unit_m
        self.chunk_bytes = chunk_bytes
        self.compression = compression
        self.ros1 = fmt in ("ros1", "mcap-ros1")
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if POSE_TYPES["tf"] not in self.typestore.fielddefs:  # the Noetic store lacks tf2_msgs
            self.typestore.register(get_types_from_msg(TF_MESSAGE_DEF, POSE_TYPES["tf"]))
        # Staging: the file itself (mcap, ros1) or a parent holding the bag folder (rosbag2).
        self._staging = self.path.parent / f".{self.path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
        self._tmp = self._staging / self.path.name if fmt.startswith("ros2") else self._staging
        self._backend: _Backend | None = None
        self.frames_written = 0

    @property
    def color_topic(self) -> str:
        return self.layout.color + ("/compressed" if self.color_encoding in ("jpeg", "png") else "")

    @property
    def depth_topic(self) -> str:
        return self.layout.depth + ("/compressedDepth" if self.depth_encoding.startswith("compressedDepth") else "")

    # ------------------------------------------------------------------ context
    def __enter__(self) -> RecordingWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:
        if not self.path.parent.is_dir():
            raise OutputError(self.path, "parent folder does not exist")
        if os.path.lexists(self._staging):  # not ours: never removed
            raise OutputError(self._staging, "exists; slz does not replace it: move it away")
        try:
            if self._tmp != self._staging:
                self._staging.mkdir()
            self._backend = _BACKENDS[self.fmt](self._tmp, self)
        except BaseException as err:
            _remove(self._staging)
            if isinstance(err, OSError):
                raise OutputError(self.path, f"cannot create ({err})") from err
            raise

    def close(self) -> None:
        """Finish the file and move it into place (replacing an older recording of that name)."""
        if self._backend is None:
            return
        backend, self._backend = self._backend, None
        try:
            backend.close()
            if self.path.is_dir() and self._tmp.is_dir():
                old = safe_output.make_temp_dir(self.path, ".old")
                os.replace(self.path, old / self.path.name)
                os.replace(self._tmp, self.path)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(self._tmp, self.path)
            _remove(self._staging)
        except OSError as err:
            _remove(self._staging)
            raise OutputError(self.path, f"cannot finish writing ({err})") from err

    def abort(self) -> None:
        """Drop everything written so far (the target path is left untouched)."""
        backend, self._backend = self._backend, None
        if backend is not None:
            with contextlib.suppress(Exception):
                backend.close()
        _remove(self._staging)

    # ------------------------------------------------------------------ writing
    def write_frame(self, frame: Frame) -> None:
        """Colour, depth and both CameraInfos, all stamped with ``frame.stamp_ns``."""
        lay, stamp = self.layout, frame.stamp_ns
        self._write(self.color_topic, *self.color_message(frame.rgb, stamp), stamp)
        self._write(self.depth_topic, *self.depth_message(frame.depth_m, stamp), stamp)
        info = frame.intrinsics
        self._write(lay.color_info, CAMERA_INFO, self._camera_info(info, stamp), stamp)
        self._write(lay.depth_info, CAMERA_INFO, self._camera_info(info, stamp), stamp)
        self.frames_written += 1

    def write_pose(self, topic: str, stamp_ns: int, T_world_camera: np.ndarray,
                   kind: Literal["PoseStamped", "Odometry", "tf"] = "PoseStamped", parent: str = "world",
                   child: str = "camera_color_optical_frame") -> None:
        """One pose as PoseStamped (of ``child``, implied), Odometry or a one-transform TFMessage."""
        if kind not in POSE_TYPES:
            raise OutputError(self.path, f"unknown pose kind {kind!r} (one of {', '.join(POSE_TYPES)})")
        T = np.asarray(T_world_camera, dtype=np.float64)
        t = self.typestore.types
        gm = "geometry_msgs/msg/"
        q = Pose.from_matrix(T).as_quat()
        quat = t[gm + "Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
        header = self._header(stamp_ns, parent)
        if kind == "tf":
            tr = t[gm + "Transform"](translation=t[gm + "Vector3"](*map(float, T[:3, 3])), rotation=quat)
            msg = t[POSE_TYPES["tf"]](transforms=[t[gm + "TransformStamped"](header=header, child_frame_id=child,
                                                                              transform=tr)])
        else:
            pose = t[gm + "Pose"](position=t[gm + "Point"](*map(float, T[:3, 3])), orientation=quat)
            if kind == "PoseStamped":
                msg = t[POSE_TYPES["PoseStamped"]](header=header, pose=pose)
            else:
                zeros = np.zeros(36, dtype=np.float64)
                twist = t[gm + "Twist"](linear=t[gm + "Vector3"](0.0, 0.0, 0.0),
                                        angular=t[gm + "Vector3"](0.0, 0.0, 0.0))
                msg = t[POSE_TYPES["Odometry"]](
                    header=header, child_frame_id=child,
                    pose=t[gm + "PoseWithCovariance"](pose=pose, covariance=zeros),
                    twist=t[gm + "TwistWithCovariance"](twist=twist, covariance=zeros.copy()))
        self._write(topic, POSE_TYPES[kind], msg, stamp_ns)

    def write_imu(self, topic: str, stamp_ns: int, accel: np.ndarray, gyro: np.ndarray | None,
                  frame_id: str = "") -> None:
        """One sensor_msgs/Imu: specific force (m/s^2) and angular rate (rad/s, None: zeros, covariance -1 as
        realsense-ros writes an accelerometer-only message); no orientation (covariance[0] = -1, REP 145)."""
        t = self.typestore.types
        vec = t["geometry_msgs/msg/Vector3"]
        unknown = np.zeros(9, dtype=np.float64)
        unknown[0] = -1.0
        msg = t[IMU](header=self._header(stamp_ns, frame_id or self.layout.frame_id),
                     orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                     orientation_covariance=unknown,
                     angular_velocity=vec(*map(float, gyro if gyro is not None else (0.0, 0.0, 0.0))),
                     angular_velocity_covariance=np.zeros(9) if gyro is not None else unknown.copy(),
                     linear_acceleration=vec(*map(float, accel)), linear_acceleration_covariance=np.zeros(9))
        self._write(topic, IMU, msg, stamp_ns)

    def write_raw(self, topic: str, msgtype: str, msg: Message | bytes, stamp_ns: int) -> None:
        """Any message: an instance from ``self.typestore`` or already serialised bytes."""
        self._write(topic, msgtype, msg, stamp_ns)

    def message(self, msgtype: str, **fields: Message) -> Message:
        """A message object of this writer's typestore (for ``write_raw``)."""
        return self.typestore.types[msgtype](**fields)

    def header(self, stamp_ns: int, frame_id: str = "") -> Message:
        return self._header(stamp_ns, frame_id or self.layout.frame_id)

    def color_message(self, rgb: np.ndarray, stamp_ns: int) -> tuple[str, Message]:
        """(msgtype, message) of a colour image in this writer's encoding (for ``write_raw``)."""
        if self.color_encoding in ("jpeg", "png"):
            return COMPRESSED, self._compressed_color(rgb, stamp_ns)
        return IMAGE, self._color_image(rgb, stamp_ns)

    def depth_message(self, depth_m: np.ndarray, stamp_ns: int) -> tuple[str, Message]:
        """(msgtype, message) of a depth image in this writer's encoding (for ``write_raw``)."""
        if self.depth_encoding.startswith("compressedDepth"):
            return COMPRESSED, self._compressed_depth(depth_m, stamp_ns)
        return IMAGE, self._depth_image(depth_m, stamp_ns)

    # ------------------------------------------------------------------ messages
    def _write(self, topic: str, msgtype: str, msg: Message | bytes, stamp_ns: int) -> None:
        if self._backend is None:
            raise OutputError(self.path, "writer is not open (use it as a context manager)")
        data: bytes | memoryview
        if isinstance(msg, (bytes, bytearray, memoryview)):
            data = bytes(msg)
        elif self.ros1:
            data = self.typestore.serialize_ros1(msg, msgtype)
        else:
            data = self.typestore.serialize_cdr(msg, msgtype)
        try:
            self._backend.write(topic, msgtype, data, int(stamp_ns))
        except OSError as err:  # disk full, quota, read-only: name the recording, not "internal error"
            raise OutputError(self.path, f"cannot write ({err.strerror or err})") from err

    def _header(self, stamp_ns: int, frame_id: str) -> Message:
        t = self.typestore.types
        stamp = t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000),
                                                 nanosec=int(stamp_ns % 1_000_000_000))
        if self.ros1:
            return t["std_msgs/msg/Header"](seq=self.frames_written, stamp=stamp, frame_id=frame_id)
        return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _image(self, stamp: int, arr: np.ndarray, encoding: str) -> Message:
        h, w = arr.shape[:2]
        data = np.ascontiguousarray(arr)
        if self.big_endian and data.dtype.itemsize > 1:
            data = data.astype(data.dtype.newbyteorder(">"))
        raw = data.reshape(-1).view(np.uint8)
        return self.typestore.types[IMAGE](header=self._header(stamp, self.layout.frame_id), height=h, width=w,
                                           encoding=encoding, is_bigendian=int(self.big_endian),
                                           step=raw.size // h, data=raw)

    def _color_image(self, rgb: np.ndarray, stamp: int) -> Message:
        enc = self.color_encoding
        conv = {"bgr8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGB2RGBA, "bgra8": cv2.COLOR_RGB2BGRA,
                "mono8": cv2.COLOR_RGB2GRAY}.get(enc)
        arr = cv2.cvtColor(rgb, conv) if conv is not None else rgb
        return self._image(stamp, arr, enc)

    def _compressed_color(self, rgb: np.ndarray, stamp: int) -> Message:
        ok, buf = cv2.imencode("." + ("jpg" if self.color_encoding == "jpeg" else "png"),
                               cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OutputError(self.path, f"OpenCV could not encode a {self.color_encoding} image")
        return self.typestore.types[COMPRESSED](header=self._header(stamp, self.layout.frame_id),
                                                format=f"bgr8; {self.color_encoding} compressed bgr8",
                                                data=buf.reshape(-1))

    def _depth_counts(self, depth_m: np.ndarray) -> np.ndarray:
        counts = np.rint(np.nan_to_num(depth_m, nan=0.0, posinf=0.0, neginf=0.0) / self.depth_unit_m)
        return np.clip(counts, 0, np.iinfo(np.uint16).max).astype(np.uint16)

    def _depth_image(self, depth_m: np.ndarray, stamp: int) -> Message:
        if self.depth_encoding == "32FC1":
            return self._image(stamp, depth_m.astype(np.float32), "32FC1")
        return self._image(stamp, self._depth_counts(depth_m), self.depth_encoding)

    def _compressed_depth(self, depth_m: np.ndarray, stamp: int) -> Message:
        if self.depth_encoding == "compressedDepth-32FC1":
            z0, dmax = COMPRESSED_DEPTH_QUANTIZATION, COMPRESSED_DEPTH_MAX_M
            quant_a = np.float32(z0 * (z0 + 1.0))
            quant_b = np.float32(1.0 - quant_a / dmax)
            d = depth_m.astype(np.float32)
            ok = np.isfinite(d) & (d > 0) & (d < dmax)
            code = np.zeros(d.shape, dtype=np.float64)
            code[ok] = quant_a / d[ok] + quant_b
            # Depths nearer than A / 65535 (~0.15 m) overflow the 16-bit code: written as "no data".
            code[code > np.iinfo(np.uint16).max] = 0
            q = code.astype(np.uint16)
            img, header = q, COMPRESSED_DEPTH_HEADER.pack(0, float(quant_a), float(quant_b))
            fmt = "32FC1; compressedDepth png"
        else:
            img, header, fmt = self._depth_counts(depth_m), COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0), \
                "16UC1; compressedDepth png"
        ok_png, buf = cv2.imencode(".png", img)
        if not ok_png:
            raise OutputError(self.path, "OpenCV could not encode a 16-bit depth PNG")
        data = np.concatenate([np.frombuffer(header, dtype=np.uint8), buf.reshape(-1)])
        return self.typestore.types[COMPRESSED](header=self._header(stamp, self.layout.frame_id), format=fmt, data=data)

    def _camera_info(self, k: Intrinsics, stamp: int) -> Message:
        t = self.typestore.types
        K = k.K.reshape(-1).astype(np.float64)
        P = np.array([k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0], dtype=np.float64)
        D = np.asarray(k.distortion if k.distortion else (0.0,) * 5, dtype=np.float64)
        R = np.eye(3).reshape(-1)
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        fields: dict[str, RosMessage | int | str | np.ndarray] = dict(
            header=self._header(stamp, self.layout.frame_id), height=k.height, width=k.width,
            distortion_model=k.distortion_model or "plumb_bob", binning_x=0, binning_y=0, roi=roi)
        keys = ("D", "K", "R", "P") if self.ros1 else ("d", "k", "r", "p")
        fields.update(dict(zip(keys, (D, K, R, P), strict=True)))
        return t[CAMERA_INFO](**fields)


# ----------------------------------------------------------------------------- backends
class _Backend:
    def write(self, topic: str, msgtype: str, data: bytes | memoryview, stamp_ns: int) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _McapBackend(_Backend):
    def __init__(self, tmp: Path, w: RecordingWriter) -> None:
        from mcap.writer import CompressionType, Writer

        self.w = w
        self.f = tmp.open("wb")
        compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if w.chunk_bytes:
            self.mcap = Writer(self.f, compression=compression[w.compression], chunk_size=w.chunk_bytes)
        else:  # mcap's own default chunk size
            self.mcap = Writer(self.f, compression=compression[w.compression])
        self.mcap.start(profile="ros1" if w.ros1 else "ros2", library="slz")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}

    def write(self, topic: str, msgtype: str, data: bytes | memoryview, stamp_ns: int) -> None:
        if topic not in self.channels:
            if msgtype not in self.schemas:
                ver = 1 if self.w.ros1 else 2
                text, _ = self.w.typestore.generate_msgdef(msgtype, ros_version=ver)
                name = msgtype.replace("/msg/", "/") if self.w.ros1 else msgtype
                self.schemas[msgtype] = self.mcap.register_schema(
                    name, "ros1msg" if self.w.ros1 else "ros2msg", text.encode())
            self.channels[topic] = self.mcap.register_channel(
                topic, "ros1" if self.w.ros1 else "cdr", self.schemas[msgtype])
        # mcap writes any buffer (its annotation says bytes): rosbags serialises to a memoryview
        self.mcap.add_message(self.channels[topic], log_time=stamp_ns, data=data,  # type: ignore[arg-type]
                              publish_time=stamp_ns)

    def close(self) -> None:
        try:
            self.mcap.finish()
        finally:
            self.f.close()


class _RosbagBackend(_Backend):
    def __init__(self, tmp: Path, w: RecordingWriter) -> None:
        self.w = w
        if w.fmt == "ros1":
            from rosbags.rosbag1 import Writer as Writer1

            self.bag: Writer1 | Writer2 = Writer1(tmp)
        else:
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2

            plugin = StoragePlugin.MCAP if w.fmt == "ros2-mcap" else StoragePlugin.SQLITE3
            self.bag = Writer2(tmp, version=8, storage_plugin=plugin)
        self.bag.open()
        self.conns: dict[str, Connection] = {}

    def write(self, topic: str, msgtype: str, data: bytes | memoryview, stamp_ns: int) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.bag.add_connection(topic, msgtype, typestore=self.w.typestore)
        self.bag.write(self.conns[topic], stamp_ns, data)

    def close(self) -> None:
        self.bag.close()


_BACKENDS: dict[str, Callable[[Path, RecordingWriter], _Backend]] = {
    "mcap": _McapBackend, "mcap-ros1": _McapBackend,
    "ros1": _RosbagBackend, "ros2-sqlite": _RosbagBackend, "ros2-mcap": _RosbagBackend,
}


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists():
        path.unlink()
