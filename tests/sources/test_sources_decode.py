"""Pure decoders (decode.py) on hand-built messages: step padding, byte order, errors, maths."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from slzcli.errors import DecodeError
from slzcli.geometry import Pose
from slzcli.sources import decode

TS2 = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)


def header(ts, sec: int = 5, nsec: int = 7, frame: str = "cam"):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    if "seq" in t["std_msgs/msg/Header"].__dataclass_fields__:  # ROS 1 header
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def image(arr: np.ndarray, encoding: str, pad: int = 0, big: bool = False, ts=TS2):
    """An Image with ``pad`` junk bytes at the end of every row."""
    h = arr.shape[0]
    a = arr.astype(arr.dtype.newbyteorder(">" if big else "<")) if arr.dtype.itemsize > 1 else arr
    rows = np.ascontiguousarray(a).reshape(h, -1).view(np.uint8)
    padded = np.concatenate([rows, np.full((h, pad), 0xAB, np.uint8)], axis=1)
    return ts.types["sensor_msgs/msg/Image"](header=header(ts), height=h, width=arr.shape[1], encoding=encoding,
                                             is_bigendian=int(big), step=padded.shape[1], data=padded.reshape(-1))


def compressed(data: bytes, fmt: str, ts=TS2):
    return ts.types["sensor_msgs/msg/CompressedImage"](header=header(ts), format=fmt,
                                                       data=np.frombuffer(data, np.uint8))


@pytest.mark.parametrize("pad", [0, 3, 8])
@pytest.mark.parametrize("big", [False, True])
def test_depth_16uc1_honours_step_and_byte_order(pad: int, big: bool) -> None:
    counts = np.array([[0, 1000, 65535], [1, 2500, 0]], np.uint16)
    d = decode.decode_depth(image(counts, "16UC1", pad, big), 0.001)
    np.testing.assert_array_equal(np.isnan(d), counts == 0)
    np.testing.assert_allclose(d[counts > 0], counts[counts > 0] / 1000.0, rtol=1e-7)


@pytest.mark.parametrize("big", [False, True])
def test_depth_32fc1_exact_and_invalid_to_nan(big: bool) -> None:
    m = np.array([[0.0, 1.5, np.inf], [np.nan, 3.25, -1.0]], np.float32)
    d = decode.decode_depth(image(m, "32FC1", pad=4, big=big), 0.001)
    assert d[0, 1] == np.float32(1.5) and d[1, 1] == np.float32(3.25)
    assert np.isnan(d[[0, 0, 1, 1], [0, 2, 0, 2]]).all()


def test_max_depth_sets_far_pixels_to_nan() -> None:
    counts = np.array([[1000, 9000]], np.uint16)
    d = decode.decode_depth(image(counts, "mono16"), 0.001, max_depth_m=5.0)
    assert d[0, 0] == np.float32(1.0) and np.isnan(d[0, 1])


@pytest.mark.parametrize("enc,conv", [("rgb8", None), ("bgr8", cv2.COLOR_RGB2BGR), ("rgba8", cv2.COLOR_RGB2RGBA),
                                      ("bgra8", cv2.COLOR_RGB2BGRA)])
def test_colour_encodings_with_row_padding(enc: str, conv) -> None:
    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    raw = cv2.cvtColor(rgb, conv) if conv is not None else rgb
    np.testing.assert_array_equal(decode.decode_color(image(raw, enc, pad=5)), rgb)


def test_mono8_becomes_grey_rgb() -> None:
    g = np.arange(12, dtype=np.uint8).reshape(3, 4)
    out = decode.decode_color(image(g, "mono8", pad=1))
    assert out.shape == (3, 4, 3) and np.all(out == g[..., None])


def test_unsupported_encodings_name_the_encoding() -> None:
    with pytest.raises(DecodeError, match="yuv422"):
        decode.decode_color(image(np.zeros((2, 2, 2), np.uint8), "yuv422"))
    with pytest.raises(DecodeError, match="8UC1"):
        decode.decode_depth(image(np.zeros((2, 2), np.uint8), "8UC1"), 0.001)
    with pytest.raises(DecodeError, match="rvl"):
        decode.decode_depth(compressed(b"\0" * 40, "16UC1; compressedDepth rvl"), 0.001)


def test_short_image_data_is_a_decode_error() -> None:
    msg = image(np.zeros((4, 4), np.uint16), "16UC1")
    msg.height = 8
    with pytest.raises(DecodeError, match="bytes"):
        decode.decode_depth(msg, 0.001)


def test_compressed_depth_32fc1_follows_image_transport_formula() -> None:
    A, B = 10100.0, 1.0 - 10100.0 / 10.0
    q = np.array([[0, 3000, 65535]], np.uint16)
    _, png = cv2.imencode(".png", q)
    msg = compressed(struct.pack("<iff", 0, A, B) + png.tobytes(), "32FC1; compressedDepth png")
    d = decode.decode_depth(msg, 0.001)
    assert np.isnan(d[0, 0])
    np.testing.assert_allclose(d[0, 1:], np.float32(A) / (q[0, 1:].astype(np.float32) - np.float32(B)), rtol=1e-6)


def test_compressed_depth_16uc1_png_is_millimetres() -> None:
    q = np.array([[0, 1234]], np.uint16)
    _, png = cv2.imencode(".png", q)
    d = decode.decode_depth(compressed(b"\0" * 12 + png.tobytes(), "16UC1; compressedDepth"), 0.001)
    assert np.isnan(d[0, 0]) and d[0, 1] == np.float32(1.234)


def test_compressed_colour_garbage_is_a_decode_error() -> None:
    with pytest.raises(DecodeError, match="jpeg"):
        decode.decode_color(compressed(b"not a jpeg", "jpeg"))


@pytest.mark.parametrize("ts", [TS1, TS2])
def test_camera_info_ros1_and_ros2_fields(ts) -> None:
    t = ts.types
    K = np.array([500.0, 0, 320.5, 0, 501.0, 240.25, 0, 0, 1])
    keys = ("D", "K", "R", "P") if ts is TS1 else ("d", "k", "r", "p")
    roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    msg = t["sensor_msgs/msg/CameraInfo"](header=header(ts), height=480, width=640, distortion_model="plumb_bob",
                                          binning_x=0, binning_y=0, roi=roi,
                                          **dict(zip(keys, (np.array([0.1, -0.2, 0, 0, 0]), K, np.eye(3).ravel(),
                                                            np.zeros(12)), strict=True)))
    k = decode.decode_camera_info(msg)
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (500.0, 501.0, 320.5, 240.25, 640, 480)
    assert k.distortion_model == "plumb_bob" and k.distortion[:2] == (0.1, -0.2)


@pytest.mark.parametrize("ts,ros1", [(TS1, True), (TS2, False)])
def test_header_stamp_from_raw_bytes(ts, ros1: bool) -> None:
    msg = image(np.zeros((2, 2), np.uint16), "16UC1", ts=ts)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 123_456_789
    data = ts.serialize_ros1(msg, "sensor_msgs/msg/Image") if ros1 else \
        ts.serialize_cdr(msg, "sensor_msgs/msg/Image")
    assert decode.header_stamp(data, ros1) == (1_700_000_000_123_456_789, "cam")
    if not ros1:
        big = ts.serialize_cdr(msg, "sensor_msgs/msg/Image", little_endian=False)
        assert decode.header_stamp(big, False) == (1_700_000_000_123_456_789, "cam")
    with pytest.raises(DecodeError):
        decode.header_stamp(b"\0\1", ros1)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_quaternion_matrix_round_trip(q) -> None:
    R = decode.quat_to_matrix(*q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    T = np.eye(4)
    T[:3, :3] = R
    np.testing.assert_allclose(decode.quat_to_matrix(*Pose.from_matrix(T).as_quat()), R, atol=1e-9)


def test_compose_chain_and_cycles() -> None:
    a = np.eye(4)
    a[:3, 3] = (1, 0, 0)
    b = np.eye(4)
    b[:3, 3] = (0, 2, 0)
    tree = {"body": ("world", a), "cam": ("body", b)}
    chain = decode.compose_chain(tree, "cam")
    assert chain is not None
    top, T = chain
    assert top == "world"
    np.testing.assert_allclose(T[:3, 3], (1, 2, 0))
    chain = decode.compose_chain(tree, "cam", stop_at="body")
    assert chain is not None
    top, T = chain
    np.testing.assert_allclose(T, b)
    assert decode.compose_chain(tree, "cam", stop_at="map") is None
    with pytest.raises(DecodeError, match="cycle"):
        decode.compose_chain({"a": ("b", a), "b": ("a", a)}, "a")
