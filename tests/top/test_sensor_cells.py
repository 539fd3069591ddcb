"""Cells of the sensor x altitude matrix (benchmarks/sensor_matrix.py) held end to end through the CLI.

Each cell: `slz synth SCENE --start x,y,Z` with a depth sensor, then `slz detect` (SLAM as the user
runs it, a detection on frames 0 and 2 of 3), scored against the synth ground truth. Every limit below
was measured over seeds 0-4 (the numbers in the comments); the suite runs seeds 0-2.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from slzcli.cli import main

# Three frames: the detections are on frames 0 and 2, the pipeline is causal and the renders are prefix-stable
# (flight and noise drawn frame by frame), so a fourth frame, tracked after the last detection, changed none of
# the numbers asserted below (measured, 3 vs 4 frames, seed 0 D435 at 5 m, seed 1 D455 at 5 m, seed 0 gaussian
# 0.003 at 10 m: identical status, precision, recall, site, depth limits and noise estimate; only the SLAM
# ATE and the frame counts differ). It cost a quarter of each cell's render (D435: 22.1 -> 15.4 CPU s).
FRAMES = "3"
DETECT = ["--set", "landing.detect_on=every_nth", "--set", "landing.every_nth_frame=2"]
GAUSS = {"gauss0.003": ["--set", "synth.sensor.model=gaussian", "--set", "synth.sensor.depth_sigma_a=0.003"]}
D435 = ["--set", "synth.sensor.model=stereo", "--set", "synth.sensor.preset=d435"]   # the default sensor
D455 = ["--set", "synth.sensor.model=stereo", "--set", "synth.sensor.preset=d455"]
SEEDS = [0, 1, 2]


def detect_cell(runner, tmp: Path, scene: str, start: str, sensor: list[str], seed: int) -> dict:
    rec = tmp / f"{scene}.mcap"
    res = runner.invoke(main, ["synth", scene, "-o", str(rec), "--frames", FRAMES, "--start", start,
                               "--seed", str(seed), *sensor])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp / "run"), "--json", *DETECT])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    summary["landing"] = json.loads((tmp / "run" / "landing.json").read_text())
    return summary


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("altitude", ["10", "4"])
def test_parking_lot_under_heavy_gaussian_noise_gives_a_truly_safe_site(runner, tmp_path: Path, seed: int,
                                                                         altitude: str) -> None:
    """sigma = 0.003 z^2 (0.3 m at 10 m, 8x slz synth's old sensor). At 10 m a map-point cluster's level carries
    0.3 m of point noise: the raised-surface rule's margin (0.34-0.50 m on seeds 0-1) hides the 0.09 m
    tolerance, and the run says so rather than land (METHOD 2.5.1 step 4); from 4 m the site is committed."""
    s = detect_cell(runner, tmp_path, "parking_lot", f"0,0,{altitude}", GAUSS["gauss0.003"], seed)
    if altitude == "10" and s["status"] != "site":
        assert s["status"] == "no_safe_site" and "not told from one higher than" in s["reason"], s["reason"]
        return
    assert s["status"] == "site", s["reason"]
    gt = s["ground_truth"]
    # measured over seeds 0-4: precision 1.00 at 10 m and at 4 m, recall 0.39-0.41 and 0.27-0.28; every site
    # truly safe (limit 0.95); the smallest detectable step 0.063-0.065 m at 10 m (tolerated: 0.09)
    assert gt["mask"]["precision"] >= 0.95
    assert gt["site"]["safe"] is True
    lim = s["landing"]["site"]["depth_limits"]
    assert lim["vouched"] and lim["step_min_m"] <= 0.09
    # the estimate is the sensor's a = 0.003 (measured 0.00300-0.00301 on every seed; limit 5 %)
    assert s["depth_noise"]["a_per_m_median"] == pytest.approx(0.003, rel=0.05)


@pytest.mark.parametrize("seed", SEEDS)
def test_parking_lot_seen_by_a_d435_at_5_m_gives_a_truly_safe_site(runner, tmp_path: Path, seed: int) -> None:
    """The stereo model's D435 (noise 0.7-1.1x Intel's figure, correlated over ~3.5 px) at 5 m."""
    s = detect_cell(runner, tmp_path, "parking_lot", "0,0,5", D435, seed)
    assert s["status"] == "site", s["reason"]
    gt = s["ground_truth"]
    # measured over seeds 0-4: precision 1.00, recall 0.23-0.27, every site truly safe (limit 0.95); estimated
    # a 0.0019 (the pixel band; the sensor's total per-pixel error is ~0.004 z^2, correlated over ~3.5 px)
    assert gt["mask"]["precision"] >= 0.95
    assert gt["site"]["safe"] is True


@pytest.mark.parametrize("seed", SEEDS)
def test_parking_lot_seen_by_a_d455_at_5_m_gives_a_truly_safe_site(runner, tmp_path: Path, seed: int) -> None:
    """The D455's error is small enough that the maps run at full resolution, where its correlated error and
    sub-pixel steps are not white: Canny's scaling follows their measured spread (before: 17 % of open ground
    were edges, recall 0.00, no site)."""
    s = detect_cell(runner, tmp_path, "parking_lot", "0,0,5", D455, seed)
    assert s["status"] == "site", s["reason"]
    gt = s["ground_truth"]
    # measured over seeds 0-4: precision 1.00, recall 0.153-0.175, every site truly safe with clearance
    # 1.44-2.06 m (limits: precision 0.95, recall 0.08 = half the worst)
    assert gt["mask"]["precision"] >= 0.95
    assert gt["mask"]["recall"] >= 0.08
    assert gt["site"]["safe"] is True


@pytest.mark.parametrize("seed", SEEDS)
def test_d435_at_10_m_is_an_honest_no(runner, tmp_path: Path, seed: int) -> None:
    """At 10 m a D435's correlated error hides steps the UAV cannot tolerate: no site, and why (measured over
    seeds 0-4: no site every time, steps below 0.29-0.34 m hidden)."""
    s = detect_cell(runner, tmp_path, "parking_lot", "0,0,10", D435, seed)
    assert s["status"] == "no_safe_site"
    assert "hides steps below" in s["landing"]["reason"] and "it would not" in s["landing"]["reason"]


@pytest.mark.parametrize("seed", SEEDS)
def test_no_site_scene_gives_no_site_under_noise(runner, tmp_path: Path, seed: int) -> None:
    s = detect_cell(runner, tmp_path, "no_site", "0,0,10", GAUSS["gauss0.003"], seed)
    assert s["status"] == "no_safe_site"
    assert s["landing"]["status"] == "no_safe_site" and s["landing"]["reason"]


def test_noise_the_uav_cannot_see_through_is_an_honest_no(runner, tmp_path: Path) -> None:
    """sigma = 0.006 z^2 (0.6 m at 10 m): the limits say what is hidden and where it would not be."""
    s = detect_cell(runner, tmp_path, "parking_lot", "0,0,10", ["--set", "synth.sensor.model=gaussian", "--set",
                                                                 "synth.sensor.depth_sigma_a=0.006"], 0)
    assert s["status"] == "no_safe_site"
    reason = s["landing"]["reason"]
    assert reason.startswith("at 9.") and "the depth noise (sigma ~ 0.5" in reason
    assert "hides steps below" in reason and "it would not" in reason
    assert s["depth_noise"]["detections_not_vouched"] == s["detections"]
    assert s["ground_truth"]["mask"]["precision"] is None     # nothing was called safe
