"""A run's info before its first frame: from the file's own index where it accounts for every message (an MCAP's
summary and message indexes, a ROS 1 bag's index), else the full pass ``slz info`` makes; after the frames pass,
that pass's own pairing."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from sources_util import PERIOD_NS, SUFFIX, write_frames

from slzcli.config.loader import load_config
from slzcli.sources import open_recording
from slzcli.sources.messages import MessageRecording
from slzcli.sources.recording import RecordingInfo

N = 7


def _no_full_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(self: MessageRecording) -> RecordingInfo:
        raise AssertionError("the full info pass ran")
    monkeypatch.setattr(MessageRecording, "info", refuse)


def _same_info(a: RecordingInfo, b: RecordingInfo) -> None:
    assert a.streams == b.streams and a.duration_s == b.duration_s and a.choices == b.choices
    assert a.intrinsics == b.intrinsics and a.intrinsics_source == b.intrinsics_source
    assert a.frame_period_s == pytest.approx(PERIOD_NS * 1e-9)
    assert a.expected_frames == b.expected_frames == N
    assert a.warnings == b.warnings and a.camera_preset == b.camera_preset


@pytest.mark.parametrize("fmt", ["mcap", "mcap-ros1", "ros1", "ros2-sqlite", "ros2-mcap"])
def test_a_run_reads_the_index_and_learns_what_the_full_pass_does(fmt: str, tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / f"rec{SUFFIX[fmt]}"
    write_frames(path, fmt, N, **({"chunk_bytes": 4000} if fmt.startswith("mcap") else {}))  # many chunks
    config = load_config()
    with open_recording(path, config) as rec:
        full = rec.info()
    with monkeypatch.context() as m, open_recording(path, config) as rec:
        _no_full_pass(m)
        indexed = rec.run_info()
    _same_info(indexed, full)


def test_a_rosbag2_whose_storage_does_not_add_up_gets_the_full_pass(tmp_path: Path) -> None:
    """A sqlite3 rosbag2 whose messages table lost a row its metadata still counts: the times do not account
    for every message, so the full pass reads what is there."""
    import sqlite3

    path = tmp_path / "rec"
    write_frames(path, "ros2-sqlite", N)
    db = next(path.glob("*.db3"))
    con = sqlite3.connect(db)
    con.execute("DELETE FROM messages WHERE id = (SELECT MAX(id) FROM messages)")
    con.commit()
    con.close()
    with open_recording(path, load_config()) as rec:
        assert isinstance(rec, MessageRecording)
        if rec.log.log_times() is not None:   # rosbags counted the rows itself: then they add up
            pytest.skip("this rosbags counts the messages from the storage, not the metadata")
        a, b = rec.run_info(), rec.info()
    assert a.streams == b.streams and a.pairing == b.pairing


def _copy_messages(src: Path, dst: Path, chunked: bool, statistics: bool) -> None:
    """The recording's messages rewritten by mcap's own writer, in chunks or not, with statistics or not."""
    with src.open("rb") as f, dst.open("wb") as out:
        w = Writer(out, use_chunking=chunked, use_statistics=statistics)
        w.start(profile="ros2", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in make_reader(f).iter_messages():
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas.get(channel.schema_id, 0))
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time)
        w.finish()


@pytest.mark.parametrize("damage", ["cut short", "unchunked", "no statistics"])
def test_an_mcap_whose_index_does_not_account_for_every_message_gets_the_full_pass(damage: str,
                                                                                    tmp_path: Path) -> None:
    """Cut short (no summary: the recorder was killed), messages outside chunks (no message index), or no
    statistics to check the indexes against: every message is read, as before."""
    path = tmp_path / "rec.mcap"
    write_frames(path, "mcap", N, chunk_bytes=4000)
    if damage == "cut short":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) * 9 // 10])  # the summary and the last chunk's end gone
    else:
        dst = tmp_path / "copy.mcap"
        _copy_messages(path, dst, chunked=damage != "unchunked", statistics=damage != "no statistics")
        path = dst
    with open_recording(path, load_config()) as rec:
        assert isinstance(rec, MessageRecording) and rec.log.log_times() is None
        a, b = rec.run_info(), rec.info()
    assert a.streams == b.streams and a.pairing == b.pairing


def test_a_window_is_estimated_from_the_log_times_as_the_full_pass_counts_it(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "rec.mcap"
    write_frames(path, "mcap", N)
    for keys, frames in ((["sources.window.max_frames=3"], 3),
                         ([f"sources.window.start_s={1.5 * PERIOD_NS * 1e-9}"], N - 2),
                         (["sources.window.stride=2"], (N + 1) // 2)):
        config = load_config(None, keys)
        with open_recording(path, config) as rec:
            full = rec.info().expected_frames
        with monkeypatch.context() as m, open_recording(path, config) as rec:
            _no_full_pass(m)
            assert rec.run_info().expected_frames == full == frames, keys


def test_after_the_frames_pass_the_info_holds_that_pass_s_pairing(tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    write_frames(path, "mcap", N)
    with open_recording(path, load_config(None, ["sources.window.max_frames=4"])) as rec:
        info = rec.run_info()
        assert rec.after_frames(info) is info  # no pass yet: the estimate stands
        frames = list(rec.frames())
        after = rec.after_frames(info)
    assert len(frames) == 4 and after.pairing == rec.report and after.pairing.paired == 4
    assert after.pairing.outside_window == N - 4 and any("--max-frames 4" in n for n in after.pairing.notes)
    assert after.streams == info.streams


def test_a_sqlite3_bags_times_are_streamed_not_listed(tmp_path: Path) -> None:
    """The timestamp column of a rosbag2 sqlite3 file is read into one array, not a Python list of rows first (an
    hour with a 1 kHz IMU is 3.6 million rows: 535 MB traced as a list against 90 MB streamed, measured). Measured
    here: 25 bytes a row traced streamed (the array, the per-topic masks and copies), 144 as a list; the bound, 40,
    is 1.6x the first and 1/3.6 of the second."""
    import sqlite3
    import tracemalloc

    from slzcli.sources.rosbag import _sqlite_log_times

    n = 200_000
    db = tmp_path / "bag_0.db3"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT)")
    con.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER, timestamp INTEGER, data BLOB)")
    con.executemany("INSERT INTO topics VALUES (?, ?)", [(1, "/imu"), (2, "/camera/color")])
    con.executemany("INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
                    ((2 if i % 30 == 0 else 1, 10**18 + i * 10**6, b"") for i in range(n)))
    con.commit()
    con.close()
    tracemalloc.start()
    try:
        times = _sqlite_log_times(db)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert times is not None
    assert len(times["/camera/color"]) == -(-n // 30) and len(times["/imu"]) == n - -(-n // 30)
    assert times["/imu"][0] == 10**18 + 10**6 and times["/camera/color"][-1] == 10**18 + (n - 1) // 30 * 30 * 10**6
    assert peak < 40 * n, f"{peak / n:.0f} bytes a row"
