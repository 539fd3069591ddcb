"""Property-based tests (hypothesis): decoders, config loader, maps, fuzzy engine, site selection.

Example counts are kept moderate (the whole file runs in well under a minute).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slzcli.config import load_config
from slzcli.errors import ConfigError
from slzcli.landing.select import select_site
from slzcli.methods.maps import fuzzy
from slzcli.outputs.recording import RecordingWriter
from slzcli.scoring import get_scorer
from slzcli.sources import decode
from slzcli.terrain.maps import compute_maps
from slzcli.types import Intrinsics, TerrainMaps

CONFIG = load_config()
FUZZY = get_scorer(CONFIG.scoring, CONFIG.mask, "fuzzy")
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _up() -> np.ndarray:
    """World up in the optical frame of a camera looking straight down (z forward = down, y = image down)."""
    return np.array([0.0, 0.0, -1.0])


def _writer(ros1: bool, **kw) -> RecordingWriter:
    """A writer used only for its message helpers (never opened: no file is written)."""
    return RecordingWriter("unused.mcap", "mcap-ros1" if ros1 else "mcap", **kw)


def _roundtrip(w: RecordingWriter, msgtype: str, msg):
    """Serialise and deserialise as a reader would (CDR or ROS 1)."""
    ts = w.typestore
    if w.ros1:
        return ts.deserialize_ros1(ts.serialize_ros1(msg, msgtype), msgtype)
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msgtype), msgtype)


sizes = st.tuples(st.integers(1, 24), st.integers(1, 24))


# ----------------------------------------------------------------------------- decoders
@SETTINGS
@given(size=sizes, enc=st.sampled_from(["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "png"]), ros1=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_colour_roundtrips_through_writer_and_decoder(size, enc, ros1, seed) -> None:
    w_px, h_px = size
    rgb = np.random.default_rng(seed).integers(0, 256, (h_px, w_px, 3), dtype=np.uint8)
    if enc == "mono8":
        rgb[..., 1] = rgb[..., 2] = rgb[..., 0]  # grey in, grey out
    w = _writer(ros1, color_encoding=enc)
    msgtype, msg = w.color_message(rgb, 1)
    out = decode.decode_color(_roundtrip(w, msgtype, msg))
    assert out.dtype == np.uint8 and out.shape == (h_px, w_px, 3)
    np.testing.assert_array_equal(out, rgb)


@SETTINGS
@given(size=sizes, enc=st.sampled_from(["16UC1", "mono16", "32FC1", "compressedDepth"]), big=st.booleans(),
       ros1=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_depth_roundtrips_in_any_encoding_and_byte_order(size, enc, big, ros1, seed) -> None:
    w_px, h_px = size
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 65536, (h_px, w_px))
    counts[rng.random((h_px, w_px)) < 0.2] = 0  # holes
    depth = np.where(counts > 0, counts / 1000.0, np.nan).astype(np.float32)
    w = _writer(ros1, depth_encoding=enc, big_endian=big)
    msgtype, msg = w.depth_message(depth, 1)
    out = decode.decode_depth(_roundtrip(w, msgtype, msg), 0.001)
    assert out.dtype == np.float32 and out.shape == (h_px, w_px)
    np.testing.assert_array_equal(np.isnan(out), counts == 0)
    ok = counts > 0
    np.testing.assert_allclose(out[ok], depth[ok], rtol=1e-6)


def _valid_payloads() -> list[bytes]:
    """Real jpeg, 8-bit png and compressedDepth (header + 16-bit png) bytes for the fuzzer to cut and flip."""
    import cv2

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    counts = rng.integers(0, 65536, (12, 16)).astype(np.uint16)
    return [cv2.imencode(".jpg", rgb)[1].tobytes(), cv2.imencode(".png", rgb)[1].tobytes(),
            decode.COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0) + cv2.imencode(".png", counts)[1].tobytes()]


PAYLOADS = _valid_payloads()


@st.composite
def damaged(draw) -> bytes:
    """A real payload cut short and with a few bytes overwritten, or plain garbage."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=512))
    data = bytearray(draw(st.sampled_from(PAYLOADS)))
    data = data[: draw(st.integers(0, len(data)))]
    for _ in range(draw(st.integers(0, 4))):
        if data:
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
    return bytes(data)


def _image(encoding: str, height: int, width: int, step: int, big: bool, data: bytes):
    from types import SimpleNamespace as NS

    return NS(__msgtype__="sensor_msgs/msg/Image", encoding=encoding, height=height, width=width, step=step,
              is_bigendian=big, data=np.frombuffer(data, np.uint8))


def _compressed(fmt: str, data: bytes):
    from types import SimpleNamespace as NS

    return NS(__msgtype__="sensor_msgs/msg/CompressedImage", format=fmt, data=np.frombuffer(data, np.uint8))


raw_images = st.builds(_image, st.sampled_from([*decode.COLOR_ENCODINGS, *decode.DEPTH_ENCODINGS, "64FC1", "", "8UC3"]),
                       st.integers(0, 40), st.integers(0, 40), st.integers(0, 400), st.booleans(),
                       st.binary(max_size=4096))
compressed_images = st.builds(_compressed, st.sampled_from(
    ["jpeg", "png", "rgb8; jpeg compressed bgr8", "16UC1; compressedDepth", "32FC1; compressedDepth png",
     "16UC1; compressedDepth rvl", "", "bgr8; compressedDepth"]), damaged())


@settings(max_examples=int(os.environ.get("SLZ_FUZZ_EXAMPLES", "300")), deadline=None)
@given(msg=st.one_of(raw_images, compressed_images))
def test_decoders_on_damaged_messages_give_an_image_or_a_decode_error(msg) -> None:
    """Whatever a torn or hostile message holds, decoding raises DecodeError (the frame is skipped and
    counted) or returns a well-formed image: never another exception, never a wrong dtype."""
    from slzcli.errors import DecodeError

    for fn, dtype, ndim in ((decode.decode_color, np.uint8, 3),
                            (lambda m: decode.decode_depth(m, 0.001), np.float32, 2)):
        try:
            out = fn(msg)
        except DecodeError:
            continue
        assert out.dtype == dtype and out.ndim == ndim
        if ndim == 3:
            assert out.shape[2] == 3
        if hasattr(msg, "height"):
            assert out.shape[:2] == (msg.height, msg.width)


# ----------------------------------------------------------------------------- config loader
def _leaves(d: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in d.items():
        out += _leaves(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
    return out


KEYS = _leaves(CONFIG.to_dict())
ident = st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True)
keys = st.one_of(st.sampled_from(KEYS), st.lists(ident, min_size=1, max_size=4).map(".".join),
                 st.tuples(st.sampled_from(KEYS), ident).map(".".join),
                 st.text(max_size=12))
values = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                   st.text(max_size=10), st.lists(st.floats(-10, 10), max_size=4))


@settings(max_examples=50, deadline=None)
@given(key=keys, value=values, raw=st.booleans())
def test_config_override_is_a_config_or_a_config_error_naming_the_key(key, value, raw) -> None:
    import json

    text = str(value) if raw else json.dumps(value)
    item = f"{key}={text}"
    typed = item.partition("=")[0].strip()  # the key as --set reads it
    try:
        cfg = load_config(None, [item])
    except ConfigError as err:
        parts = typed.split(".")
        named = [".".join(parts[:i]) for i in range(1, len(parts) + 1)]
        assert err.key and err.key in str(err), (item, str(err))
        assert err.key in (item, typed) or err.key.split("[")[0] in named, (item, err.key, str(err))
        return
    assert typed in KEYS  # only a known key can load
    assert cfg.hash()


def _value(key: str):
    node = CONFIG.to_dict()
    for part in key.split("."):
        node = node[part]
    return node


@settings(max_examples=25, deadline=None)
@given(key=st.sampled_from([k for k in KEYS if isinstance(_value(k), float)]), sign=st.sampled_from(["", "-"]))
def test_infinite_float_is_refused_naming_the_key(key, sign) -> None:
    """``.inf`` used to pass every unbounded float (e.g. reorder_window_ms -> OverflowError deep in sync)."""
    with pytest.raises(ConfigError, match="must be finite") as err:
        load_config(None, [f"{key}={sign}.inf"])
    assert err.value.key == key


# ----------------------------------------------------------------------------- maps
def _scene(seed: int, w: int, h: int) -> np.ndarray:
    """Depth in whole millimetres: a tilted plane, a few boxes, some holes."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 4.0 + rng.uniform(-1, 1) * u / w + rng.uniform(-1, 1) * v / h
    for _ in range(rng.integers(0, 4)):
        u0, v0 = rng.integers(0, w), rng.integers(0, h)
        z[v0:v0 + rng.integers(2, h // 2), u0:u0 + rng.integers(2, w // 2)] -= rng.uniform(0.2, 1.5)
    counts = np.rint(z * 1000.0)
    counts[rng.random((h, w)) < rng.uniform(0, 0.3)] = 0
    return counts


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), size=st.sampled_from([(48, 36), (64, 48), (80, 60)]))
def test_maps_are_float32_in_unit_range_and_independent_of_depth_units(seed, size) -> None:
    w, h = size
    counts = _scene(seed, w, h)
    depth = np.where(counts > 0, counts / 1000.0, np.nan).astype(np.float32)
    intr = Intrinsics(0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2, w, h)
    maps = {}
    for enc in ("16UC1", "32FC1"):
        wr = _writer(False, depth_encoding=enc)
        msgtype, msg = wr.depth_message(depth, 1)
        d = decode.decode_depth(_roundtrip(wr, msgtype, msg), 0.001)
        maps[enc] = compute_maps(d, intr, _up(), CONFIG.terrain)
    m = maps["16UC1"]
    for name in TerrainMaps.NAMES:
        a = getattr(m, name)
        assert a.dtype == np.float32 and a.shape == (h, w), name
        finite = a[np.isfinite(a)]
        assert np.all((finite >= 0) & (finite <= 1)), name
        np.testing.assert_allclose(a, getattr(maps["32FC1"], name), atol=1e-4, equal_nan=True, err_msg=name)
    score = FUZZY(m)
    assert score.dtype == np.float32 and np.all(np.isfinite(score)), "NaN leaked into the score"
    assert np.all((score >= 0) & (score <= 1))


# ----------------------------------------------------------------------------- fuzzy engine
unit = st.floats(0, 1)


@settings(max_examples=50, deadline=None)
@given(x=st.tuples(unit, unit, unit, unit), i=st.integers(0, 3), a=unit, b=unit)
def test_shipped_rule_base_is_monotone_in_each_input(x, i, a, b) -> None:
    lo, hi = sorted((a, b))
    pts = np.array([x, x], dtype=np.float32)
    pts[0, i], pts[1, i] = lo, hi
    score = FUZZY.score_arrays({n: pts[:, k] for k, n in enumerate(TerrainMaps.NAMES)})
    assert score[0] <= score[1] + 1e-5, (x, i, lo, hi, score)


# ----------------------------------------------------------------------------- site selection
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 400))
def test_site_never_lies_on_a_pixel_the_mask_rejects(seed, n) -> None:
    rng = np.random.default_rng(seed)
    w, h, alt = 160, 120, 6.0
    f = 0.8 * w
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # camera at (0, 0, alt) looking down
    T[2, 3] = alt
    half = alt * np.array([w, h]) / (2 * f)
    xyz = np.column_stack([rng.uniform(-half[0], half[0], n), rng.uniform(-half[1], half[1], n),
                           rng.normal(0, 0.01, n)])
    mask = np.zeros((h, w), bool)
    for _ in range(rng.integers(0, 5)):  # random rectangles of "safe"
        u0, v0 = rng.integers(0, w), rng.integers(0, h)
        mask[v0:v0 + rng.integers(5, h), u0:u0 + rng.integers(5, w)] = True
    score = mask.astype(np.float32)
    sel = select_site(xyz, T, K, mask, score, fuzzy(CONFIG).params)
    assert sel.kept.sum() <= n
    if sel.site is None:
        assert sel.reason
        return
    u, v = sel.site.pixel
    assert mask[round(v), round(u)], (u, v)
    kept_px = np.round(sel.projected[sel.kept]).astype(int)
    assert np.all(mask[kept_px[:, 1], kept_px[:, 0]])
