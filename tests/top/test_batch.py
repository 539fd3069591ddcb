"""Many recordings (issue 9): local pool vs Dask, kill and resume, results.mcap, batch summary."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN

from slzcli import batch
from slzcli.cli import main
from slzcli.errors import ConfigError, OutputError
from slzcli.outputs import run_lock
from slzcli.records import BatchSettings, BatchTotals

FRAMES = 4
SCENES = ("clear_field", "no_site", "parking_lot")  # sorted: the order a glob gives them
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("flights")
    runner = CliRunner()
    for scene in SCENES:
        res = runner.invoke(main, ["synth", scene, "-o", str(folder / f"{scene}.mcap"), "--frames", str(FRAMES),
                                   *GAUSSIAN])
        assert res.exit_code == 0, res.output
    return folder


@pytest.fixture(scope="module")
def local_run(flights, tmp_path_factory) -> tuple[Path, dict, str]:
    """The reference: the three recordings on a local pool of two workers (quoted glob pattern)."""
    out = tmp_path_factory.mktemp("local") / "runs"
    res = CliRunner().invoke(main, ["detect", str(flights / "*.mcap"), "-o", str(out), "--workers", "2", "--json"])
    assert res.exit_code == 0, res.output
    return out, json.loads(res.stdout), res.stderr


def landing(run: Path) -> dict:
    """landing.json without its timings (the part that must not depend on where it ran)."""
    rec = json.loads((run / "landing.json").read_text())
    rec.pop("timings_ms")
    return rec


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "slzcli.cli", *args]


# ----------------------------------------------------------------------------- local pool and Dask
def test_local_pool_batch_writes_a_run_per_recording_and_the_summary(local_run) -> None:
    out, summary, stderr = local_run
    totals = summary["batch"]
    assert (totals["engine"], totals["workers"], totals["recordings"], totals["processed"]) == ("local", 2, 3, 3)
    assert totals["frames"] == 3 * FRAMES and totals["failed"] == 0 and totals["frames_per_s"] > 0
    assert [Path(r["run"]).name for r in summary["runs"]] == list(SCENES)
    for scene in SCENES:
        assert (out / scene / "landing.json").is_file() and (out / scene / "results.mcap").is_file()
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["site", "no_safe_site", "site"]
    assert all(float(r["wall_s"]) > 0 and float(r["peak_rss_mb"]) > 0 and r["worker"] for r in rows)
    assert rows[0]["site_x"] and not rows[1]["site_x"]
    batch_json = json.loads((out / "summary.json").read_text())
    assert batch_json["batch"]["config_hash"] and len(batch_json["recordings"]) == 3
    # the batch object is the records' fields in their order (the file's contract), then the earlier rows
    names = [f.name for f in fields(BatchTotals)]
    assert list(batch_json["batch"]) == [*names, *(f.name for f in fields(BatchSettings)), "earlier_rows"]
    assert list(totals) == [*names, "summary_files"]  # --json
    progress = [ln for ln in stderr.splitlines() if ln.startswith("slz: [")]
    assert len(progress) == 3 and progress[-1].startswith("slz: [3/3]") and "frames/s" in progress[-1]
    assert leftovers(out) == []


def test_dask_local_cluster_gives_the_same_results(local_run, flights, tmp_path) -> None:
    distributed = pytest.importorskip("distributed", reason="dask[distributed] not installed (pip install 'slz[dask]')")
    ref, _, _ = local_run
    out = tmp_path / "runs"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = CliRunner().invoke(main, ["detect", str(flights / "*.mcap"), "-o", str(out),
                                        "--scheduler", cluster.scheduler_address, "--json"])
    assert res.exit_code == 0, res.output
    totals = json.loads(res.stdout)["batch"]
    assert totals["engine"] == "dask" and totals["processed"] == 3 and totals["frames"] == 3 * FRAMES
    for scene in SCENES:
        assert landing(out / scene) == landing(ref / scene), scene


def test_unreachable_scheduler_is_one_line_naming_the_option(flights, tmp_path) -> None:
    pytest.importorskip("distributed")
    res = CliRunner().invoke(main, ["detect", str(flights / "*.mcap"), "-o", str(tmp_path / "r"),
                                    "--scheduler", "nosuchproto://nowhere:1"])
    assert res.exit_code == 1 and "Traceback" not in res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "--scheduler" in lines[0] and "nosuchproto://nowhere:1" in lines[0]


# ----------------------------------------------------------------------------- kill, resume
def test_killed_batch_reruns_only_what_is_missing(local_run, flights, tmp_path) -> None:
    ref, _, _ = local_run
    out = tmp_path / "runs"
    recordings = [str(flights / f"{s}.mcap") for s in SCENES]
    proc = subprocess.Popen(cli("detect", *recordings, "-o", str(out), "--workers", "1"), cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not ((out / SCENES[0] / "run.json").is_file() and list(out.glob(f".{SCENES[1]}.*.partial"))):
            assert proc.poll() is None and time.monotonic() < deadline, "the batch ended before it could be killed"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole session: no process gets to clean up
        proc.wait()
    assert list(out.glob(f".{SCENES[1]}.*.partial")), "the kill left no half-written run (test premise)"
    assert not (out / SCENES[1]).exists()

    res = CliRunner().invoke(main, ["detect", *recordings, "-o", str(out), "--workers", "2", "--json"])
    assert res.exit_code == 0, res.output
    skipped = {Path(r["run"]).name: r["skipped"] for r in json.loads(res.stdout)["runs"]}
    assert skipped == {SCENES[0]: True, SCENES[1]: False, SCENES[2]: False}
    assert leftovers(out) == []  # the stale partial folder and lock are gone
    for scene in SCENES:
        assert landing(out / scene) == landing(ref / scene), scene


def test_sigterm_stops_the_pool_and_leaves_no_temporary_folder(flights, tmp_path) -> None:
    out = tmp_path / "runs"
    proc = subprocess.Popen(cli("detect", str(flights / "*.mcap"), "-o", str(out), "--workers", "2"), cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob(".*.partial")):
            assert proc.poll() is None and time.monotonic() < deadline, "the batch ended before it could be stopped"
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and "interrupted" in err.decode()
    assert leftovers(out) == []
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert "interrupted" in {r["status"] for r in rows}
    for r in rows:  # whatever is marked done is complete
        assert r["status"] == "interrupted" or (Path(r["run"]) / "run.json").is_file()


# ----------------------------------------------------------------------------- results.mcap
def test_results_mcap_reads_back_with_expected_topics_and_the_score_image(local_run) -> None:
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    run = local_run[0] / "clear_field"
    summary = json.loads((run / "run.json").read_text())["summary"]
    detections, tracked = summary["detections"], summary["tracking"].get("ok", 0)
    store = get_typestore(Stores.ROS2_HUMBLE)
    msgs: dict[str, list] = {}
    with (run / "results.mcap").open("rb") as fh:
        reader = make_reader(fh)
        info = reader.get_summary()
        assert info is not None
        schemas = {ch.topic: info.schemas[ch.schema_id].name for ch in info.channels.values()}
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            msgs.setdefault(channel.topic, []).append(store.deserialize_cdr(message.data, schema.name))
        in_file = [m.log_time for _, c, m in reader.iter_messages(log_time_order=False)
                   if c.topic != "/slz/landing_site"]
    # written as tracked; only the committed site (on its frame's stamp) comes last
    assert in_file == sorted(in_file)
    map_names = ("depth_variance", "flatness", "inclination", "steepness")
    for topic in ["/slz/score", *(f"/slz/maps/{n}" for n in map_names)]:  # values: raw mono8
        assert schemas[topic] == "sensor_msgs/msg/Image" and len(msgs[topic]) == detections, topic
    for topic in ("/slz/color/compressed", "/slz/overlay/compressed"):  # pictures: JPEG
        assert schemas[topic] == "sensor_msgs/msg/CompressedImage" and len(msgs[topic]) == detections, topic
    for topic in ("/slz/mask", "/slz/map_points", "/slz/candidates"):
        assert schemas[topic] == "sensor_msgs/msg/PointCloud2", topic
    assert schemas["/slz/site"] == schemas["/slz/landing_site"] == "visualization_msgs/msg/MarkerArray"
    assert schemas["/slz/camera_pose"] == "geometry_msgs/msg/PoseStamped"
    assert schemas["/tf"] == "tf2_msgs/msg/TFMessage"
    assert len(msgs["/slz/camera_pose"]) == len(msgs["/tf"]) == tracked == FRAMES

    # Every score image is round(255 * score) of that detection's maps.npz, on the frame's own stamp.
    stamps_s = [float(ln.split()[0]) for ln in (run / "trajectory.tum").read_text().splitlines()
                if ln and not ln.startswith("#")]
    folders = sorted((run / "frames").iterdir())
    assert len(folders) == detections
    for folder, img in zip(folders, msgs["/slz/score"], strict=True):
        score = np.load(folder / "maps.npz")["score"]
        assert img.encoding == "mono8" and (img.height, img.width) == score.shape
        decoded = img.data.reshape(img.height, img.width)
        assert np.array_equal(decoded, np.rint(np.clip(np.nan_to_num(score), 0, 1) * 255).astype(np.uint8))
        stamp = img.header.stamp.sec * 10**9 + img.header.stamp.nanosec
        assert abs(stamp * 1e-9 - stamps_s[int(folder.name)]) < 1e-5  # trajectory.tum keeps microseconds

    # The committed site: the Eq. 10 square as a closed line strip on landing.json's corners.
    site = json.loads((run / "landing.json").read_text())["site"]
    (markers,) = msgs["/slz/landing_site"]
    strip = next(m for m in markers.markers if m.type == 4)
    corners = np.array([[p.x, p.y, p.z] for p in strip.points])
    assert np.allclose(corners[[0, 1, 3, 2]], site["corners_world"]) and np.allclose(corners[0], corners[-1])
    # Candidates carry the k-means label as a fourth float32 field.
    cand = msgs["/slz/candidates"][-1]
    assert [f.name for f in cand.fields] == ["x", "y", "z", "cluster"] and cand.point_step == 16
    pts = cand.data.view("<f4").reshape(-1, 4)
    assert len(pts) == cand.width and np.all(np.isfinite(pts[:, :3]))


def test_results_mcap_can_be_switched_off(flights, tmp_path) -> None:
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["detect", str(flights / "clear_field.mcap"), "-o", str(out),
                                    "--set", "output.results_mcap=false", "--outputs", "summary"])
    assert res.exit_code == 0, res.output
    assert (out / "landing.json").is_file() and not (out / "results.mcap").exists()
    assert not (tmp_path / "summary.csv").exists()  # one recording named alone: no batch summary


# ----------------------------------------------------------------------------- inputs, failures, locks
def test_patterns_expand_sorted_without_repeats_and_names_stay_unique(tmp_path) -> None:
    for rel in ("a/x.mcap", "a/y.bag", "b/x.mcap"):
        (tmp_path / rel).parent.mkdir(exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    found = batch.expand([str(tmp_path / "*" / "*.mcap"), str(tmp_path / "a" / "x.mcap"), str(tmp_path / "a/y.bag")])
    assert found == [tmp_path / "a/x.mcap", tmp_path / "b/x.mcap", tmp_path / "a/y.bag"]
    tasks = batch.plan(found, tmp_path / "out", batch=True)
    assert [t.run_dir.name for t in tasks] == ["a_x", "b_x", "y"]
    assert all(t.recording.is_absolute() and t.run_dir.is_absolute() for t in tasks)
    with pytest.raises(ConfigError, match="share the run folder"):
        batch.plan([tmp_path / "a/x.mcap", tmp_path / "a/x.bag", tmp_path / "c/a/x.mcap"], None, batch=True)


def test_pattern_matching_nothing_is_one_line_exit_1(runner, tmp_path) -> None:
    res = runner.invoke(main, ["detect", str(tmp_path / "*.mcap"), "-o", str(tmp_path / "runs")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "*.mcap" in lines[0] and "no recording matches" in lines[0]


def test_failed_recordings_are_rows_and_exit_1_naming_the_summary(runner, tmp_path) -> None:
    for name in ("empty.mcap", "garbage.mcap"):
        (tmp_path / name).write_bytes(b"" if name == "empty.mcap" else b"\x00garbage" * 100)
    out = tmp_path / "runs"
    res = runner.invoke(main, ["detect", str(tmp_path / "empty.mcap"), str(tmp_path / "garbage.mcap"),
                               "-o", str(out), "--workers", "1"])
    assert res.exit_code == 1 and "Traceback" not in res.output
    error = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: error:")]
    assert len(error) == 1 and "2 of 2 recordings failed" in error[0] and "summary.csv" in error[0]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["failed", "failed"] and "empty.mcap" in rows[0]["error"]
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv", "summary.json"]  # no run, no temporary


def test_run_lock_refuses_a_second_writer_and_removes_stale_partials(tmp_path) -> None:
    from slzcli.outputs.safe_output import make_temp_dir

    run = tmp_path / "flight"
    stale = make_temp_dir(run, ".partial")  # marked as slz's the moment it was made
    (stale / "frames").mkdir(parents=True)
    other = make_temp_dir(tmp_path / "flight2", ".partial")
    users = tmp_path / ".flight.mine.partial"  # a user's folder with such a name: no marker
    users.mkdir()
    with run_lock.claim(run) as removed:
        assert removed == [stale] and not stale.exists() and other.exists() and users.exists()
        with pytest.raises(OutputError, match="another slz process"), run_lock.claim(run):
            pass
    # the lock file is gone, the other run and the user's folder untouched
    assert leftovers(tmp_path) == sorted([other.name, users.name])
    with run_lock.claim(run) as removed:  # free again
        assert removed == []
