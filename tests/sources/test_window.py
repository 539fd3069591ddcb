"""The time window (sources.window; --start/--end/--stride/--max-frames on detect, compare and info).

The readers apply it to colour/depth pairs in stamp order, before decoding, and stop reading once
no later pair can be in it; ``slz info`` counts within it; the window is in the rerun key.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import GAUSSIAN, synth_recording
from sources_util import PERIOD_NS, T0_NS, write_frames
from test_sources_tum import make_tum

from slzcli.cli import main
from slzcli.config import WindowCfg, load_config
from slzcli.errors import ConfigError
from slzcli.sources import open_recording
from slzcli.sources.window import WindowFilter

N = 20  # frames written; the sources_util frames are PERIOD_NS apart from T0_NS


def window(**kw: object) -> WindowCfg:
    base = {"start_s": None, "end_s": None, "start_stamp_s": None, "end_stamp_s": None, "stride": 1, "max_frames": 0}
    return WindowCfg(**{**base, **kw})  # type: ignore[arg-type]


def kept(win: WindowCfg, stamps: list[int]) -> list[int]:
    f = WindowFilter(win)
    return [i for i, s in enumerate(stamps) if f.keep(s)]


STAMPS = [T0_NS + i * PERIOD_NS for i in range(N)]


@pytest.mark.parametrize(("kw", "expected"), [
    ({}, list(range(N))),
    # [0.1 s, 0.4 s): frame 3 at 0.099999999 s and 12 at 0.399999996 s are within BOUND_TOLERANCE_NS (1 us)
    # of the bounds, so on them: 3 is in, 12 out
    ({"start_s": 0.1, "end_s": 0.4}, list(range(3, 12))),
    ({"start_s": 3 * PERIOD_NS / 1e9}, list(range(3, N))),         # a frame exactly at start is in
    ({"end_s": 3 * PERIOD_NS / 1e9}, [0, 1, 2]),                    # a frame exactly at end is out
    ({"stride": 3}, list(range(0, N, 3))),
    ({"stride": 2, "max_frames": 4}, [0, 2, 4, 6]),
    ({"start_s": 0.21, "stride": 5}, [7, 12, 17]),                  # strides count from the window's start
    ({"start_stamp_s": (T0_NS + 5 * PERIOD_NS) / 1e9}, list(range(5, N))),
    ({"end_stamp_s": (T0_NS + 3 * PERIOD_NS) / 1e9}, [0, 1, 2]),   # exact to the float's 0.24 us
])
def test_window_filter_keeps_the_pairs_of_the_window(kw, expected) -> None:
    assert kept(window(**kw), STAMPS) == expected


def test_window_filter_counts_what_it_leaves_out_and_knows_when_done() -> None:
    f = WindowFilter(window(start_s=0.1, end_s=0.4, stride=2))
    for s in STAMPS:
        f.keep(s)
    assert (f.before, f.after, f.strided, f.kept) == (3, 8, 4, 5)
    assert f.left_out + f.kept == N and f.done()
    g = WindowFilter(window(max_frames=2))
    assert [g.keep(s) for s in STAMPS[:3]] == [True, True, False] and g.done()
    assert not WindowFilter(window(end_s=1.0)).done()  # nothing seen yet


@pytest.mark.parametrize(("kw", "key"), [
    ({"start_s": 2.0, "end_s": 1.0}, "sources.window.end_s"),
    ({"start_stamp_s": 5.0, "end_stamp_s": 5.0}, "sources.window.end_stamp_s"),
    ({"start_s": 1.0, "start_stamp_s": 1.0}, "sources.window.start_s"),
])
def test_a_contradictory_window_is_a_config_error_naming_the_key(kw, key) -> None:
    with pytest.raises(ConfigError) as err:
        WindowFilter(window(**kw))
    assert err.value.key == key


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2-sqlite", "tum"])
def test_readers_read_only_the_window_and_info_counts_within_it(tmp_path: Path, fmt: str) -> None:
    if fmt == "tum":
        path = tmp_path / "seq"
        make_tum(path, n=N)
        period_s = 0.033333
    else:
        path = tmp_path / ("rec" + {"mcap": ".mcap", "ros1": ".bag"}.get(fmt, ""))
        write_frames(path, fmt, n=N)
        period_s = PERIOD_NS / 1e9
    config = load_config(None, [f"sources.window.start_s={3.5 * period_s}", f"sources.window.end_s={15.5 * period_s}",
                                "sources.window.stride=2"])
    with open_recording(path, config) as rec:
        info = rec.info()
        frames = list(rec.frames())
    first = frames[0].stamp_ns
    offsets = [round((f.stamp_ns - first) / 1e9 / period_s) for f in frames]
    assert offsets == [0, 2, 4, 6, 8, 10]                   # frames 4, 6, ..., 14 of the recording
    assert [f.index for f in frames] == list(range(6))      # numbered within the window
    assert info.pairing.paired == rec.report.paired == 6
    assert info.pairing.outside_window == N - 6             # info saw every pair; frames() all up to the end
    assert rec.report.outside_window <= N - 6
    assert any(n.startswith("window --start") for n in rec.report.notes)


def test_the_reader_stops_once_no_later_pair_can_be_in_the_window(tmp_path: Path, monkeypatch) -> None:
    """--end 5 frames into a 200-frame recording reads about the first 5 frames plus the pairing window
    (sources.reorder_window_ms 500 ms = 15 periods here), not all 200."""
    path = tmp_path / "long.mcap"
    write_frames(path, "mcap", n=200)
    from slzcli.sources.messages import MessageRecording

    seen = {"n": 0}
    wrap = MessageRecording._wrap

    def counting(self, it):
        for m in wrap(self, it):
            seen["n"] += 1
            yield m

    monkeypatch.setattr(MessageRecording, "_wrap", counting)
    config = load_config(None, [f"sources.window.end_s={4.5 * PERIOD_NS / 1e9}"])
    with open_recording(path, config) as rec:
        seen["n"] = 0
        frames = list(rec.frames())
    assert len(frames) == 5
    # 2 image messages a frame (+ CameraInfo): 200 frames are >= 400 messages; measured 64 read here, 55 below
    assert seen["n"] < 100, seen["n"]
    config = load_config(None, ["sources.window.max_frames=3"])
    with open_recording(path, config) as rec:
        seen["n"] = 0
        assert len(list(rec.frames())) == 3
    assert seen["n"] < 100, seen["n"]


def test_info_cli_window_and_usage_errors(runner, tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    write_frames(path, "mcap", n=N)
    res = runner.invoke(main, ["info", str(path), "--start", "0.1", "--end", "0.4", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["frames"] == info["pairing"]["paired"] == 9 and info["pairing"]["outside_window"] == 11
    res = runner.invoke(main, ["info", str(path), "--start", f"@{(T0_NS + 15 * PERIOD_NS) / 1e9!r}", "--json"])
    assert res.exit_code == 0 and json.loads(res.stdout)["frames"] == 5
    res = runner.invoke(main, ["info", str(path), "--max-frames", "4", "--stride", "3"])
    assert res.exit_code == 0 and "RGB-D frames that pair: 4" in res.stdout
    assert "--stride 3 --max-frames 4" in res.stdout
    for bad in (["--start", "x"], ["--start", "-1"], ["--end", "nan"], ["--start", "@"], ["--stride", "0"],
                ["--max-frames", "0"], ["--start", "2", "--end", "1"], ["--set", "nokey"]):
        res = runner.invoke(main, ["info", str(path), *bad])
        assert res.exit_code == 2, (bad, res.output)
        assert "Traceback" not in res.output
    # the same contradiction through the config keys is a config error (exit 1) naming the key
    res = runner.invoke(main, ["info", str(path), "--set", "sources.window.start_s=2", "--set",
                               "sources.window.end_s=1"])
    assert res.exit_code == 1 and "sources.window.end_s: must be later than" in res.stderr


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("win") / "cf.mcap", "clear_field", 6, *GAUSSIAN)


def test_detect_window_is_in_run_json_and_the_rerun_key(runner, flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["detect", str(flight), "-o", str(out), "--outputs", "summary", "--json"]
    res = runner.invoke(main, [*args, "--max-frames", "3"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    assert s["frames"] == 3 and s["pairing"]["paired"] == 3 and s["pairing"]["outside_window"] == 3
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["sources"]["window"]["max_frames"] == 3
    res = runner.invoke(main, [*args, "--max-frames", "3"])          # the same window: done before
    assert res.exit_code == 0 and json.loads(res.stdout)["skipped"] is True
    res = runner.invoke(main, [*args, "--max-frames", "4"])          # another window: another run
    assert res.exit_code == 1 and "sources.window.max_frames 3 -> 4" in res.stderr
    res = runner.invoke(main, [*args, "--max-frames", "4", "--force"])
    assert res.exit_code == 0 and json.loads(res.stdout)["frames"] == 4


def test_an_empty_window_fails_naming_it_and_leaves_nothing(runner, flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(flight), "-o", str(out), "--start", "100"])
    assert res.exit_code == 1
    assert "no RGB-D frame in the window (window --start 100 s: 0 frame(s) read, 6 before the start" in res.stderr
    assert not out.exists()


def test_compare_reads_the_window(runner, flight: Path, tmp_path: Path) -> None:
    local = tmp_path / flight.name
    for f in flight.parent.iterdir():  # the recording and its ground-truth sidecars
        shutil.copy(f, tmp_path / f.name)
    res = runner.invoke(main, ["compare", str(local), "-o", str(tmp_path / "cmp"), "--stride", "2", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["recordings"][0]["frames"] == 3
