"""The cheaper detection-frame writer (issue 18 target 3) writes what it wrote before, read back.

- The fast paths give the same values as the plain numpy they replaced: float16 casts bit for bit,
  mono8 bytes, the overlay's pixels, the .npy members of maps.npz byte for byte.
- A run read back (through the CLI): overlay.png is the overlay exactly; results.mcap's maps and score
  are round(255 * value) of the detection's own arrays exactly, its colour and overlay JPEGs decode
  close to the frame and to overlay.png, its chunks are LZ4.
- The recording writer's chunk compression, and slz reading an LZ4 MCAP recording.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import bad_inputs as B
import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, synth_recording

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.errors import OutputError
from slzcli.outputs import files, images, palette, results_mcap, run_folder
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.recording import RecordingWriter
from slzcli.sources import open_recording

EVERY = ("--set", "slam.backend=odometry", "--set", "landing.detect_on=every_nth",
         "--set", "landing.every_nth_frame=1")
MAPS = ("depth_variance", "flatness", "inclination", "steepness")
# JPEG at q95 (4:2:0) of rendered 640x480 frames (gaussian sensor), measured on synth seeds 0-2 x 4 frames:
# mean |decoded - original| per channel 4.33-4.36 grey levels for clear_field's colour (its grass is fine-grained),
# 3.00-3.02 for an overlay of it, 2.25-2.31 / 1.78-1.81 for parking_lot. Bound 8: 1.8x the largest; the same
# frame with red and blue swapped is 19.5 off, shifted by 8 px 24 (parking_lot: 7.5 and 19.3).
JPEG_MEAN_ABS_MAX = 8.0


# ----------------------------------------------------------------------------- the fast paths
def float_edge_cases() -> np.ndarray:
    """Every float16 value and every midpoint between neighbours (the round-half-even cases) as float32,
    their negatives, NaN, infinities, -0, values past float16's range, subnormals, and random bit patterns."""
    f16 = np.arange(2**16, dtype=np.uint32).astype(np.uint16).view(np.float16)
    finite = np.sort(f16[np.isfinite(f16)].astype(np.float32))
    mid = (finite[:-1].astype(np.float64) + finite[1:]) / 2
    rng = np.random.default_rng(3)
    bits = rng.integers(0, 2**32, 2**20, dtype=np.uint64).astype(np.uint32).view(np.float32)
    special = np.array([np.nan, np.inf, -np.inf, -0.0, 65504, 65519.99, 65520, 1e30, 1e-30, 6e-8, 3e-8],
                       np.float32)
    # the special values first: the tests cut the tail to make a 640-wide map
    return np.concatenate([special, finite, mid.astype(np.float32),
                           np.nextafter(mid.astype(np.float32), np.float32(np.inf)), -mid.astype(np.float32), bits])


def test_float16_through_opencv_is_numpys_cast_bit_for_bit() -> None:
    values = float_edge_cases()
    values = values[: len(values) // 640 * 640].reshape(-1, 640)  # a 2-D map, as the maps are
    with np.errstate(over="ignore", invalid="ignore"):
        want = values.astype(np.float16)
    got = run_folder.to_float16(values)
    assert got.dtype == np.float16 and got.shape == values.shape
    nan = np.isnan(values)
    assert np.array_equal(got.view(np.uint16)[~nan], want.view(np.uint16)[~nan])
    assert np.isnan(got[nan]).all()  # NaN stays NaN (F16C quiets a signalling NaN's payload; numpy keeps it)
    # views, Fortran order, a row, a column, nothing: the same as numpy's
    wide16 = values[:480, :640]
    for view in (wide16[:, ::2], np.asfortranarray(wide16), wide16[::3, 5:300], wide16[:1], wide16[:, :1],
                 np.zeros((0, 5), np.float32)):
        ok = ~np.isnan(view)
        with np.errstate(over="ignore", invalid="ignore"):
            assert np.array_equal(run_folder.to_float16(view)[ok], view.astype(np.float16)[ok]), view.shape
    # other dtypes and shapes take numpy's own cast
    wide = values[:3][~np.isnan(values[:3])].astype(np.float64)
    with np.errstate(over="ignore"):
        assert np.array_equal(run_folder.to_float16(wide).view(np.uint16), wide.astype(np.float16).view(np.uint16))


def test_mono8_is_round_255_of_the_clipped_value_with_nan_as_zero() -> None:
    values = float_edge_cases()
    with np.errstate(invalid="ignore", over="ignore"):
        want = np.rint(np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
    assert np.array_equal(results_mcap.mono8(values), want)
    ramp = np.arange(256, dtype=np.float32) / 255  # every byte comes back from its own value
    assert np.array_equal(results_mcap.mono8(ramp), np.arange(256))
    assert np.array_equal(results_mcap.mono8(ramp.astype(np.float64)), np.arange(256))


@pytest.mark.parametrize("reverse", [False, True])
def test_heat_maps_have_the_colours_of_the_plain_numpy_drawing(reverse) -> None:
    values = float_edge_cases()
    values = values[: len(values) // 640 * 640].reshape(-1, 640)
    with np.errstate(invalid="ignore", over="ignore"):
        v = np.nan_to_num(values, nan=0.0)
        byte = (np.clip(1.0 - v if reverse else v, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    want = cv2.applyColorMap(byte, palette.CV2_COLORMAP)
    want[~np.isfinite(values)] = 0
    assert np.array_equal(images.heatmap_bgr(values, reverse=reverse), want)
    valid = np.random.default_rng(0).random(values.shape) > 0.1
    want[~valid] = 0
    want[valid & ~np.isfinite(values)] = cv2.applyColorMap(byte, palette.CV2_COLORMAP)[valid & ~np.isfinite(values)]
    assert np.array_equal(images.heatmap_bgr(values, reverse=reverse, valid=valid), want)


def reference_site_overlay(rgb: np.ndarray, mask: np.ndarray, projected: np.ndarray, kept: np.ndarray,
                           chosen: np.ndarray) -> np.ndarray:
    """The overlay as the plain numpy it replaced draws it (broadcast tint, boolean-indexed dots)."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    img = cv2.addWeighted(bgr, 0.55, np.where(mask[..., None], images.SAFE_BGR, images.UNSAFE_BGR), 0.45, 0.0)
    h, w = mask.shape
    for sel, colour, radius in ((np.ones(len(projected), bool), palette.bgr(palette.POINT), 1),
                                (kept, palette.bgr(palette.KEPT), 2), (chosen, palette.bgr(palette.CHOSEN), 3)):
        dots = np.zeros((h, w), np.uint8)
        pts = np.round(projected[sel]).astype(np.int64)
        dots[pts[:, 1], pts[:, 0]] = 1
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        img[cv2.dilate(dots, disc).astype(bool)] = colour
    return img


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_overlay_has_the_pixels_of_the_plain_numpy_drawing(seed) -> None:
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    mask = rng.random((h, w)) > 0.4
    projected = np.column_stack([rng.uniform(0, w - 1, 40), rng.uniform(0, h - 1, 40)])
    kept, chosen = rng.random(40) > 0.5, rng.random(40) > 0.8
    got = images.site_overlay_bgr(rgb, mask, projected, kept, chosen)
    assert np.array_equal(got, reference_site_overlay(rgb, mask, projected, kept, chosen))
    assert np.array_equal(images.overlay_bgr(rgb, np.ones((h, w), bool))[0, 0],
                          cv2.addWeighted(rgb[:1, :1, ::-1].copy(), 0.55,
                                          images.SAFE_BGR[None, None].copy(), 0.45, 0.0)[0, 0])


ARRAYS: dict[str, Any] = {
    "f32": np.linspace(0, 1, 48 * 64, dtype=np.float32).reshape(48, 64), "f16": np.full((3, 4), np.nan, np.float16),
    "mask": np.eye(5, dtype=bool), "ints": np.arange(7, dtype=np.int64), "empty": np.zeros((0, 3)),
    "scalar": np.float64(3.5), "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
    "strided": np.arange(40.0).reshape(5, 8)[:, ::2],
}


@pytest.mark.parametrize("stored", [True, False])
def test_npz_members_are_the_bytes_np_save_writes_and_load_back(tmp_path, stored) -> None:
    path = tmp_path / "maps.npz"
    files.write_npz_streamed(path, ARRAYS, stored=frozenset(ARRAYS) if stored else frozenset())
    with np.load(path) as z:
        for name, value in ARRAYS.items():
            want = np.asarray(value)
            assert z[name].dtype == want.dtype and z[name].shape == want.shape, name
            assert np.array_equal(z[name], want, equal_nan=want.dtype.kind == "f"), name
    with zipfile.ZipFile(path) as zf:
        for name, value in ARRAYS.items():
            buf = io.BytesIO()
            np.save(buf, np.asarray(value, order="C"))
            assert zf.read(f"{name}.npy") == buf.getvalue(), name
            assert zf.getinfo(f"{name}.npy").compress_type == (zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED)
        assert zf.testzip() is None  # every member's CRC checks


def test_an_object_array_is_refused_not_pickled(tmp_path) -> None:
    with pytest.raises(ValueError, match="pickling"):
        files.write_npz_streamed(tmp_path / "x.npz", {"o": np.array([{"a": 1}], dtype=object)})
    assert list(tmp_path.iterdir()) == []  # the temporary is removed


# ----------------------------------------------------------------------------- a run, read back
@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[Path, list[Any]]:
    """A 4-frame clear_field run, every frame a detection, with the detections the writer was handed."""
    rec = synth_recording(tmp_path_factory.mktemp("rec") / "clear.mcap", "clear_field", 4, *GAUSSIAN)
    out = tmp_path_factory.mktemp("runs") / "run"
    seen: list[Any] = []
    write = run_folder.write_detection

    def keep(run_dir, det, cfg, *rest) -> None:
        seen.append(det)
        write(run_dir, det, cfg, *rest)

    mp = pytest.MonkeyPatch()
    mp.setattr(run_folder, "write_detection", keep)
    try:
        res = CliRunner().invoke(main, ["detect", str(rec), "-o", str(out), *EVERY])
    finally:
        mp.undo()
    assert res.exit_code == 0, res.output
    assert len(seen) == 4
    return out, seen


def read_results(path: Path) -> tuple[dict[str, list[Any]], dict[str, str], set[str]]:
    """results.mcap: decoded messages per topic, schema name per topic, the chunks' compressions."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    msgs: dict[str, list[Any]] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        info = reader.get_summary()
        assert info is not None
        schemas = {ch.topic: info.schemas[ch.schema_id].name for ch in info.channels.values()}
        compressions = {c.compression for c in info.chunk_indexes}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None
            msgs.setdefault(channel.topic, []).append(store.deserialize_cdr(message.data, schema.name))
    return msgs, schemas, compressions


def test_overlay_png_is_the_overlay_exactly(run) -> None:
    out, dets = run
    for det in dets:
        path = out / "frames" / f"{det.frame.index:06d}" / "overlay.png"
        got = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert got is not None and np.array_equal(got, detection_overlay_bgr(det))
        assert path.stat().st_size >= got.nbytes  # stored, not deflated (images.PHOTO_PNG)


def test_results_mcap_maps_are_exact_and_pictures_close(run) -> None:
    out, dets = run
    msgs, schemas, compressions = read_results(out / "results.mcap")
    assert compressions == {"lz4"}
    assert schemas["/slz/color/compressed"] == schemas["/slz/overlay/compressed"] == "sensor_msgs/msg/CompressedImage"
    assert "/slz/color" not in schemas and "/slz/overlay" not in schemas
    for i, det in enumerate(dets):
        for name in MAPS:
            img = msgs[f"/slz/maps/{name}"][i]
            assert img.encoding == "mono8" and (img.height, img.width) == det.score.mask.shape
            want = np.rint(np.clip(np.nan_to_num(det.maps.as_dict()[name], nan=0.0), 0, 1) * 255).astype(np.uint8)
            assert np.array_equal(img.data.reshape(img.height, img.width), want), name
        score = msgs["/slz/score"][i]
        want = np.rint(np.clip(np.nan_to_num(det.score.score, nan=0.0), 0, 1) * 255).astype(np.uint8)
        assert np.array_equal(score.data.reshape(score.height, score.width), want)
        overlay_png = cv2.imread(str(out / "frames" / f"{det.frame.index:06d}" / "overlay.png"), cv2.IMREAD_COLOR)
        assert overlay_png is not None
        for topic, original in (("/slz/color/compressed", cv2.cvtColor(det.frame.rgb, cv2.COLOR_RGB2BGR)),
                                ("/slz/overlay/compressed", overlay_png)):
            msg = msgs[topic][i]
            assert "jpeg" in msg.format
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert stamp == det.frame.stamp_ns
            decoded = cv2.imdecode(msg.data, cv2.IMREAD_COLOR)
            assert decoded is not None and decoded.shape == original.shape, topic
            err = np.abs(decoded.astype(np.int16) - original.astype(np.int16))
            assert err.mean() < JPEG_MEAN_ABS_MAX, (topic, err.mean())


# ----------------------------------------------------------------------------- the recording writer
@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_recording_chunks_take_the_compression_asked_and_slz_reads_them(tmp_path, compression) -> None:
    path = tmp_path / "rec.mcap"
    frames = [B.textured_frame(i) for i in range(3)]
    with RecordingWriter(path, "mcap", compression=compression) as w:
        for f in frames:
            w.write_frame(f)
    _, _, compressions = read_results(path)
    assert compressions == {"" if compression == "none" else compression}
    with open_recording(path, load_config()) as rec:
        got = list(rec.frames())
    assert len(got) == 3
    for f, g in zip(frames, got, strict=True):
        assert np.array_equal(f.rgb, g.rgb) and np.allclose(f.depth_m, g.depth_m, atol=5e-4)


def test_an_unknown_compression_is_refused_naming_the_file(tmp_path) -> None:
    with pytest.raises(OutputError, match="unknown MCAP compression 'brotli'") as err:
        RecordingWriter(tmp_path / "rec.mcap", "mcap", compression="brotli")
    assert "rec.mcap" in str(err.value)
