"""The fused landing map's outputs: /slz/landing_map in results.mcap (a foxglove_msgs/Grid Foxglove draws without
configuration), landing_map.png's legend and scale bar, and the landing-map section of report.html.

The grid is read back with the ``mcap`` library and decoded with the schema text the file itself carries (not the
typestore that wrote it), its fields read by the names and offsets the message declares, and compared cell for
cell with landing_map.npz. The schema is held against foxglove/schemas' ros_foxglove_msgs/ros2 definitions, written
out here as the oracle, and the message against the checks Foxglove's 3D panel makes before it draws a Grid
(FoxgloveGrid.ts ``_validateFoxgloveGrid``).
"""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path
from typing import Any

import cv2
import jinja2
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, synth_recording

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.outputs import detect_report, palette
from slzcli.outputs.landing_map import LEGEND_BAND_PX, landing_map_bgr, px_per_cell, read_landing_map
from slzcli.outputs.results_mcap import ResultsMcap
from slzcli.records import DecideAdvice
from slzcli.types import LandingGrid

FRAMES = 8
FAST = ("--set", "slam.backend=odometry")
TOPIC = "/slz/landing_map"
NAMES = ("unseen", "unsafe", "undecided", "safe")   # the codes docs/USAGE.md and results_mcap's docstring give
# foxglove/schemas ros_foxglove_msgs/ros2 (the oracle): (type, name) of every field, constants apart
FOXGLOVE = {
    "foxglove_msgs/msg/Grid": [("builtin_interfaces/Time", "timestamp"), ("string", "frame_id"),
                               ("geometry_msgs/Pose", "pose"), ("uint32", "column_count"),
                               ("foxglove_msgs/Vector2", "cell_size"), ("uint32", "row_stride"),
                               ("uint32", "cell_stride"), ("foxglove_msgs/PackedElementField[]", "fields"),
                               ("uint8[]", "data")],
    "foxglove_msgs/PackedElementField": [("string", "name"), ("uint32", "offset"), ("uint8", "type")],
    "foxglove_msgs/Vector2": [("float64", "x"), ("float64", "y")],
}
PACKED = {1: ("u1", 1), 2: ("i1", 1), 3: ("<u2", 2), 4: ("<i2", 2), 5: ("<u4", 4), 6: ("<i4", 4), 7: ("<f4", 4),
          8: ("<f8", 8)}   # PackedElementField type -> numpy type, bytes


# ----------------------------------------------------------------------------- reading results.mcap
def split_msgdef(name: str, text: str) -> dict[str, str]:
    """A ros2msg schema (the main definition, then ``MSG: <name>`` sections) -> {name: definition}."""
    parts = re.split(r"^={80}\n", text, flags=re.M)
    out = {name: parts[0]}
    for part in parts[1:]:
        head, _, body = part.partition("\n")
        out[head.removeprefix("MSG: ").strip()] = body
    return out


def fields_of(definition: str) -> list[tuple[str, str]]:
    return [(ln.split()[0], ln.split()[1]) for ln in definition.splitlines()
            if ln.strip() and not ln.startswith("#") and "=" not in ln]


def read_grids(path: Path) -> tuple[Any, list[tuple[int, Any]]]:
    """(the schema record, [(log time, message)]) of /slz/landing_map, decoded with the file's own schema."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    out: list[tuple[int, Any]] = []
    schema: Any = None
    with path.open("rb") as fh:
        for sch, _channel, msg in make_reader(fh).iter_messages(topics=[TOPIC], log_time_order=False):
            assert sch is not None
            if schema is None:
                schema = sch
                types: dict[str, Any] = {}
                for name, text in split_msgdef(sch.name, sch.data.decode()).items():
                    full = name if "/msg/" in name else name.replace("/", "/msg/", 1)
                    types.update(get_types_from_msg(text, full))
                store.register(types)
            out.append((msg.log_time, store.deserialize_cdr(msg.data, sch.name)))
    return schema, out


def decode(msg: Any) -> np.ndarray:
    """The cells as records, by the names, offsets and types the message declares (rows = y)."""
    dtype = np.dtype({"names": [f.name for f in msg.fields], "formats": [PACKED[f.type][0] for f in msg.fields],
                      "offsets": [f.offset for f in msg.fields], "itemsize": msg.cell_stride})
    rows = len(msg.data) // msg.row_stride
    data = np.asarray(msg.data, np.uint8).reshape(rows, msg.row_stride)[:, :msg.column_count * msg.cell_stride]
    return np.ascontiguousarray(data).view(dtype).reshape(rows, msg.column_count)


def foxglove_accepts(msg: Any) -> None:
    """What Foxglove's 3D panel checks before it draws a Grid, and what makes it pick the RGBA fields itself."""
    assert msg.fields, "Grid has no fields"
    assert len(msg.data) % msg.row_stride == 0, "row count is not an integer"
    assert msg.cell_stride * msg.column_count <= msg.row_stride
    assert max(f.offset + PACKED[f.type][1] for f in msg.fields) <= msg.cell_stride
    assert {"red", "green", "blue", "alpha"} <= {f.name for f in msg.fields}   # "RGBA (separate fields)", auto
    assert msg.cell_size.x > 0 and msg.cell_size.y > 0
    q = msg.pose.orientation
    assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


# ----------------------------------------------------------------------------- a grid of known cells
def toy_grid(seed: int = 0, shape: tuple[int, int] = (37, 53)) -> LandingGrid:
    rng = np.random.default_rng(seed)
    verdict = rng.integers(0, 4, shape).astype(np.uint8)
    seen = verdict != 0

    def f(a: np.ndarray) -> np.ndarray:
        return np.where(seen, a, np.nan).astype(np.float32)

    return LandingGrid(origin_xy=(-3 * 0.082, 17 * 0.082), resolution_m=0.082, segment=0, frame_index=41,
                       stamp_ns=1_700_000_001_234_567_890, verdict=verdict, verdict_names=NAMES,
                       score=f(rng.random(shape)), height_m=f(rng.normal(-8.0, 0.1, shape)),
                       variance_m2=f(rng.random(shape) * 0.01), looks=f(rng.random(shape) * 20))


def test_the_grid_message_round_trips_through_its_own_schema(tmp_path: Path) -> None:
    grid = toy_grid()
    with ResultsMcap(tmp_path / "results.mcap", load_config()) as res:
        res.write_landing_grid(grid)
    schema, msgs = read_grids(tmp_path / "results.mcap")
    assert schema.name == "foxglove_msgs/msg/Grid" and schema.encoding == "ros2msg"
    defs = split_msgdef(schema.name, schema.data.decode())
    for name, expected in FOXGLOVE.items():
        assert fields_of(defs[name]) == expected, name
    assert len(msgs) == 1
    log_time, msg = msgs[0]
    foxglove_accepts(msg)
    assert log_time == grid.stamp_ns == msg.timestamp.sec * 10**9 + msg.timestamp.nanosec
    assert msg.frame_id == "map"
    assert (msg.pose.position.x, msg.pose.position.y) == grid.origin_xy
    # display height: the median of a sample of the cells (heights here: N(-8, 0.1) m)
    assert msg.pose.position.z == pytest.approx(float(np.nanmedian(grid.height_m)), abs=0.05)
    assert msg.cell_size.x == msg.cell_size.y == grid.resolution_m
    cells = decode(msg)
    assert cells.shape == grid.shape
    assert same(cells["verdict"], grid.verdict) and same(cells["score"], grid.score)
    assert same(cells["height_m"], grid.height_m) and same(cells["looks"], grid.looks)
    assert same(cells["height_std_m"], np.sqrt(grid.variance_m2))
    for code, name in enumerate(NAMES):
        at = grid.verdict == code
        rgba = np.stack([cells[c][at] for c in ("red", "green", "blue", "alpha")], axis=1)
        colour = palette.UNSEEN if name == "unseen" else dict(palette.VERDICTS)[name]
        assert (rgba == [*colour, 0 if name == "unseen" else 255]).all(), name   # unseen: transparent


def test_the_picture_has_its_legend_scale_bar_and_the_site() -> None:
    grid = toy_grid(1, (60, 90))
    k = px_per_cell(grid)
    site = np.array([[0.5, 2.0], [0.5, 2.6], [1.1, 2.0], [1.1, 2.6]])
    img = landing_map_bgr(grid, site)
    map_h = grid.shape[0] * k
    assert img.shape[0] == map_h + LEGEND_BAND_PX and img.shape[1] >= grid.shape[1] * k
    band = img[map_h:]
    for name, rgb in (("safe", palette.SAFE), ("unsafe", palette.UNSAFE), ("undecided", palette.UNDECIDED),
                      ("unseen", palette.UNSEEN)):
        assert (band == palette.bgr(rgb)).all(axis=2).sum() >= 100, name   # a 13 x 13 swatch each, minus its border
    # the scale bar: one black 2 px line whose length is a round number of metres at the picture's scale
    rows = np.flatnonzero(((band == 0).all(axis=2)).sum(axis=1) > 40)
    assert rows.size >= 2
    length_px = int(((band[rows[0]] == 0).all(axis=1)).sum())
    metres = length_px * grid.resolution_m / k
    assert min(abs(metres - m) for m in (0.5, 1, 2, 5, 10, 20, 50)) < 2 * grid.resolution_m / k + 0.01
    # the site's square: a white outline where its edges fall (y up)
    ox, oy = grid.origin_xy
    col = round((0.8 - ox) / grid.resolution_m * k)
    row = round((grid.shape[0] - (2.6 - oy) / grid.resolution_m) * k)
    assert (img[row - 2:row + 3, col] == 255).all(axis=1).any()


# ----------------------------------------------------------------------------- through the CLI
@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("lm") / "clear.mcap", "clear_field", FRAMES, *GAUSSIAN)


def detect(recording: Path, out: Path, *args: str) -> dict[str, Any]:
    res = CliRunner().invoke(main, ["detect", str(recording), "-o", str(out), *FAST, *args])
    assert res.exit_code == 0, res.output
    return json.loads((out / "run.json").read_text())


@pytest.fixture(scope="module")
def fused(recording, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fused") / "run"
    detect(recording, out, "--method", "fused")
    return out


def funnel_times(path: Path) -> list[int]:
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        return [m.log_time for _s, _c, m in make_reader(fh).iter_messages(topics=["/slz/funnel"])]


@pytest.mark.slow   # whole slz synth / detect runs (conftest.SLOW_FILES)
def test_results_mcap_carries_the_landing_map_per_detection_and_the_flights_at_the_end(fused: Path) -> None:
    _schema, msgs = read_grids(fused / "results.mcap")
    run = json.loads((fused / "run.json").read_text())
    detections = funnel_times(fused / "results.mcap")
    assert len(detections) == run["summary"]["detections"] > 0
    # one grid per detection frame at its stamp, then the flight's
    assert [t for t, _ in msgs[:-1]] == detections
    for t, msg in msgs:
        foxglove_accepts(msg)
        assert msg.timestamp.sec * 10**9 + msg.timestamp.nanosec == t
    with np.load(fused / "landing_map.npz") as z:
        npz = {k: z[k] for k in z.files}
    t, last = msgs[-1]
    assert t == int(npz["stamp_ns"]) and t >= detections[-1]
    assert last.frame_id == str(npz["frame_id"]) == "map"
    assert (last.pose.position.x, last.pose.position.y) == tuple(npz["origin_xy"])     # exactly
    assert last.cell_size.x == last.cell_size.y == float(npz["resolution_m"])
    cells = decode(last)
    assert cells.shape == npz["verdict"].shape
    assert tuple(str(n) for n in npz["verdict_names"]) == NAMES
    assert same(cells["verdict"], npz["verdict"]) and same(cells["score"], npz["score"])
    assert same(cells["height_m"], npz["height_m"]) and same(cells["looks"], npz["looks"])
    assert same(cells["height_std_m"], np.sqrt(npz["variance_m2"]))
    assert (cells["verdict"] == NAMES.index("safe")).any() and (cells["verdict"] == NAMES.index("unsafe")).any()
    # each detection's grid is the cells it judged: where both hold a cell, the verdict is a cell of the same
    # ground (same lattice: origins on whole cells)
    for _t, msg in msgs[:-1]:
        offset = (np.array([msg.pose.position.x, msg.pose.position.y]) - npz["origin_xy"]) / npz["resolution_m"]
        assert np.allclose(offset, np.round(offset), atol=1e-6)


@pytest.mark.slow   # whole slz synth / detect runs (conftest.SLOW_FILES)
def test_the_report_shows_the_landing_map_with_the_site(fused: Path) -> None:
    page = (fused / "report.html").read_text()
    assert "id=landing_map>" in page and "/slz/landing_map" in page
    assert page.index("id=result>") < page.index("id=landing_map>") < page.index("id=funnel>")
    pngs = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(pngs) == 1
    img = cv2.imdecode(np.frombuffer(base64.b64decode(pngs[0]), np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    grid = read_landing_map(fused / "landing_map.npz")
    assert img.shape[0] == grid.shape[0] * px_per_cell(grid) + LEGEND_BAND_PX
    landing = json.loads((fused / "landing.json").read_text())
    assert landing["status"] == "site"     # the clear field from 10 m with Gaussian noise: a site
    assert "The committed site's square is outlined" in page
    # the committed square drawn: on the map, the PNG without it plus a white outline on a black halo
    k = px_per_cell(grid)
    map_px = grid.shape[0] * k
    changed = (img[:map_px] != landing_map_bgr(grid)[:map_px]).any(axis=2)
    assert changed.any()
    assert ((img[:map_px][changed] == 255).all(axis=1) | (img[:map_px][changed] == 0).all(axis=1)).all()
    centre = np.asarray(landing["site"]["center_world"])[:2]
    ox, oy = grid.origin_xy
    col = (centre[0] - ox) / grid.resolution_m * k
    row = (grid.shape[0] - (centre[1] - oy) / grid.resolution_m) * k
    rows, cols = np.nonzero(changed)
    assert abs(rows.mean() - row) < 3 * k and abs(cols.mean() - col) < 3 * k   # the outline is around the site


@pytest.mark.slow   # whole slz synth / detect runs (conftest.SLOW_FILES)
def test_the_advice_is_shown_when_the_method_gives_one(fused: Path) -> None:
    text = "to decide the ground at (1.2, 3.4) m: 12 more frames or 2.1 m of sideways flight"
    assert detect_report._advice_text(DecideAdvice("fused", text)) == text
    assert detect_report._advice_text(None) is None and detect_report._advice_text(DecideAdvice("fused", "")) is None
    section = detect_report._landing_map(fused, None, text + " <b>")
    assert "What would decide the undecided ground" in section and "12 more frames" in section
    assert "&lt;b&gt;" in section and "No site was committed." in section
    assert "What would decide" not in detect_report._landing_map(fused, None, None)


@pytest.mark.slow   # whole slz synth / detect runs (conftest.SLOW_FILES)
def test_per_frame_methods_keep_their_report_and_results(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "fuzzy"
    detect(recording, out, "--method", "fuzzy")
    page = (out / "report.html").read_text()
    assert "landing_map" not in page and not (out / "landing_map.npz").exists()
    _schema, msgs = read_grids(out / "results.mcap")
    assert msgs == []
    # the template renders the same bytes as before the section was added, when there is none
    env = jinja2.Environment(loader=jinja2.PackageLoader("slzcli.outputs", "templates"), autoescape=True,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    assert env.loader is not None
    source = env.loader.get_source(env, "detect_report.html")[0]
    before = source.replace("{% if landing_map %}\n{{ landing_map }}\n{% endif %}\n", "")
    assert before != source
    ctx = {"name": "x", "css": "", "result": "R", "funnel": "F", "figure5": "G", "trajectory": "T",
           "site_columns": [], "sites": [], "detections": [], "level": "maps", "timings": []}
    assert env.get_template("detect_report.html").render(landing_map="", **ctx) == \
        env.from_string(before).render(**ctx)
