"""Helpers shared by tests in several folders: small known frames and recordings, the real frames as recordings."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slzcli.outputs.recording import RecordingWriter
from slzcli.types import Frame, Intrinsics

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
INTR = Intrinsics(60.5, 61.25, 15.5, 11.75, 32, 24)
SUFFIX = {"mcap": ".mcap", "mcap-ros1": ".mcap", "ros1": ".bag", "ros2-sqlite": "", "ros2-mcap": ""}


def known_frame(i: int = 0, h: int = 24, w: int = 32) -> Frame:
    """A frame with a distinct pattern per index; depth in whole millimetres with holes (NaN)."""
    rng = np.random.default_rng(i)
    v, u = np.mgrid[0:h, 0:w]
    # Smooth (so jpeg stays close) but different in every channel (so a swapped order shows).
    rgb = np.stack([u * 255 // max(w - 1, 1), v * 255 // max(h - 1, 1), (u + v + 7 * i) * 3 % 256],
                   axis=-1).astype(np.uint8)
    depth_mm = rng.integers(300, 9000, (h, w))
    depth = (depth_mm / 1000.0).astype(np.float32)
    depth[rng.random((h, w)) < 0.1] = np.nan
    intr = INTR if (w, h) == (INTR.width, INTR.height) else INTR.scaled(w, h)
    return Frame(i, T0_NS + i * PERIOD_NS, rgb, depth, intr)


def write_frames(path: Path, fmt: str, n: int = 3, **kwargs) -> list[Frame]:
    frames = [known_frame(i) for i in range(n)]
    with RecordingWriter(path, fmt, **kwargs) as w:
        for f in frames:
            w.write_frame(f)
    return frames


def pose(i: int) -> np.ndarray:
    """A smooth, non-trivial pose for frame i."""
    a = 0.1 * i
    T = np.eye(4)
    T[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]])  # camera looking down
    T[:3, 3] = (0.5 * i, -0.25 * i, 10.0 - 0.1 * i)
    return T


def realsense_intrinsics(root: Path) -> Intrinsics:
    """The real RealSense frames' colour intrinsics (``cam_params_realsense.json``, K stored column-major)."""
    import json

    cam = json.loads((root / "cam_params_realsense.json").read_text())
    k = np.array(cam["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T
    return Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], int(cam["width"]), int(cam["height"]))


def realsense_recording(root: Path, path: Path, fmt: str) -> Path:
    """The 10 real RealSense frames as a recording a realsense-ros user would have (colour, aligned depth in
    millimetres read as metres, camera_info) at 30 Hz: "their own bag" for the tests of real data."""
    import cv2

    from slzcli.config import load_config

    intr = realsense_intrinsics(root)
    unit_m = load_config().sources.depth_unit_16u_m
    with RecordingWriter(path, fmt) as w:
        for i, name in enumerate(sorted((root / "color").glob("*.png"))):
            bgr = cv2.imread(str(name), cv2.IMREAD_COLOR)
            raw = cv2.imread(str(root / "depth" / name.name), cv2.IMREAD_UNCHANGED)
            assert bgr is not None and raw is not None
            depth = np.where(raw > 0, raw * unit_m, np.nan).astype(np.float32)
            w.write_frame(Frame(i, T0_NS + i * PERIOD_NS, bgr[:, :, ::-1].copy(), depth, intr))
    return path


def realsense_bag(root: Path, out: Path) -> Path:
    """The real frames as a realsense-ros bag (aligned depth, 16UC1 millimetres: REP 118), depth decoded as
    float32 millimetres / 1000 (the arithmetic a TUM folder with ``depth_scale: 1000`` gets)."""
    import cv2

    k = realsense_intrinsics(root)
    with RecordingWriter(out, "ros1") as w:
        for i, f in enumerate(sorted((root / "color").glob("*.png"))):
            raw = cv2.imread(str(root / "depth" / f.name), cv2.IMREAD_UNCHANGED)
            bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
            assert raw is not None and bgr is not None
            depth = np.where(raw > 0, raw.astype(np.float32) / np.float32(1000), np.nan).astype(np.float32)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            w.write_frame(Frame(i, T0_NS + i * PERIOD_NS, rgb, depth, k))
    return out


def write_cloud(w: RecordingWriter, topic: str, stamp: int, xyz: np.ndarray) -> None:
    """A recorded SLAM map (sensor_msgs/PointCloud2 of x, y, z float32 and a point id) as ORB-SLAM3 ROS wrappers
    publish it, in the world frame."""
    data = np.concatenate([xyz.astype("<f4"), np.arange(len(xyz), dtype="<i4")[:, None].view("<f4")], 1)
    fields = [w.message("sensor_msgs/msg/PointField", name=n, offset=4 * i, datatype=7 if n != "id" else 5,
                        count=1) for i, n in enumerate(("x", "y", "z", "id"))]
    msg = w.message("sensor_msgs/msg/PointCloud2", header=w.header(stamp, "world"), height=1, width=len(xyz),
                    fields=fields, is_bigendian=False, point_step=16, row_step=16 * len(xyz),
                    data=np.frombuffer(data.tobytes(), np.uint8).copy(), is_dense=True)
    w.write_raw(topic, "sensor_msgs/msg/PointCloud2", msg, stamp)
