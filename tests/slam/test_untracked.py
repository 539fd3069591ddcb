"""SLAM honesty: every backend's frames without a pose are counted in run.json and the summary line, with a warning
above slam.max_untracked_share."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import synth_recording
from sources_util import PERIOD_NS, known_frame, pose, realsense_bag

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.outputs.recording import RecordingWriter
from slzcli.records import UntrackedRecord
from slzcli.slam.orbslam3 import available as orbslam3_available
from slzcli.summary import untracked_frames

MAX_SHARE = load_config().slam.max_untracked_share
needs_orbslam3 = pytest.mark.skipif(not orbslam3_available(),
                                    reason="optional pyorbslam3 (slz[orbslam3]) not installed")


def detect(runner: CliRunner, rec: Path, out: Path, *sets: str) -> tuple[Any, dict[str, Any]]:
    args = ["detect", str(rec), "-o", str(out), "--outputs", "summary"]
    for s in sets:
        args += ["--set", s]
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    return res, json.loads((out / "run.json").read_text())["summary"]


def test_untracked_share_and_its_warning() -> None:
    assert untracked_frames(np.ones(10, bool), {"ok": 10}, "odometry", 0.1) == UntrackedRecord(0, 0.0, "")
    one = untracked_frames(np.r_[False, np.ones(9, bool)], {"ok": 9, "initialising": 1}, "odometry", 0.1)
    assert one.frames_untracked == 1 and one.warning == ""          # 10 %: at the limit, not above
    two = untracked_frames(np.r_[False, False, np.ones(8, bool)], {"ok": 8, "lost": 2}, "orbslam3", 0.1)
    assert two.untracked_share == 0.2
    assert "orbslam3 could not track 2 of 10 frames (20%: 2 lost)" in two.warning
    assert "slam.max_untracked_share 10%" in two.warning
    assert untracked_frames(np.zeros(0, bool), {}, "odometry", 0.1).warning == ""


def test_odometry_on_the_real_hand_held_frames_says_it_lost_seven(realsense_dir: Path, tmp_path: Path,
                                                                 runner: CliRunner) -> None:
    bag = realsense_bag(realsense_dir, tmp_path / "rs.bag")
    res, s = detect(runner, bag, tmp_path / "run", "slam.backend=odometry")
    # the odometry is deterministic: measured 3 tracked, 7 lost (the camera moves ~0.3 m and turns between frames)
    assert s["tracking"] == {"ok": 3, "lost": 7}
    assert s["slam"]["frames_untracked"] == 7 and s["slam"]["untracked_share"] == 0.7
    assert "odometry could not track 7 of 10 frames (70%: 7 lost)" in res.stderr
    assert "10 frames (7 not tracked)" in res.stdout
    res, s = detect(runner, bag, tmp_path / "run2", "slam.backend=odometry", "slam.max_untracked_share=0.8")
    assert s["slam"]["frames_untracked"] == 7 and "could not track" not in res.stderr and s["slam"]["warning"] == ""


def test_the_recorded_backend_counts_the_frames_without_a_recorded_pose(tmp_path: Path, runner: CliRunner) -> None:
    bag = tmp_path / "posed.mcap"
    with RecordingWriter(bag, "mcap") as w:
        for i in range(8):
            f = known_frame(i, 120, 160)
            w.write_frame(f)
            if i < 5:   # frame 5 takes frame 4's pose (33 ms < sources.pose_tolerance_ms 50), 6 and 7 have none
                w.write_pose("/camera/pose", f.stamp_ns, pose(i))
    assert load_config().sources.pose_tolerance_ms < 2 * PERIOD_NS / 1e6
    res, s = detect(runner, bag, tmp_path / "run")
    assert s["slam_backend"] == "recorded" and s["tracking"] == {"ok": 6, "lost": 2}
    assert s["slam"]["frames_untracked"] == 2 and "recorded could not track 2 of 8 frames (25%: 2 lost)" in res.stderr


@needs_orbslam3
def test_orbslam3_rgbd_on_frames_without_texture_tracks_none_and_says_so(tmp_path: Path, runner: CliRunner) -> None:
    bag = tmp_path / "blank.mcap"
    with RecordingWriter(bag, "mcap") as w:
        for i in range(6):   # uniform grey at 3 m: no ORB feature, so no map can start (deterministic)
            f = known_frame(i, 120, 160)
            w.write_frame(type(f)(i, f.stamp_ns, np.full_like(f.rgb, 128), np.full_like(f.depth_m, 3.0),
                                  f.intrinsics))
    res, s = detect(runner, bag, tmp_path / "run", "slam.backend=orbslam3")
    assert s["slam"]["frames_untracked"] == 6 and s["slam"]["untracked_share"] == 1.0
    assert "orbslam3 could not track 6 of 6 frames" in res.stderr


@needs_orbslam3
def test_orbslam3_counts_agree_with_its_tracking_states_on_the_real_frames(realsense_dir: Path, tmp_path: Path,
                                                                          runner: CliRunner) -> None:
    bag = realsense_bag(realsense_dir, tmp_path / "rs.bag")
    res, s = detect(runner, bag, tmp_path / "run", "slam.backend=orbslam3")
    # ORB-SLAM3's threads make the split vary from run to run; every frame without a pose is counted either way
    tracked = sum(seg["frames_tracked"] for seg in s["slam"]["segments"])
    assert s["slam"]["frames_untracked"] == s["frames"] - tracked == s["frames"] - s["tracking"].get("ok", 0)
    assert (s["slam"]["untracked_share"] > MAX_SHARE) == bool(s["slam"]["warning"]) == ("could not track" in res.stderr)


@needs_orbslam3
def test_monocular_orbslam3_on_a_hover_counts_every_frame_untracked(runner: CliRunner, tmp_path: Path) -> None:
    hover = synth_recording(tmp_path / "hover.mcap", "clear_field", 6, "--set", "synth.sensor.model=gaussian",
                            "--start", "0,0,5")
    # 6 frames of a hover: no parallax, a monocular map cannot start (test_monocular.py measured it)
    res, s = detect(runner, hover, tmp_path / "run", "slam.backend=orbslam3", "slam.orbslam3.sensor=monocular")
    assert s["slam"]["frames_untracked"] == 6 and "could not track 6 of 6 frames" in res.stderr
