"""Through the CLI, a camera pitched 30 degrees on the vehicle (nothing in the recording says so but its IMU):
over a 1.5 m box on level ground both paths (the default and ``--method fused``) land on level ground beside it,
truly safe, never on the box; hovering over a 1.8 m box on rocky ground (its top the only flat surface) both find
no site and the per-frame path says the best one is raised; the straight-down ``camera.mount`` forced on the
tilted recording is refused (the IMU contradicts it), naming the key."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, HALF_SIZE

from slzcli.cli import main
from slzcli.synth.scenes import SCENES_DIR

BOX = """description: "A 3.4 x 3.0 m concrete box 1.5 m high on level dirt ground."
ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}
objects:
  - {name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, 1.5], material: concrete}
"""
ROCKS = """description: "A 3.4 x 3.0 m concrete box 1.8 m high on ground strewn with rocks."
ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}
objects:
  - {name: rock, kind: box, at_m: [-8.0, -10.0], size_m: [0.35, 0.35, 0.3], material: rock,
     repeat: {count: [21, 26], pitch_m: [0.8, 0.8]}}
  - {name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, 1.8], material: concrete}
"""
# 20 frames at 10 Hz, 1 m/s north from 5.5 m: the view's centre (5.5 tan 30 = 3.2 m ahead) crosses the box
FLIGHT = ("--frames", "20", "--rate", "10", "--path", "transect", "--start", "0,-4.125,5.5",
          "--set", "synth.flight.speed_m_s=1.0", "--set", "synth.flight.mount_pitch_deg=30",
          "--set", "synth.imu.enabled=true", *GAUSSIAN, *HALF_SIZE)
# hovering 10 frames where the view's centre meets the box top ((5.5 - 1.8) tan 30 = 2.1 m ahead)
HOVER = ("--frames", "10", "--path", "hover", "--start", "0,-2.1,5.5", "--set", "synth.flight.mount_pitch_deg=30",
         "--set", "synth.imu.enabled=true", *GAUSSIAN, *HALF_SIZE)
DETECT = ("--json", "--set", "slam.backend=odometry", *HALF_SIZE)


def _recording(folder: Path, name: str, text: str, flight: tuple[str, ...] = FLIGHT) -> Path:
    scene = folder / f"{name}.yaml"
    scene.write_text(text)
    shutil.copy(SCENES_DIR / "_common.yaml", folder / "_common.yaml")   # the shared materials
    rec = folder / f"{name}.mcap"
    res = CliRunner().invoke(main, ["synth", str(scene), "-o", str(rec), "--seed", "0", *flight])
    assert res.exit_code == 0, res.output
    return rec


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    return _recording(tmp_path_factory.mktemp("tilt_box"), "box", BOX)


@pytest.fixture(scope="module")
def rocks(tmp_path_factory) -> Path:
    return _recording(tmp_path_factory.mktemp("tilt_rocks"), "rocks", ROCKS, HOVER)


def _on_box(xy: list[float], half: tuple[float, float] = (1.7, 1.5)) -> bool:
    return abs(xy[0]) <= half[0] and abs(xy[1]) <= half[1]


@pytest.mark.parametrize("method", ["fuzzy", "fused"])
def test_a_pitched_camera_lands_beside_a_box_on_level_ground(tmp_path: Path, runner, box: Path, method: str) -> None:
    rec = box
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "out"), "--method", method, *DETECT])
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    assert s["gravity"]["source"] == "imu" and abs(s["gravity"]["tilt_deg"] - 30.0) < 3.0, s["gravity"]
    assert s["status"] == "site", s["reason"]
    site = s["ground_truth"]["site"]
    assert site["safe"] is True and not _on_box(site["true_xy"]), site
    # the straight-down mount forced on it: the IMU contradicts it, exit 1 naming the key, nothing left
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "wrong"), "--method", method, *DETECT,
                               "--set", "camera.gravity.source=mount"])
    assert res.exit_code == 1
    err = json.loads(res.stdout)["error"]["message"]
    assert "camera.gravity.source mount" in err and "IMU" in err and "camera.gravity.source auto" in err, err
    assert not (tmp_path / "wrong").exists()


@pytest.mark.parametrize("method", ["fuzzy", "fused"])
def test_a_pitched_camera_refuses_a_raised_box_top(tmp_path: Path, runner, rocks: Path, method: str) -> None:
    rec = rocks
    res = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "out"), "--method", method, *DETECT,
                               "--set", "landing.kmeans_k=1"])    # the top as one cluster (per frame)
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    assert s["status"] == "no_safe_site", s
    if method == "fuzzy":   # the top reaches the rule (the fused verdict does not call it safe: nothing to refuse)
        assert re.match(r"the best site is on a surface 1\.[3-9] m above the ground around it", s["reason"]), \
            s["reason"]
