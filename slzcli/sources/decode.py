"""Pure decoders: deserialised ROS messages (ROS 1 or ROS 2 field names) -> numpy and types.

No I/O here. Images follow REP 118 for depth (16UC1/mono16 in millimetres via
``depth_unit_16u_m``, 0 = no data; 32FC1 in metres, 0/inf/NaN = no data). Poses are
``T_world_camera`` 4x4 float64. ``header_stamp`` reads a message's ``std_msgs/Header``
straight from the serialised bytes so that pairing never has to deserialise an image.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import cast

import cv2
import numpy as np

from slzcli.errors import DecodeError, short_repr
from slzcli.geometry import Pose
from slzcli.sources import ros_types as ros
from slzcli.sources.image_limits import FrameTooLarge, check_compressed, check_pixels
from slzcli.types import Intrinsics

# A damaged jpeg/png makes OpenCV's decoder print its own warnings and errors on stderr, around
# slz's one-line message; imdecode's None already becomes a DecodeError naming the message.
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)

# sensor_msgs/image_encodings: (numpy dtype, channels) of the raw layouts we read.
COLOR_ENCODINGS: dict[str, tuple[str, int]] = {
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4), "mono8": ("u1", 1),
    "8UC1": ("u1", 1), "8UC3": ("u1", 3),
}
DEPTH_ENCODINGS: dict[str, tuple[str, int]] = {"16UC1": ("u2", 1), "mono16": ("u2", 1), "32FC1": ("f4", 1)}
# compressed_depth_image_transport ConfigHeader: int32 format, float32 depthQuantA, float32 depthQuantB.
COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")


def _f(msg: object, ros2: str, ros1: str) -> object:
    """A field whose name differs between ROS 1 (upper case) and ROS 2 (lower case)."""
    value = getattr(msg, ros2, None)
    return getattr(msg, ros1) if value is None else value


def _is(msg: object, short_type: str) -> bool:
    """Whether a deserialised message is of type ``pkg/msg/short_type`` (rosbags sets __msgtype__)."""
    return str(getattr(msg, "__msgtype__", "")).rsplit("/", 1)[-1] == short_type


def stamp_ns(header: ros.Header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


# ----------------------------------------------------------------------------- raw headers
def header_stamp(data: bytes | memoryview, ros1: bool) -> tuple[int, str]:
    """(stamp_ns, frame_id) of a serialised message that starts with ``std_msgs/Header``.

    CDR: 4-byte encapsulation (byte 1 = 1 little endian), int32 sec, uint32 nanosec, string.
    ROS 1: uint32 seq, uint32 sec, uint32 nsec, string (no NUL). Raises DecodeError if short.
    """
    buf = bytes(data[:512]) if len(data) > 512 else bytes(data)
    try:
        if ros1:
            _, sec, nsec, n = struct.unpack_from("<IIII", buf, 0)
            frame = buf[16:16 + n].decode("utf-8", "replace")
        else:
            order = "<" if buf[1] == 1 else ">"
            sec, nsec, n = struct.unpack_from(order + "iII", buf, 4)
            frame = buf[16:16 + max(n - 1, 0)].decode("utf-8", "replace")
    except (struct.error, IndexError) as err:
        raise DecodeError(f"message too short for a std_msgs/Header ({len(data)} bytes)") from err
    return int(sec) * 1_000_000_000 + int(nsec), frame


# ----------------------------------------------------------------------------- images
def _raw_array(msg: ros.Image, dtype: str, channels: int, max_px: int = 0) -> np.ndarray:
    """HxW[xC] view of an Image's data honouring ``step`` (row padding) and ``is_bigendian``.

    ``max_px`` > 0: a declared width x height over it is ``FrameTooLarge`` before any copy.
    """
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    row = w * channels * itemsize
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0:
        raise DecodeError(f"Image {msg.encoding} is empty ({w}x{h} px)")
    check_pixels(w, h, max_px, f"Image {msg.encoding}")
    if step < row or data.size < step * h:
        raise DecodeError(f"Image {msg.encoding} {w}x{h}: data has {data.size} bytes, step {step}; "
                          f"expected at least {row} bytes per row and {step * h} in all")
    rows = data[: step * h].reshape(h, step)[:, :row]
    order = ">" if msg.is_bigendian else "<"
    arr = np.ascontiguousarray(rows).view(order + dtype) if itemsize > 1 else rows
    arr = arr.reshape((h, w, channels) if channels > 1 else (h, w))
    return arr.astype(arr.dtype.newbyteorder("=")) if itemsize > 1 else arr


def imdecode_bounded(buf: np.ndarray, flags: int, max_px: int, what: str) -> np.ndarray | None:
    """``cv2.imdecode`` after the header's size passed ``max_px``; OpenCV's own refusals become None.

    OpenCV throws (rather than returning None) on images over its ``CV_IO_MAX_IMAGE_PIXELS``
    and on some malformed headers: one such frame must not end the whole recording.
    """
    check_compressed(buf, max_px, what)
    try:
        return cv2.imdecode(buf, flags)
    except cv2.error:
        return None


def decode_color(msg: ros.Image | ros.CompressedImage, max_px: int = 0) -> np.ndarray:
    """``sensor_msgs/Image`` or ``CompressedImage`` (jpeg/png) -> uint8 HxWx3 RGB.

    ``max_px`` > 0 bounds the declared pixels (``sources.max_image_px``), checked before decoding.
    """
    if _is(msg, "CompressedImage"):
        msg = cast(ros.CompressedImage, msg)
        buf = np.frombuffer(msg.data, dtype=np.uint8)
        what = f"CompressedImage format {short_repr(str(msg.format), 40)}"
        img = imdecode_bounded(buf, cv2.IMREAD_COLOR, max_px, what) if buf.size else None
        if img is None:
            raise DecodeError(f"{what}: not a decodable jpeg/png")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    msg = cast(ros.Image, msg)
    enc = str(msg.encoding)
    if enc not in COLOR_ENCODINGS:
        raise DecodeError(f"unsupported colour encoding {short_repr(enc, 40)} "
                          f"(supported: {', '.join(COLOR_ENCODINGS)})")
    arr = _raw_array(msg, *COLOR_ENCODINGS[enc], max_px=max_px)
    convert = {"bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB,
               "mono8": cv2.COLOR_GRAY2RGB, "8UC1": cv2.COLOR_GRAY2RGB}.get(enc)
    return cv2.cvtColor(arr, convert) if convert is not None else np.ascontiguousarray(arr)


def depth_to_metres(raw: np.ndarray, depth_unit_16u_m: float, max_depth_m: float = 0.0) -> np.ndarray:
    """uint16 counts or float32 metres -> float32 metres with NaN for no data (and beyond max_depth_m)."""
    if raw.dtype == np.uint16:
        # Divide by counts per metre: correctly rounded when that is a whole number (1000, 5000).
        depth = raw.astype(np.float32) / np.float32(1.0 / depth_unit_16u_m)
        depth[raw == 0] = np.nan
    else:
        depth = raw.astype(np.float32, copy=True)
        depth[(depth <= 0) | ~np.isfinite(depth)] = np.nan
    if max_depth_m > 0:
        depth[depth > max_depth_m] = np.nan
    return depth


def decode_depth(msg: ros.Image | ros.CompressedImage, depth_unit_16u_m: float, max_depth_m: float = 0.0,
                 max_px: int = 0) -> np.ndarray:
    """Depth ``Image`` (16UC1, mono16, 32FC1) or ``compressedDepth`` -> float32 metres, NaN = no data."""
    if _is(msg, "CompressedImage"):
        return decode_compressed_depth(cast(ros.CompressedImage, msg), depth_unit_16u_m, max_depth_m, max_px)
    msg = cast(ros.Image, msg)
    enc = str(msg.encoding)
    if enc not in DEPTH_ENCODINGS:
        raise DecodeError(f"unsupported depth encoding {short_repr(enc, 40)} "
                          f"(supported: {', '.join(DEPTH_ENCODINGS)})")
    return depth_to_metres(_raw_array(msg, *DEPTH_ENCODINGS[enc], max_px=max_px), depth_unit_16u_m, max_depth_m)


def decode_compressed_depth(msg: ros.CompressedImage, depth_unit_16u_m: float, max_depth_m: float = 0.0,
                            max_px: int = 0) -> np.ndarray:
    """image_transport ``compressedDepth``: 12-byte ConfigHeader then a 16-bit PNG.

    16UC1: the PNG holds the raw counts. 32FC1: it holds inverse-depth codes q with
    depth = A / (q - B), q = 0 -> NaN (compressed_depth_image_transport/codec.cpp).
    """
    fmt = str(msg.format)
    encoding = fmt.split(";")[0].strip()
    shown = short_repr(fmt, 60)
    if "compresseddepth" not in fmt.lower().replace(" ", ""):
        raise DecodeError(f"CompressedImage format {shown} is not compressedDepth")
    if "rvl" in fmt.lower():
        raise DecodeError(f"unsupported compressedDepth codec in format {shown} (only png)")
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size <= COMPRESSED_DEPTH_HEADER.size:
        raise DecodeError(f"compressedDepth message of {data.size} bytes has no image after its header")
    _, quant_a, quant_b = COMPRESSED_DEPTH_HEADER.unpack(data[: COMPRESSED_DEPTH_HEADER.size].tobytes())
    payload = data[COMPRESSED_DEPTH_HEADER.size:]
    try:
        img = imdecode_bounded(payload, cv2.IMREAD_UNCHANGED, max_px, f"compressedDepth format {shown}")
    except DecodeError as err:
        if isinstance(err, FrameTooLarge):
            raise
        img = None
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise DecodeError(f"compressedDepth format {shown}: payload is not a 16-bit single-channel PNG")
    if encoding in ("16UC1", "mono16"):
        return depth_to_metres(img, depth_unit_16u_m, max_depth_m)
    if encoding == "32FC1":
        q = img.astype(np.float32)
        with np.errstate(divide="ignore"):
            depth = np.float32(quant_a) / (q - np.float32(quant_b))
        depth[img == 0] = np.nan
        return depth_to_metres(depth.astype(np.float32), depth_unit_16u_m, max_depth_m)
    raise DecodeError(f"unsupported compressedDepth encoding {short_repr(encoding, 40)} in format {shown}")


def match_depth_to_color(depth_m: np.ndarray, color_shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour resize of depth to the colour size (never blends depths across edges)."""
    h, w = color_shape
    if depth_m.shape == (h, w):
        return depth_m
    return cv2.resize(depth_m, (w, h), interpolation=cv2.INTER_NEAREST)


# ----------------------------------------------------------------------------- camera info
def decode_camera_info(msg: ros.CameraInfo) -> Intrinsics:
    """``CameraInfo`` -> Intrinsics (K row-major; distortion model and D recorded), not yet checked."""
    k = np.asarray(_f(msg, "k", "K"), dtype=np.float64).reshape(-1)
    if k.size != 9 or not np.all(np.isfinite(k)) or (k[0] == 0 and k[4] == 0):
        # Uncalibrated (ROS: K left zero) or unreadable; any other bad K is refused by validate.py.
        raise DecodeError(f"CameraInfo has no usable K ({k.tolist()})")
    d = tuple(float(v) for v in np.asarray(_f(msg, "d", "D"), dtype=np.float64).reshape(-1))
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width), int(msg.height),
                      str(msg.distortion_model), d)


# ----------------------------------------------------------------------------- poses
def quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation (normalised first; zero or non-finite rejected)."""
    q = np.array([x, y, z, w], dtype=np.float64)
    try:
        return Pose.from_quat(q, np.zeros(3)).rotation.as_matrix()
    except ValueError:
        raise DecodeError(f"invalid quaternion {q.tolist()}") from None


def transform_matrix(translation: ros.Vector3, rotation: ros.Quaternion) -> np.ndarray:
    """geometry_msgs Point/Vector3 + Quaternion -> 4x4."""
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(rotation.x, rotation.y, rotation.z, rotation.w)
    T[:3, 3] = (translation.x, translation.y, translation.z)
    if not np.all(np.isfinite(T[:3, 3])):
        raise DecodeError(f"non-finite position {T[:3, 3].tolist()}")
    return T


def decode_pose(msg: ros.PoseStamped | ros.Odometry) -> tuple[int, str, str, np.ndarray]:
    """PoseStamped or Odometry -> (stamp_ns, parent frame, child frame or '', T_parent_child)."""
    if _is(msg, "Odometry"):
        odom = cast(ros.Odometry, msg)
        pose, child = odom.pose.pose, str(odom.child_frame_id).lstrip("/")
    else:
        pose, child = cast(ros.PoseStamped, msg).pose, ""
    return (stamp_ns(msg.header), str(msg.header.frame_id).lstrip("/"), child,
            transform_matrix(pose.position, pose.orientation))


def decode_tf(msg: ros.TFMessage) -> list[tuple[int, str, str, np.ndarray]]:
    """TFMessage -> [(stamp_ns, parent, child, T_parent_child)] with leading '/' stripped from names."""
    return [(stamp_ns(t.header), t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/"),
             transform_matrix(t.transform.translation, t.transform.rotation)) for t in msg.transforms]


def compose_chain(tree: Mapping[str, tuple[str, np.ndarray]], frame: str,
                  stop_at: str | None = None) -> tuple[str, np.ndarray] | None:
    """Walk child -> parent links from ``frame`` to the root (or ``stop_at``): (top frame, T_top_frame).

    ``tree`` maps child frame -> (parent frame, T_parent_child). None when ``stop_at`` is
    not on the chain. A cycle is reported as DecodeError naming the frames.
    """
    T = np.eye(4)
    node = frame.lstrip("/")
    seen: list[str] = []
    while node != stop_at and node in tree:
        if node in seen:
            raise DecodeError(f"tf cycle through frames {' -> '.join([*seen, node])}")
        seen.append(node)
        parent, T_parent_node = tree[node]
        T = T_parent_node @ T
        node = parent
    if stop_at is not None and node != stop_at:
        return None
    return node, T


# sensor_msgs/PointField datatypes -> numpy kinds
POINTFIELD_KINDS = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def decode_pointcloud2(msg: ros.PointCloud2) -> tuple[np.ndarray, np.ndarray]:
    """XYZ (N,3) float64 of the finite points of a PointCloud2 and their ids (int64, -1 without an id field).

    Works on rosbags ROS 1 and ROS 2 message objects (same field names). DecodeError when x/y/z are
    missing or the byte count does not match the declared layout.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise DecodeError(f"PointCloud2 has no {'/'.join(missing)} field (fields: {', '.join(fields) or 'none'})")
    endian = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name in ("x", "y", "z", "id"):
        f = fields.get(name)
        if f is None:
            continue
        if f.datatype not in POINTFIELD_KINDS:
            raise DecodeError(f"PointCloud2 field {name!r} has unknown datatype {f.datatype}")
        names.append(name)
        formats.append(endian + POINTFIELD_KINDS[f.datatype])
        offsets.append(f.offset)
    step = int(msg.point_step)
    width, height = int(msg.width), int(msg.height)
    n = width * height
    raw = msg.data
    data = np.frombuffer(raw.tobytes() if isinstance(raw, np.ndarray) else bytes(raw), dtype=np.uint8)
    row_step = int(msg.row_step)
    if n == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    if step <= 0 or len(data) < row_step * (height - 1) + step * width:
        raise DecodeError(f"PointCloud2 data has {len(data)} bytes, too few for {n} points of {step} bytes")
    if row_step != step * width:
        rows = data[: row_step * height].reshape(height, row_step)[:, : step * width]
        data = np.ascontiguousarray(rows).reshape(-1)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    pts = np.frombuffer(data[: n * step].tobytes(), dtype=dtype, count=n)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    ids = pts["id"].astype(np.int64) if "id" in names else np.full(n, -1, np.int64)
    ok = np.all(np.isfinite(xyz), axis=1)
    return xyz[ok], ids[ok]
