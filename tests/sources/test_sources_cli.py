"""`slz info` on good and bad recordings: counts, --json, and one-line errors with exit code 1."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from sources_util import SUFFIX, known_frame, write_frames

from slzcli.cli import main
from slzcli.outputs.recording import RecordingWriter, TopicLayout


def run(runner: CliRunner, *args: str):
    return runner.invoke(main, ["info", *args], catch_exceptions=False)


def assert_one_line_error(result, *needles: str) -> None:
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.startswith("slz: error:")]
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for n in needles:
        assert n in lines[0], lines[0]


@pytest.mark.parametrize("fmt", list(SUFFIX))
def test_info_json_has_expected_counts(tmp_path: Path, runner: CliRunner, fmt: str) -> None:
    path = tmp_path / f"r{SUFFIX[fmt]}"
    write_frames(path, fmt, n=4)
    result = run(runner, "--json", str(path))
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["frames"] == 4 and summary["pairing"]["unpaired_color"] == 0
    counts = {t["topic"]: t["count"] for t in summary["topics"]}
    assert counts["/camera/color/image_raw"] == 4 and counts["/camera/aligned_depth_to_color/image_raw"] == 4
    assert summary["streams"]["depth"]["topic"] == "/camera/aligned_depth_to_color/image_raw"
    assert summary["streams"]["depth"]["reason"]
    assert summary["intrinsics"]["fx"] == pytest.approx(60.5) and summary["intrinsics"]["width"] == 32
    rates = [t["rate_hz"] for t in summary["topics"]]
    assert all(r == pytest.approx(30.0, rel=1e-3) for r in rates)


def test_info_text_is_plain_and_names_streams(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "r.bag"
    write_frames(path, "ros1", n=3)
    result = run(runner, str(path))
    assert result.exit_code == 0
    out = result.stdout
    assert "ros1 bag" in out and "/camera/color/image_raw" in out and "RGB-D frames that pair: 3" in out
    assert "aligned to colour" in out and "fx 60.500" in out
    assert "\x1b[" not in out  # no terminal escapes when not a terminal


def test_missing_path(tmp_path: Path, runner: CliRunner) -> None:
    assert_one_line_error(run(runner, str(tmp_path / "nope.mcap")), "nope.mcap", "no such file")


@pytest.mark.parametrize("name", ["empty.mcap", "empty.bag"])
def test_empty_file(tmp_path: Path, runner: CliRunner, name: str) -> None:
    (tmp_path / name).write_bytes(b"")
    assert_one_line_error(run(runner, str(tmp_path / name)), name, "empty")


@pytest.mark.parametrize("name,cause", [("junk.mcap", "not an MCAP file"), ("junk.bag", "not a ROS 1 bag")])
def test_garbage_bytes(tmp_path: Path, runner: CliRunner, name: str, cause: str) -> None:
    (tmp_path / name).write_bytes(np.random.default_rng(0).bytes(4096))
    assert_one_line_error(run(runner, str(tmp_path / name)), name, cause)


def test_garbage_rosbag2_folder(tmp_path: Path, runner: CliRunner) -> None:
    bag = tmp_path / "bag2"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    assert_one_line_error(run(runner, str(bag)), "bag2", "not a readable ros2 bag")


def test_cut_short_ros1_bag(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "r.bag"
    write_frames(path, "ros1", n=5)
    data = path.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert_one_line_error(run(runner, str(cut)), "cut.bag", "index")


def test_cut_short_mcap_before_any_message(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "r.mcap"
    write_frames(path, "mcap", n=5)  # one chunk: a cut anywhere loses all of it
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:200])
    assert_one_line_error(run(runner, str(cut)), "cut.mcap", "recovered 0 messages")


def test_cut_short_mcap_reports_what_was_recovered(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "r.mcap"
    write_frames(path, "mcap", n=30, chunk_bytes=6000)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    result = run(runner, "--json", str(cut))
    assert result.exit_code == 0
    summary = json.loads(result.stdout)
    assert 3 < summary["frames"] < 30
    assert "recovered" in summary["warnings"][0]
    assert "recovered" in result.stderr and "cut.mcap" in result.stderr


def test_no_depth_stream(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "colour_only.mcap"
    f = known_frame(0)
    with RecordingWriter(path, "mcap") as w:
        w.write_raw("/camera/color/image_raw", *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
    assert_one_line_error(run(runner, str(path)), "colour_only.mcap", "no depth stream")


def test_no_colour_stream(tmp_path: Path, runner: CliRunner) -> None:
    path = tmp_path / "depth_only.bag"
    f = known_frame(0)
    with RecordingWriter(path, "ros1") as w:
        w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
    assert_one_line_error(run(runner, str(path)), "depth_only.bag", "no colour stream")


def test_unknown_suffix_and_bad_topic_override(tmp_path: Path, runner: CliRunner) -> None:
    (tmp_path / "x.txt").write_text("hello")
    assert_one_line_error(run(runner, str(tmp_path / "x.txt")), "x.txt", "unknown recording type")
    path = tmp_path / "r.mcap"
    write_frames(path, "mcap", n=1)
    result = run(runner, "--set", "sources.topics.depth=/nope", str(path))
    assert_one_line_error(result, "r.mcap", "sources.topics.depth", "/nope")


def test_unsupported_encoding_in_every_frame_is_an_error_naming_it(tmp_path: Path) -> None:
    from slzcli.config import load_config
    from slzcli.errors import DatasetError
    from slzcli.sources import open_recording

    path = tmp_path / "yuv.mcap"
    f = known_frame(0)
    with RecordingWriter(path, "mcap", layout=TopicLayout()) as w:
        w.write_frame(f)
    # Rewrite with a colour encoding slz does not read.
    bad = tmp_path / "bad.mcap"
    with RecordingWriter(bad, "mcap") as w:
        _, msg = w.color_message(f.rgb, f.stamp_ns)
        msg.encoding = "yuv422"
        w.write_raw("/camera/color/image_raw", "sensor_msgs/msg/Image", msg, f.stamp_ns)
        w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
    with open_recording(bad, load_config()) as rec:
        with pytest.raises(DatasetError, match="yuv422"):
            list(rec.frames())
        assert rec.report.undecodable == 1
    with open_recording(path, load_config()) as rec:
        assert len(list(rec.frames())) == 1


def test_info_reads_stamps_only_and_accepts_the_db3_path(tmp_path: Path, runner: CliRunner) -> None:
    # An encoding slz cannot decode still counts and pairs in `slz info`: its pairing decodes no image; the depth
    # check, which decodes a few frames, says it could not read them.
    path = tmp_path / "yuv.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(3):
            f = known_frame(i)
            _, msg = w.color_message(f.rgb, f.stamp_ns)
            msg.encoding = "yuv422"
            w.write_raw(w.color_topic, "sensor_msgs/msg/Image", msg, f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(f.depth_m, f.stamp_ns), f.stamp_ns)
    result = run(runner, "--json", str(path))
    assert result.exit_code == 0 and json.loads(result.stdout)["frames"] == 3
    assert "yuv422" in json.loads(result.stdout)["depth"]["unread"]
    bag = tmp_path / "bag2"
    write_frames(bag, "ros2-sqlite", n=2)
    result = run(runner, "--json", str(bag / "bag2.db3"))
    assert result.exit_code == 0 and json.loads(result.stdout)["frames"] == 2
