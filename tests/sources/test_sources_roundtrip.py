"""Write recordings with RecordingWriter in every format x encoding and read them back exactly."""

from __future__ import annotations

import json
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import pytest
from sources_util import PERIOD_NS, SUFFIX, T0_NS, known_frame, pose, write_frames

from slzcli.config import load_config
from slzcli.outputs.recording import COMPRESSED_DEPTH_MAX_M, COMPRESSED_DEPTH_QUANTIZATION, RecordingWriter, TopicLayout
from slzcli.sources import open_recording
from slzcli.sources.messages import MessageRecording, RawMessage
from slzcli.types import Frame, Intrinsics

FORMATS = list(SUFFIX)
CFG = load_config()
PoseKind = Literal["PoseStamped", "Odometry", "tf"]


def read_all(path: Path, overrides: tuple[str, ...] = ()):
    cfg = load_config(None, overrides) if overrides else CFG
    with open_recording(path, cfg) as rec:
        frames = list(rec.frames())
        return frames, rec.report, rec.info()


def expected_rgb(rgb: np.ndarray, enc: str) -> np.ndarray:
    if enc == "mono8":
        return cv2.cvtColor(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
    return rgb


def assert_depth_equal(got: np.ndarray, want: np.ndarray) -> None:
    assert got.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=1e-6)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("color_encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "png", "jpeg"])
def test_color_encodings_round_trip(tmp_path: Path, fmt: str, color_encoding: str) -> None:
    path = tmp_path / f"rec{SUFFIX[fmt]}"
    written = write_frames(path, fmt, color_encoding=color_encoding)
    frames, report, _ = read_all(path)
    assert len(frames) == len(written) and report.paired == len(written)
    for got, want in zip(frames, written, strict=True):
        assert got.rgb.dtype == np.uint8 and got.rgb.shape == want.rgb.shape
        exp = expected_rgb(want.rgb, color_encoding)
        if color_encoding == "jpeg":  # lossy: close on a smooth image, channel order still right
            assert np.abs(got.rgb.astype(int) - exp.astype(int)).mean() < 6
        else:
            np.testing.assert_array_equal(got.rgb, exp)
        assert got.stamp_ns == want.stamp_ns
        assert_depth_equal(got.depth_m, want.depth_m)
        assert got.intrinsics.fx == want.intrinsics.fx and got.intrinsics.cy == want.intrinsics.cy


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("depth_encoding,big_endian", [
    ("16UC1", False), ("16UC1", True), ("mono16", False), ("mono16", True), ("32FC1", False), ("32FC1", True),
    ("compressedDepth", False)])  # compressedDepth is a PNG: it has no byte order
def test_depth_encodings_round_trip(tmp_path: Path, fmt: str, depth_encoding: str, big_endian: bool) -> None:
    path = tmp_path / f"rec{SUFFIX[fmt]}"
    written = write_frames(path, fmt, depth_encoding=depth_encoding, big_endian=big_endian)
    frames, report, _ = read_all(path)
    assert report.paired == len(written)
    for got, want in zip(frames, written, strict=True):
        assert_depth_equal(got.depth_m, want.depth_m)  # 16UC1: mm -> m and 0 -> NaN; 32FC1 exact
        np.testing.assert_array_equal(got.rgb, want.rgb)


def test_16uc1_zero_is_nan_and_counts_are_millimetres(tmp_path: Path) -> None:
    f = known_frame(0)
    depth = np.full(f.depth_m.shape, 1.234, np.float32)
    depth[3, 4] = np.nan
    with RecordingWriter(tmp_path / "r.mcap", "mcap") as w:
        w.write_frame(Frame(0, T0_NS, f.rgb, depth, f.intrinsics))
    frames, _, _ = read_all(tmp_path / "r.mcap")
    assert np.isnan(frames[0].depth_m[3, 4])
    assert frames[0].depth_m[0, 0] == np.float32(1234 * 0.001)


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_compressed_depth_32fc1_inverse_quantisation(tmp_path: Path, fmt: str) -> None:
    path = tmp_path / f"rec{SUFFIX[fmt]}"
    written = write_frames(path, fmt, n=2, depth_encoding="compressedDepth-32FC1")
    frames, _, _ = read_all(path)
    quant_a = COMPRESSED_DEPTH_QUANTIZATION * (COMPRESSED_DEPTH_QUANTIZATION + 1)
    for got, want in zip(frames, written, strict=True):
        ok = ~np.isnan(want.depth_m) & (want.depth_m < COMPRESSED_DEPTH_MAX_M)
        np.testing.assert_array_equal(np.isnan(got.depth_m[ok]), False)
        # One code step is d^2 / A metres: the error stays within a step (plus float rounding).
        step = want.depth_m[ok] ** 2 / quant_a
        assert np.all(np.abs(got.depth_m[ok] - want.depth_m[ok]) <= step * 1.01 + 1e-5)
        assert np.all(np.isnan(got.depth_m[np.isnan(want.depth_m)]))


@pytest.mark.parametrize("fmt", ["ros1", "ros2-sqlite"])
def test_realsense_frames_round_trip(tmp_path: Path, realsense_dir: Path, fmt: str) -> None:
    params = json.loads((realsense_dir / "cam_params_realsense.json").read_text())
    K = np.array(params["intrinsic_matrix"], dtype=float).reshape(3, 3, order="F")  # column-major
    intr = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], params["width"], params["height"])
    assert intr.fx == pytest.approx(617.25) and intr.cy == pytest.approx(245.98, abs=0.01)
    names = sorted(p.name for p in (realsense_dir / "color").glob("*.png"))[:4]
    written = []
    path = tmp_path / f"rs{SUFFIX[fmt]}"
    with RecordingWriter(path, fmt, depth_encoding="16UC1") as w:
        for i, name in enumerate(names):
            bgr = cv2.imread(str(realsense_dir / "color" / name), cv2.IMREAD_COLOR)
            raw = cv2.imread(str(realsense_dir / "depth" / name), cv2.IMREAD_UNCHANGED)
            assert bgr is not None and raw is not None and raw.dtype == np.uint16
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            depth = raw.astype(np.float32) * np.float32(0.001)
            depth[raw == 0] = np.nan
            f = Frame(i, T0_NS + i * PERIOD_NS, rgb, depth, intr)
            w.write_frame(f)
            written.append((f, raw))
    frames, report, info = read_all(path)
    assert report.paired == len(names) and info.intrinsics == frames[0].intrinsics
    for got, (want, raw) in zip(frames, written, strict=True):
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(np.isnan(got.depth_m), raw == 0)
        assert np.isnan(got.depth_m).any()  # real holes survive
        assert_depth_equal(got.depth_m, want.depth_m)
        assert (got.intrinsics.fx, got.intrinsics.fy, got.intrinsics.cx, got.intrinsics.cy) == \
            (intr.fx, intr.fy, intr.cx, intr.cy)
        assert (got.intrinsics.width, got.intrinsics.height) == (640, 480)


def _write_with_poses(path: Path, fmt: str, kind: PoseKind, n: int = 5, static_link: np.ndarray | None = None,
                      child: str = "camera_color_optical_frame") -> list[Frame]:
    frames = [known_frame(i) for i in range(n)]
    with RecordingWriter(path, fmt) as w:
        if static_link is not None:
            w.write_pose("/tf_static", T0_NS, static_link, kind="tf", parent="base_link",
                         child="camera_color_optical_frame")
        for i, f in enumerate(frames):
            topic = {"PoseStamped": "/slam/pose", "Odometry": "/odom", "tf": "/tf"}[kind]
            w.write_pose(topic, f.stamp_ns, pose(i), kind=kind, parent="world", child=child)
            w.write_frame(f)
    return frames


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2-mcap"])
@pytest.mark.parametrize("kind", ["PoseStamped", "Odometry", "tf"])
def test_poses_read_back(tmp_path: Path, fmt: str, kind: PoseKind) -> None:
    path = tmp_path / f"p{SUFFIX[fmt]}"
    _write_with_poses(path, fmt, kind)
    frames, report, info = read_all(path)
    assert report.without_pose == 0 and len(frames) == 5
    for i, f in enumerate(frames):
        np.testing.assert_allclose(f.T_world_camera, pose(i), atol=1e-9)
    assert {c.role: c.topic for c in info.choices}["pose"] in ("/slam/pose", "/odom", "/tf")


@pytest.mark.parametrize("kind", ["tf", "Odometry"])
def test_body_pose_plus_static_body_to_camera_link(tmp_path: Path, kind: PoseKind) -> None:
    link = np.eye(4)
    link[:3, 3] = (0.1, 0.0, -0.05)
    link[:3, :3] = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]])  # body FLU-ish -> optical, downward camera
    path = tmp_path / "p.mcap"
    _write_with_poses(path, "mcap", kind, static_link=link, child="base_link")
    frames, report, _ = read_all(path)
    assert report.without_pose == 0
    for i, f in enumerate(frames):
        np.testing.assert_allclose(f.T_world_camera, pose(i) @ link, atol=1e-9)


def test_pose_between_samples_is_interpolated_and_far_pose_is_none(tmp_path: Path) -> None:
    f = known_frame(0)
    path = tmp_path / "p.mcap"
    A, B = pose(0), pose(1)
    with RecordingWriter(path, "mcap") as w:
        w.write_pose("/pose", f.stamp_ns - 10_000_000, A)
        w.write_pose("/pose", f.stamp_ns + 10_000_000, B)
        w.write_frame(f)
        late = known_frame(1)
        w.write_frame(Frame(1, f.stamp_ns + 2_000_000_000, late.rgb, late.depth_m, late.intrinsics))
    frames, report, _ = read_all(path)
    np.testing.assert_allclose(frames[0].T_world_camera[:3, 3], (A[:3, 3] + B[:3, 3]) / 2, atol=1e-9)
    assert frames[1].T_world_camera is None and report.without_pose == 1


def test_ground_truth_pose_is_skipped_unless_allowed(tmp_path: Path) -> None:
    path = tmp_path / "gt.mcap"
    frames = [known_frame(i) for i in range(3)]
    with RecordingWriter(path, "mcap") as w:
        for i, f in enumerate(frames):
            w.write_pose("/ground_truth/pose", f.stamp_ns, pose(i))
            w.write_frame(f)
    got, _, info = read_all(path)
    choice = {c.role: c for c in info.choices}["pose"]
    assert choice.topic is None and "ground truth" in choice.reason
    assert all(f.T_world_camera is None for f in got)
    got, _, _ = read_all(path, ("sources.use_ground_truth_pose=true",))
    np.testing.assert_allclose(got[2].T_world_camera, pose(2))


def test_topic_choice_prefers_aligned_depth_and_honours_overrides(tmp_path: Path) -> None:
    path = tmp_path / "two_depths.mcap"
    f = known_frame(0)
    other = np.full(f.depth_m.shape, 7.0, np.float32)
    with RecordingWriter(path, "mcap") as w:
        w.write_frame(f)
        raw_layout = RecordingWriter(tmp_path / "unused.mcap", "mcap", layout=TopicLayout(
            depth="/camera/depth/image_rect_raw", depth_info="/camera/depth/camera_info"))
        w.write_raw("/camera/depth/image_rect_raw", *raw_layout.depth_message(other, f.stamp_ns), f.stamp_ns)
    got, _, info = read_all(path)
    choices = {c.role: c for c in info.choices}
    assert choices["depth"].topic == "/camera/aligned_depth_to_color/image_raw"
    assert "aligned" in choices["depth"].reason
    assert_depth_equal(got[0].depth_m, f.depth_m)
    got, _, info = read_all(path, ("sources.topics.depth=/camera/depth/image_rect_raw",))
    assert {c.role: c for c in info.choices}["depth"].reason == "set by sources.topics.depth"
    assert np.all(got[0].depth_m == 7.0)


def test_unaligned_depth_of_another_size_is_resized_and_noted(tmp_path: Path) -> None:
    path = tmp_path / "sizes.mcap"
    small = known_frame(0, h=12, w=16)
    big = known_frame(0)
    layout = TopicLayout(depth="/camera/depth/image_rect_raw", depth_info="/camera/depth/camera_info")
    with RecordingWriter(path, "mcap", layout=layout) as w:
        w.write_raw(layout.color, *w.color_message(big.rgb, T0_NS), T0_NS)
        w.write_raw(layout.depth, *w.depth_message(small.depth_m, T0_NS + 1), T0_NS + 1)
        w.write_raw(layout.depth, *w.depth_message(small.depth_m, T0_NS + 5_000_000), T0_NS + 5_000_000)
    got, report, info = read_all(path)
    # Two depth messages: the colour takes the nearer one, the other is counted, not dropped silently.
    assert report.paired == 1 and report.unpaired_depth == 1
    assert got[0].depth_m.shape == (24, 32)
    assert_depth_equal(got[0].depth_m, np.repeat(np.repeat(small.depth_m, 2, axis=0), 2, axis=1))
    assert any("resized nearest-neighbour" in n for n in report.notes)
    assert any("config camera" in n for n in report.notes)  # no CameraInfo written
    assert "not aligned" in {c.role: c for c in info.choices}["depth"].reason


def test_shuffled_log_order_still_pairs(tmp_path: Path) -> None:
    path = tmp_path / "shuffled.bag"
    frames = [known_frame(i) for i in range(6)]
    with RecordingWriter(path, "ros1") as w:
        for f in reversed(frames):  # bag is indexed by log time = stamp, so write order does not matter
            w.write_frame(f)
    got, report, _ = read_all(path)
    assert [g.stamp_ns for g in got] == [f.stamp_ns for f in frames] and report.paired == 6


def test_writer_is_atomic(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with pytest.raises(RuntimeError), RecordingWriter(path, "mcap") as w:
        w.write_frame(known_frame(0))
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    write_frames(path, "mcap", n=1)
    write_frames(path, "mcap", n=2)  # replaces the older recording
    assert read_all(path)[1].paired == 2
    bag = tmp_path / "bag2"
    write_frames(bag, "ros2-sqlite", n=1)
    assert sorted(p.name for p in bag.iterdir()) == ["bag2.db3", "metadata.yaml"]
    write_frames(bag, "ros2-sqlite", n=2)
    assert read_all(bag)[1].paired == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "bag2"]


def test_cut_short_mcap_yields_frames_before_the_cut(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "full.mcap"
    write_frames(path, "mcap", n=30, chunk_bytes=6000)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with caplog.at_level("WARNING"):
        got, _, info = read_all(cut)
    assert 3 < len(got) < 30
    assert [g.index for g in got] == list(range(len(got)))
    assert any("recovered" in r.getMessage() and f"{len(got)} frames" in r.getMessage() for r in caplog.records)
    assert info.warnings and "recovered" in info.warnings[0]
    full = read_all(path)[0]
    for g, f in zip(got, full, strict=False):  # got is a prefix of full
        np.testing.assert_array_equal(g.rgb, f.rgb)


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2-sqlite"])
def test_frames_stream_without_reading_everything_first(tmp_path: Path, fmt: str) -> None:
    """The first frame comes out after about one reorder window of messages, not after the whole file."""
    path = tmp_path / f"long{SUFFIX[fmt]}"
    n = 60  # 2 s at 30 Hz; the window is 0.5 s
    with RecordingWriter(path, fmt) as w:
        for i in range(n):
            f = known_frame(i % 3)
            w.write_frame(Frame(i, T0_NS + i * PERIOD_NS, f.rgb, f.depth_m, f.intrinsics))
            w.write_pose("/pose", T0_NS + i * PERIOD_NS, pose(i))
    with open_recording(path, CFG) as rec:
        assert isinstance(rec, MessageRecording)
        consumed: list[str] = []
        inner = rec.log.messages

        def counting(topics: Collection[str]) -> Iterator[RawMessage]:
            for m in inner(topics):
                consumed.append(m.topic)
                yield m

        rec.log.messages = counting  # type: ignore[method-assign]
        it = rec.frames()
        first = next(it)
        at_first = len(consumed)
        rest = list(it)
    assert first.index == 0 and len(rest) == n - 1
    assert at_first < len(consumed) / 2, (at_first, len(consumed))
    assert rest[-1].T_world_camera is not None
    np.testing.assert_allclose(rest[-1].T_world_camera, pose(n - 1), atol=1e-9)
