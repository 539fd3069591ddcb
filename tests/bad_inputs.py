"""A corpus of bad inputs, generated into a folder (nothing binary is committed).

One generator per case: ``CASES[name](folder) -> path``. Each writes a small recording (or
config file) with the project's own ``RecordingWriter`` (``write_raw`` and its message
helpers for the odd cases) and returns the path to hand to ``slz info`` / ``slz detect``.
``tests/top/test_bad_inputs.py`` says what slz must do with each.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from slzcli.outputs.recording import RecordingWriter
from slzcli.types import Frame, Intrinsics

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000  # 10 Hz
W, H = 160, 120  # ORB-SLAM3 throws on images much smaller than this (128x96 fails)
ALTITUDE_M = 6.0


def textured_frame(i: int = 0, w: int = W, h: int = H, depth: np.ndarray | None = None,
                   rgb: np.ndarray | None = None) -> Frame:
    """A camera looking straight down at flat, textured ground ``ALTITUDE_M`` below."""
    intr = Intrinsics(0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2, w, h)
    if rgb is None:
        rgb = np.random.default_rng(7).integers(0, 256, (h, w, 3), dtype=np.uint8)
        rgb = np.roll(rgb, 2 * i, axis=1)  # the camera drifts a little: trackable
    if depth is None:
        depth = np.full((h, w), ALTITUDE_M, dtype=np.float32)
    return Frame(i, T0_NS + i * PERIOD_NS, rgb, depth, intr)


def _write(path: Path, frames: list[Frame], fmt: str = "mcap", **kw) -> Path:
    with RecordingWriter(path, fmt, **kw) as w:
        for f in frames:
            w.write_frame(f)
    return path


def good(folder: Path, n: int = 4) -> Path:
    """A well-formed recording (the reference the cut/corrupted cases start from)."""
    return _write(folder / "good.mcap", [textured_frame(i) for i in range(n)])


# ----------------------------------------------------------------------------- files that are not recordings
def empty(folder: Path) -> Path:
    p = folder / "empty.mcap"
    p.write_bytes(b"")
    return p


def garbage(folder: Path) -> Path:
    p = folder / "garbage.bag"
    p.write_bytes(np.random.default_rng(1).bytes(8192))
    return p


def wrong_magic(folder: Path) -> Path:
    data = bytearray(good(folder).read_bytes())
    data[:8] = b"\x89PNG\r\n\x1a\n"  # a PNG signature where MCAP's magic should be
    p = folder / "wrong_magic.mcap"
    p.write_bytes(bytes(data))
    return p


def _cut(folder: Path, fraction: float, name: str, fmt: str = "mcap", suffix: str = ".mcap") -> Path:
    src = _write(folder / f"full_{name}{suffix}", [textured_frame(i) for i in range(6)], fmt,
                 **({"chunk_bytes": 20_000} if fmt == "mcap" else {}))
    data = src.read_bytes()
    p = folder / f"{name}{suffix}"
    p.write_bytes(data[: int(len(data) * fraction)])
    return p


def cut_header(folder: Path) -> Path:
    return _cut(folder, 0.001, "cut_header")


def cut_middle(folder: Path) -> Path:
    return _cut(folder, 0.5, "cut_middle")


def cut_before_footer(folder: Path) -> Path:
    return _cut(folder, 0.97, "cut_before_footer")


def cut_ros1(folder: Path) -> Path:
    return _cut(folder, 0.6, "cut_ros1", "ros1", ".bag")


# ----------------------------------------------------------------------------- recordings with odd content
def unsupported_depth_encoding(folder: Path) -> Path:
    p = folder / "depth_8uc3.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(3):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            _, msg = w.depth_message(f.depth_m, f.stamp_ns)
            msg.encoding = "64FC1"
            w.write_raw(w.depth_topic, "sensor_msgs/msg/Image", msg, f.stamp_ns)
    return p


def mismatched_sizes(folder: Path) -> Path:
    """Colour 96x72, depth 48x36 (and a CameraInfo of the colour size): depth is resized to colour."""
    p = folder / "mismatched.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(3):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m[::2, ::2], f.stamp_ns), f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


def camera_info_zeros(folder: Path) -> Path:
    p = folder / "info_zeros.mcap"
    zero = Intrinsics(0.0, 0.0, 0.0, 0.0, W, H)
    with RecordingWriter(p, "mcap") as w:
        for i in range(3):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
            for topic in (w.layout.color_info, w.layout.depth_info):
                w.write_raw(topic, "sensor_msgs/msg/CameraInfo", w._camera_info(zero, f.stamp_ns), f.stamp_ns)
    return p


def depth_all_nan(folder: Path) -> Path:
    nan = np.full((H, W), np.nan, dtype=np.float32)
    return _write(folder / "depth_nan.mcap", [textured_frame(i, depth=nan) for i in range(3)], depth_encoding="32FC1")


def depth_constant(folder: Path) -> Path:
    """Every pixel the same depth: a flat floor square to the camera (flat, so it may be safe)."""
    return _write(folder / "depth_constant.mcap", [textured_frame(i) for i in range(4)])


def stamps_backwards(folder: Path) -> Path:
    frames = [textured_frame(i) for i in range(4)][::-1]
    p = folder / "backwards.mcap"
    with RecordingWriter(p, "mcap") as w:
        for k, f in enumerate(frames):  # header stamps go backwards; log time forwards
            log_ns = T0_NS + k * PERIOD_NS
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), log_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), log_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        log_ns)
    return p


def duplicated_messages(folder: Path) -> Path:
    frames = [textured_frame(i) for i in range(3)]
    p = folder / "duplicated.mcap"
    with RecordingWriter(p, "mcap") as w:
        for f in frames:
            w.write_frame(f)
            w.write_frame(f)
    return p


def one_pixel(folder: Path) -> Path:
    return _write(folder / "one_pixel.mcap", [textured_frame(i, w=1, h=1) for i in range(2)])


def very_large(folder: Path) -> Path:
    w, h = 4000, 3000
    rgb = np.zeros((h, w, 3), dtype=np.uint8)
    rgb[::8] = 255  # stripes: cheap to make, something to see
    return _write(folder / "large.mcap", [textured_frame(0, w=w, h=h, rgb=rgb)])


def no_texture(folder: Path) -> Path:
    """A uniform grey image: the odometry finds no features, so there is no pose and no map point."""
    grey = np.full((H, W, 3), 128, dtype=np.uint8)
    return _write(folder / "no_texture.mcap", [textured_frame(i, rgb=grey) for i in range(4)])


# ----------------------------------------------------------------------------- config files
def config_wrong_type(folder: Path) -> Path:
    p = folder / "wrong_type.yaml"
    p.write_text("mask:\n  threshold: high\n")
    return p


def config_unknown_key(folder: Path) -> Path:
    p = folder / "unknown_key.yaml"
    p.write_text("mask:\n  treshold: 0.6\n")
    return p


def config_not_a_mapping(folder: Path) -> Path:
    p = folder / "list.yaml"
    p.write_text("- 1\n- 2\n")
    return p


def config_bad_yaml(folder: Path) -> Path:
    p = folder / "bad.yaml"
    p.write_text("mask: {threshold: [0.5\n")
    return p


def config_latin1(folder: Path) -> Path:
    p = folder / "latin1.yaml"
    p.write_bytes("# caméra\nmask:\n  threshold: 0.6\n".encode("latin-1"))
    return p


def config_utf16_no_bom(folder: Path) -> Path:
    p = folder / "utf16.yaml"
    p.write_bytes("mask:\n  threshold: 0.6\n".encode("utf-16-le"))
    return p


def config_binary(folder: Path) -> Path:
    p = folder / "binary.yaml"
    p.write_bytes(np.random.default_rng(3).bytes(2048))
    return p


def config_deep(folder: Path) -> Path:
    """20000 nested flow lists: the YAML composer recursed until RecursionError."""
    p = folder / "deep.yaml"
    p.write_text("mask: " + "[" * 20000 + "]" * 20000 + "\n")
    return p


def config_contradictory(folder: Path) -> Path:
    p = folder / "contradictory.yaml"
    p.write_text("terrain:\n  flatness:\n    canny_low: 230\n")
    return p


def alias_bomb(levels: int) -> str:
    """A YAML flow list of ``levels`` nested levels, each 9 references to the one below: 9**(levels+1) values."""
    value = "&a0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"
    for i in range(1, levels):
        value = f"&a{i} [{value}, " + ", ".join([f"*a{i - 1}"] * 8) + "]"
    return value


def config_alias_bomb(folder: Path) -> Path:
    """A ~350-byte "billion laughs" under landing.kmeans_k (the tester's: 372 bytes): 387 M values."""
    p = folder / "alias_bomb.yaml"
    p.write_text(f"landing:\n  kmeans_k: {alias_bomb(9)}\n")
    return p


def config_alias_small_bomb(folder: Path) -> Path:
    """A smaller bomb (59,049 values: under the loader's bound) whose error message once was megabytes."""
    p = folder / "alias_small_bomb.yaml"
    p.write_text(f"landing:\n  kmeans_k: {alias_bomb(5)}\n")
    return p


def config_too_deep(folder: Path) -> Path:
    p = folder / "deep.yaml"
    p.write_text("landing:\n  kmeans_k: " + "[" * 5000 + "]" * 5000 + "\n")
    return p


def config_too_large(folder: Path) -> Path:
    """A 2 MB config file (a log or a recording given as --config by mistake)."""
    p = folder / "huge.yaml"
    p.write_text("mask:\n  threshold: 0.5\n" + "# padding\n" * 200_000)
    return p


def config_long_value(folder: Path) -> Path:
    p = folder / "long_value.yaml"
    p.write_text("scoring:\n  method: " + "x" * 200_000 + "\n")
    return p


RECORDINGS: dict[str, Callable[[Path], Path]] = {f.__name__: f for f in (
    empty, garbage, wrong_magic, cut_header, cut_middle, cut_before_footer, cut_ros1,
    unsupported_depth_encoding, mismatched_sizes, camera_info_zeros, depth_all_nan, depth_constant,
    stamps_backwards, duplicated_messages, one_pixel, very_large, no_texture)}
CONFIGS: dict[str, Callable[[Path], Path]] = {f.__name__: f for f in (
    config_wrong_type, config_unknown_key, config_not_a_mapping, config_bad_yaml, config_latin1, config_utf16_no_bom,
    config_binary, config_deep, config_contradictory, config_alias_bomb, config_alias_small_bomb, config_too_deep,
    config_too_large, config_long_value)}


# ----------------------------------------------------------------------------- damaged messages
def corrupt_compressed_colour(folder: Path) -> Path:
    """CompressedImage (jpeg) whose bytes are garbage in every frame."""
    p = folder / "corrupt_jpeg.mcap"
    with RecordingWriter(p, "mcap", color_encoding="jpeg") as w:
        for i in range(3):
            f = textured_frame(i)
            _, msg = w.color_message(f.rgb, f.stamp_ns)
            msg.data = np.frombuffer(np.random.default_rng(i).bytes(500), dtype=np.uint8)
            w.write_raw(w.color_topic, "sensor_msgs/msg/CompressedImage", msg, f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
    return p


def short_image_data(folder: Path) -> Path:
    """Depth Image whose data is shorter than step x height in one of four frames (a torn write)."""
    p = folder / "short_data.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(4):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            _, msg = w.depth_message(f.depth_m, f.stamp_ns)
            if i == 1:
                msg.data = msg.data[: msg.data.size // 2]
            w.write_raw(w.depth_topic, "sensor_msgs/msg/Image", msg, f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


def camera_info_nan(folder: Path) -> Path:
    p = folder / "info_nan.mcap"
    bad = Intrinsics(float("nan"), float("nan"), float("nan"), float("nan"), W, H)
    with RecordingWriter(p, "mcap") as w:
        for i in range(3):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.layout.depth_info, "sensor_msgs/msg/CameraInfo", w._camera_info(bad, f.stamp_ns), f.stamp_ns)
    return p


RECORDINGS.update({f.__name__: f for f in (corrupt_compressed_colour, short_image_data, camera_info_nan)})


# ----------------------------------------------------------------------------- rosbag2 folders
def ros2_cut_db(folder: Path) -> Path:
    """A rosbag2 (sqlite) folder whose .db3 was cut short (copied while recording)."""
    bag = _write(folder / "cut_ros2", [textured_frame(i) for i in range(4)], "ros2-sqlite")
    db = next(bag.glob("*.db3"))
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 3])
    return bag


def ros2_missing_storage(folder: Path) -> Path:
    """metadata.yaml without the storage file it lists."""
    bag = _write(folder / "no_db_ros2", [textured_frame(i) for i in range(2)], "ros2-sqlite")
    next(bag.glob("*.db3")).unlink()
    return bag


RECORDINGS.update({f.__name__: f for f in (ros2_cut_db, ros2_missing_storage)})


# ----------------------------------------------------------------------------- values that must be validated (issue 15)
def _with_info(path: Path, intr: Intrinsics, n: int = 3) -> Path:
    """Colour, depth and a CameraInfo ``intr`` on both info topics."""
    with RecordingWriter(path, "mcap") as w:
        for i in range(n):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
            for topic in (w.layout.color_info, w.layout.depth_info):
                w.write_raw(topic, "sensor_msgs/msg/CameraInfo", w._camera_info(intr, f.stamp_ns), f.stamp_ns)
    return path


def camera_info_principal_outside(folder: Path) -> Path:
    """cx = cy = -1e6: a K that looks calibrated but puts the optical axis far outside the image."""
    return _with_info(folder / "info_cx_outside.mcap", Intrinsics(0.8 * W, 0.8 * W, -1e6, -1e6, W, H))


def camera_info_size_zero(folder: Path) -> Path:
    """A good K with width = height = 0."""
    return _with_info(folder / "info_size_zero.mcap", Intrinsics(0.8 * W, 0.8 * W, (W - 1) / 2, (H - 1) / 2, 0, 0))


def camera_info_fx_huge(folder: Path) -> Path:
    """fx = fy = 1e300: finite and positive, but a field of view of nothing."""
    return _with_info(folder / "info_fx_huge.mcap", Intrinsics(1e300, 1e300, (W - 1) / 2, (H - 1) / 2, W, H))


def camera_info_aspect_mismatch(folder: Path) -> Path:
    """A CameraInfo for 160x160 on 160x120 images: scaling it would stretch one axis."""
    return _with_info(folder / "info_aspect.mcap", Intrinsics(0.8 * W, 0.8 * W, 79.5, 79.5, W, W))


def _stamped(path: Path, stamps: list[int], log_ns: list[int] | None = None, n: int | None = None) -> Path:
    """Frames 0..n-1 (different images) with the given header stamps and log times."""
    log_ns = log_ns if log_ns is not None else stamps
    with RecordingWriter(path, "mcap") as w:
        for i, (stamp, logt) in enumerate(zip(stamps, log_ns, strict=True)):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, stamp), logt)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, stamp), logt)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, stamp), logt)
    return path


def stamps_all_zero(folder: Path) -> Path:
    """Every header stamp 0 (a driver that never set them); log times are distinct."""
    return _stamped(folder / "stamps_zero.mcap", [0] * 10, [T0_NS + i * PERIOD_NS for i in range(10)])


def stamps_all_zero_log_zero(folder: Path) -> Path:
    """Header stamps and log times all 0: nothing to tell the frames apart."""
    return _stamped(folder / "stamps_zero_log_zero.mcap", [0] * 10, [0] * 10)


def stamps_duplicated(folder: Path) -> Path:
    """Ten different frames, every one stamped with the same time (a stuck clock)."""
    return _stamped(folder / "stamps_duplicated.mcap", [T0_NS] * 10, [T0_NS + i * PERIOD_NS for i in range(10)])


def log_time_near_2_64(folder: Path) -> Path:
    """MCAP log times (and header stamps 0) near 2^64 ns: beyond what an int64 stamp can hold."""
    big = 2**64 - 1000
    return _stamped(folder / "log_time_huge.mcap", [0] * 4, [big + i for i in range(4)])


def two_depth_topics(folder: Path) -> Path:
    """A 16UC1 depth topic and an rgb8 colourised one whose name sorts first (RealSense `colorizer`)."""
    p = folder / "two_depth.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(4):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw("/camera/depth/colorized", "sensor_msgs/msg/Image", w._image(f.stamp_ns, f.rgb, "rgb8"),
                        f.stamp_ns)
            w.write_raw("/camera/depth/image_rect_raw", *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


# ----------------------------------------------------------------------------- frames over sources.max_image_px
def png_header(width: int, height: int) -> bytes:
    """A PNG that declares width x height (a valid IHDR, CRC and all) and holds almost no pixel data.

    cv2.imdecode allocates the declared size before it finds the data missing: the tester's
    12000x9000 frame (1.2 MB on disk) cost 3.4 GB this way.
    """
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)   # 8-bit RGB
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
            + chunk(b"IEND", b""))


def jpeg_header(width: int, height: int) -> bytes:
    """A JPEG whose frame header (SOF0) declares width x height, followed by no scan at all."""
    import struct

    sof = struct.pack(">BHHB", 8, height, width, 3) + b"".join(bytes([c, 0x11, 0]) for c in (1, 2, 3))
    return b"\xff\xd8" + b"\xff\xc0" + struct.pack(">H", len(sof) + 2) + sof + b"\xff\xd9"


def _with_colour_payload(folder: Path, name: str, encoding: str, payload: bytes, frames: int,
                         oversized: Callable[[int], bool]) -> Path:
    p = folder / name
    with RecordingWriter(p, "mcap", color_encoding=encoding) as w:
        for i in range(frames):
            f = textured_frame(i)
            _, msg = w.color_message(f.rgb, f.stamp_ns)
            if oversized(i):
                msg.data = np.frombuffer(payload, dtype=np.uint8)
            w.write_raw(w.color_topic, "sensor_msgs/msg/CompressedImage", msg, f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


def pose_nan(folder: Path) -> Path:
    """A recorded PoseStamped whose position is NaN in one of four frames."""
    p = folder / "pose_nan.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(4):
            f = textured_frame(i)
            w.write_frame(f)
            T = np.eye(4)
            T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down
            T[:3, 3] = (-2 * ALTITUDE_M / (0.8 * W) * i, 0.0, ALTITUDE_M)  # the motion the images show (2 px a frame)
            if i == 1:
                T[0, 3] = np.nan
            w.write_pose("/camera/pose", f.stamp_ns, T)
    return p


def symlink_loop(folder: Path) -> Path:
    p = folder / "loop.mcap"
    p.symlink_to(p.name)
    return p


def _tum(folder: Path, name: str, camera_yaml: str | None = None, n: int = 3, missing: int = 0) -> Path:
    import cv2

    root = folder / name
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines = [], []
    for i in range(n):
        f = textured_frame(i)
        t = f"{1305031102 + i * 0.1:.6f}"
        rgb_lines.append(f"{t} rgb/{i}.png")
        depth_lines.append(f"{t} depth/{i}.png")
        if i >= n - missing:
            continue  # listed, never written
        cv2.imwrite(str(root / "rgb" / f"{i}.png"), f.rgb[:, :, ::-1])
        cv2.imwrite(str(root / "depth" / f"{i}.png"), np.uint16(f.depth_m * 5000))
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if camera_yaml is not None:
        (root / "camera.yaml").write_text(camera_yaml)
    return root


def _camera_yaml(**over: object) -> str:
    values = {"fx": 0.8 * W, "fy": 0.8 * W, "cx": (W - 1) / 2, "cy": (H - 1) / 2, "width": W, "height": H, **over}
    return "".join(f"{k}: {v}\n" for k, v in values.items())


def tum_camera_width_zero(folder: Path) -> Path:
    return _tum(folder, "tum_width_zero", _camera_yaml(width=0))


def tum_camera_fx_negative(folder: Path) -> Path:
    return _tum(folder, "tum_fx_negative", _camera_yaml(fx=-128.0))


def tum_camera_fx_nan(folder: Path) -> Path:
    return _tum(folder, "tum_fx_nan", _camera_yaml(fx=".nan"))


def tum_camera_fx_huge(folder: Path) -> Path:
    return _tum(folder, "tum_fx_huge", _camera_yaml(fx=1e300, fy=1e300))


def tum_missing_images(folder: Path) -> Path:
    """30 frames listed, the images of 25 of them missing: one warning line with the count, not 25."""
    return _tum(folder, "tum_missing", _camera_yaml(), n=30, missing=25)   # its calibration: no intrinsics warning


RECORDINGS.update({f.__name__: f for f in (
    camera_info_principal_outside, camera_info_size_zero, camera_info_fx_huge, camera_info_aspect_mismatch,
    stamps_all_zero, stamps_all_zero_log_zero, stamps_duplicated, log_time_near_2_64, two_depth_topics, pose_nan,
    symlink_loop, tum_camera_width_zero, tum_camera_fx_negative, tum_camera_fx_nan, tum_camera_fx_huge,
    tum_missing_images)})


# ----------------------------------------------------------------------------- landing.json targets (slz land simulate)
FOOTPRINT_M = (0.656, 0.656)  # uav.footprint_m of the default config


def _landing(folder: Path, name: str, corners: list[list[float]] | None = None, center: list[float] | None = None,
             text: str | None = None) -> Path:
    import json

    run = folder / name
    run.mkdir(parents=True)
    c = center if center is not None else [1.0, -0.5, 0.1]
    if corners is None:
        corners = [[c[0] + sx * FOOTPRINT_M[0], c[1] + sy * FOOTPRINT_M[1], c[2]]
                   for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
    doc = {"status": "site", "method": "fuzzy", "source": "flight.mcap", "frame": {"index": 3, "stamp_ns": 1},
           "site": {"pixel": [320, 240], "center_camera": [0, 0, 5], "center_world": c, "corners_world": corners,
                    "normal_world": [0, 0, 1], "cluster": {}, "score": 0.9},
           "world_frame": "test", "timings_ms": {}}
    (run / "landing.json").write_text(text if text is not None else json.dumps(doc))
    return run


def landing_good(folder: Path) -> Path:
    return _landing(folder, "landing_good")


def landing_collinear(folder: Path) -> Path:
    return _landing(folder, "landing_collinear", [[1.0 + d, -0.5, 0.1] for d in (-0.9, -0.3, 0.3, 0.9)])


def landing_tiny(folder: Path) -> Path:
    c = [1.0, -0.5, 0.1]
    return _landing(folder, "landing_tiny", [[c[0] + sx * 1e-9, c[1] + sy * 1e-9, c[2]]
                                             for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1))])


def landing_identical(folder: Path) -> Path:
    return _landing(folder, "landing_identical", [[1.0, -0.5, 0.1]] * 4)


def landing_deep(folder: Path) -> Path:
    return _landing(folder, "landing_deep", text='{"status": "site", "site": ' + "[" * 100000 + "]" * 100000 + "}")


LANDINGS: dict[str, Callable[[Path], Path]] = {f.__name__: f for f in (
    landing_collinear, landing_tiny, landing_identical, landing_deep)}


# ----------------------------------------------------------------------------- output folders slz must not write into
# Each returns (recording, -o): `slz detect` must refuse the -o with one line and change nothing.
def out_users_folder(folder: Path) -> tuple[Path, Path]:
    out = folder / "thesis"
    out.mkdir()
    (out / "thesis.tex").write_text("\\chapter{Landing}\n")
    return good(folder, n=2), out


def out_holds_the_recording(folder: Path) -> tuple[Path, Path]:
    return good(folder, n=2), folder


def out_is_the_input_bag(folder: Path) -> tuple[Path, Path]:
    bag = _write(folder / "bag_ros2", [textured_frame(i) for i in range(2)], "ros2-mcap")
    return bag, bag


def out_is_a_compare_folder(folder: Path) -> tuple[Path, Path]:
    out = folder / "cmp"
    out.mkdir()
    (out / "compare.json").write_text('{"slz_output": {"kind": "compare", "state": "finished", "files": '
                                      '["compare.json"]}}\n')
    return good(folder, n=2), out


OUTPUTS: dict[str, Callable[[Path], tuple[Path, Path]]] = {f.__name__: f for f in (
    out_users_folder, out_holds_the_recording, out_is_the_input_bag, out_is_a_compare_folder)}


def huge_png_frame(folder: Path) -> Path:
    """Four PNG colour frames; the second declares 12000x9000 px (108 MP): that frame is skipped."""
    return _with_colour_payload(folder, "huge_png.mcap", "png", png_header(12000, 9000), 4, lambda i: i == 1)


def huge_jpeg_frames(folder: Path) -> Path:
    """Every JPEG colour frame declares 30000x30000 px: no frame is left, the run fails naming the bound."""
    return _with_colour_payload(folder, "huge_jpeg.mcap", "jpeg", jpeg_header(30000, 30000), 3, lambda i: True)


def over_opencv_limit_frame(folder: Path) -> Path:
    """One PNG declares 40000x30000 px, over OpenCV's own 2^30-pixel limit (cv2.imdecode throws, not None)."""
    return _with_colour_payload(folder, "over_opencv.mcap", "png", png_header(40000, 30000), 4, lambda i: i == 2)


def huge_raw_depth_frame(folder: Path) -> Path:
    """A raw depth Image declaring 30000x30000 (step and data too short): skipped before any copy."""
    p = folder / "huge_raw_depth.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(4):
            f = textured_frame(i)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            _, msg = w.depth_message(f.depth_m, f.stamp_ns)
            if i == 3:
                msg.width, msg.height = 30000, 30000
            w.write_raw(w.depth_topic, "sensor_msgs/msg/Image", msg, f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


RECORDINGS.update({f.__name__: f for f in (huge_png_frame, huge_jpeg_frames, over_opencv_limit_frame,
                                           huge_raw_depth_frame)})


# ----------------------------------------------------------------------------- depth in another unit than it says
def _depth_as(folder: Path, name: str, encoding: str, mutate: Callable[[object], None],
              depth: np.ndarray | None = None) -> Path:
    """Colour, CameraInfo and a depth Image written in ``encoding`` and then changed by ``mutate``."""
    p = folder / name
    with RecordingWriter(p, "mcap", depth_encoding=encoding) as w:
        for i in range(3):
            f = textured_frame(i, depth=depth)
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            kind, msg = w.depth_message(f.depth_m, f.stamp_ns)
            mutate(msg)
            w.write_raw(w.depth_topic, kind, msg, f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return p


def depth_metres_in_16uc1(folder: Path) -> Path:
    """16UC1 depth holding metres (6), not millimetres (6000): read as 6 mm."""
    def to_metres(msg) -> None:
        msg.data = (np.frombuffer(msg.data, np.uint16) // 1000).astype(np.uint16).view(np.uint8)
    return _depth_as(folder, "depth_metres_16uc1.mcap", "16UC1", to_metres)


def depth_bigendian_flag(folder: Path) -> Path:
    """32FC1 little-endian depth flagged is_bigendian: read byte-swapped (6.0 m -> ~7e-41 m)."""
    def flag(msg) -> None:
        msg.is_bigendian = 1
    return _depth_as(folder, "depth_bigendian.mcap", "32FC1", flag)


def depth_1e27(folder: Path) -> Path:
    """32FC1 depth of 1e-27 m everywhere."""
    return _depth_as(folder, "depth_1e27.mcap", "32FC1", lambda msg: None,
                     depth=np.full((H, W), 1e-27, np.float32))


# ----------------------------------------------------------------------------- sizes read from files
def fifo_recording(folder: Path) -> Path:
    """A FIFO named like a recording: opening it would wait for a writer for ever."""
    import os

    p = folder / "fifo.mcap"
    os.mkfifo(p)
    return p


def tum_sparse_rgb_txt(folder: Path) -> Path:
    """A TUM folder whose rgb.txt is a sparse 3 GB file (costs no disk; read whole it costs 3 GB)."""
    root = _tum(folder, "tum_sparse")
    with open(root / "rgb.txt", "r+b") as fh:
        fh.truncate(3 << 30)
    return root


def ros2_sparse_metadata(folder: Path) -> Path:
    """A rosbag2 folder whose metadata.yaml is a sparse 3 GB file."""
    bag = _write(folder / "sparse_meta", [textured_frame(i) for i in range(3)], "ros2-sqlite")
    with open(bag / "metadata.yaml", "r+b") as fh:
        fh.truncate(3 << 30)
    return bag


def mcap_huge_chunk(folder: Path) -> Path:
    """The first chunk of an MCAP declares 2^62 bytes uncompressed (zstd would allocate them)."""
    import struct

    data = bytearray(good(folder, 6).read_bytes())
    pos = 8  # after the magic: opcode (1 B), length (8 B), body
    while data[pos] != 0x06:  # the first Chunk record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    struct.pack_into("<Q", data, pos + 9 + 16, 2**62)  # after message_start_time, message_end_time
    p = folder / "huge_chunk.mcap"
    p.write_bytes(bytes(data))
    return p


def depth_3e38(folder: Path) -> Path:
    """32FC1 depth of 3e38 m (near float32's limit): the plan raster's indices overflowed."""
    return _depth_as(folder, "depth_3e38.mcap", "32FC1", lambda msg: None, depth=np.full((H, W), 3e38, np.float32))


RECORDINGS.update({f.__name__: f for f in (depth_3e38, depth_metres_in_16uc1, depth_bigendian_flag, depth_1e27,
                                           fifo_recording,
                                           tum_sparse_rgb_txt, ros2_sparse_metadata, mcap_huge_chunk)})
