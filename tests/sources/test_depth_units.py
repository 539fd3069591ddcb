"""Depth units: camera.yaml's depth_scale, its unknown keys refused, and slz info's depth range and warning."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from sources_util import realsense_bag, realsense_intrinsics
from test_sources_tum import make_tum

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.sources.depth_check import depth_range, implausible

CFG = load_config().sources.depth_check
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333


def realsense_tum(root: Path, out: Path, extra_yaml: str = "") -> Path:
    """The real frames as a TUM folder the way RealSense tools write one: millimetre PNGs, as they are."""
    (out / "rgb").mkdir(parents=True)
    (out / "depth").mkdir()
    k = realsense_intrinsics(root)
    rgb, depth = [], []
    for i, f in enumerate(sorted((root / "color").glob("*.png"))):
        t = (T0_NS + i * PERIOD_NS) * 1e-9
        shutil.copy(f, out / "rgb" / f.name)
        shutil.copy(root / "depth" / f.name, out / "depth" / f.name)
        rgb.append(f"{t:.6f} rgb/{f.name}")
        depth.append(f"{t:.6f} depth/{f.name}")
    (out / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (out / "depth.txt").write_text("\n".join(depth) + "\n")
    (out / "camera.yaml").write_text(f"fx: {k.fx}\nfy: {k.fy}\ncx: {k.cx}\ncy: {k.cy}\nwidth: {k.width}\n"
                                     f"height: {k.height}\n{extra_yaml}")
    return out


def detect_noise(runner: CliRunner, rec: Path, out: Path) -> dict:
    res = runner.invoke(main, ["detect", str(rec), "-o", str(out), "--json", "--set", "slam.backend=odometry"])
    assert res.exit_code == 0, res.stderr
    return json.loads(res.stdout)["depth_noise"]


def test_real_frames_give_one_noise_estimate_as_a_bag_and_as_a_tum_folder_with_depth_scale(
        realsense_dir: Path, tmp_path: Path, runner: CliRunner) -> None:
    bag = detect_noise(runner, realsense_bag(realsense_dir, tmp_path / "rs.bag"), tmp_path / "run_bag")
    tum = detect_noise(runner, realsense_tum(realsense_dir, tmp_path / "rs_mm", "depth_scale: 1000\n"),
                       tmp_path / "run_tum")
    assert bag["source"] == tum["source"] == "estimated" and bag["frames_estimated"] > 0
    # the same millimetre counts, decoded at the same unit: the same estimate at every block scale (float32 only)
    for scale, a in bag["a_per_m_by_block_px"].items():
        assert tum["a_per_m_by_block_px"][scale] == pytest.approx(a, rel=1e-6)
    # without depth_scale the benchmark's 5000 per metre puts every depth at 1/5: a = sigma / z^2 grows 5x
    wrong = detect_noise(runner, realsense_tum(realsense_dir, tmp_path / "rs_5000"), tmp_path / "run_5000")
    assert wrong["a_per_m_median"] == pytest.approx(5 * bag["a_per_m_median"], rel=1e-3)


def test_info_warns_of_millimetre_pngs_read_at_5000_per_metre_and_not_when_told(
        realsense_dir: Path, tmp_path: Path, runner: CliRunner) -> None:
    wrong = realsense_tum(realsense_dir, tmp_path / "mm")
    res = runner.invoke(main, ["info", str(wrong)])
    assert res.exit_code == 0, res.stderr
    assert "nearer than the camera's minimum range" in res.stderr and "depth_scale" in res.stderr
    assert "5000 counts per metre (sources.tum_depth_scale)" in res.stdout
    right = realsense_tum(realsense_dir, tmp_path / "mm1000", "depth_scale: 1000\n")
    res = runner.invoke(main, ["info", "--json", str(right)])
    # no depth warning (the hand-held camera's tilt is warned of by the gravity resolver, which is not tested here)
    depth_warnings = [w for w in res.stderr.splitlines() if "WARNING" in w and "gravity" not in w]
    assert res.exit_code == 0 and not depth_warnings, res.stderr
    depth = json.loads(res.stdout)["depth"]
    # measured on the 10 frames (5 read): p5 0.37 m, p50 1.02 m, p95 2.82 m, 96 % valid, 1 % nearer than 0.28 m
    assert 0.8 < depth["percentiles_m"]["p50"] < 1.3 and depth["valid_share"] > 0.85
    assert depth["frames"] == CFG.frames and depth["warning"] == ""
    assert json.loads(res.stdout)["streams"]["depth"]["reason"].startswith("TUM depth list, 1000 counts per metre")


@pytest.mark.parametrize(("yaml_line", "named"), [
    ("depth_scal: 1000\n", "'depth_scal'"),              # a misspelt key
    ("DepthMapFactor: 1000\n", "'DepthMapFactor'"),      # ORB-SLAM's name is not this file's
    ("depth_scale: 0\n", "depth_scale 0"),
    ("depth_scale: -1000\n", "depth_scale -1000"),
    ("depth_scale: .nan\n", "depth_scale nan"),
    ("depth_scale: mm\n", "depth_scale 'mm' is not a number"),
])
def test_bad_camera_yaml_is_exit_1_naming_the_key(tmp_path: Path, runner: CliRunner, yaml_line: str,
                                                  named: str) -> None:
    make_tum(tmp_path / "seq", camera_yaml=True)
    with (tmp_path / "seq" / "camera.yaml").open("a") as f:
        f.write(yaml_line)
    for cmd in (["info"], ["detect", "-o", str(tmp_path / "run"), "--set", "slam.backend=odometry"]):
        res = runner.invoke(main, [cmd[0], str(tmp_path / "seq"), *cmd[1:]])
        assert res.exit_code == 1, res.output
        assert "camera.yaml" in res.stderr and named in res.stderr and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()   # nothing partial left


def test_depth_scale_changes_the_decoded_depth_exactly(tmp_path: Path) -> None:
    from slzcli.sources import open_recording

    written = make_tum(tmp_path / "seq", camera_yaml=True)   # counts at 5000 per metre
    with (tmp_path / "seq" / "camera.yaml").open("a") as f:
        f.write("depth_scale: 1000\n")
    with open_recording(tmp_path / "seq", load_config()) as rec:
        frames = list(rec.frames())
    for got, (_, counts) in zip(frames, written, strict=True):
        ok = counts > 0
        np.testing.assert_array_equal(got.depth_m[ok], counts[ok].astype(np.float32) / np.float32(1000))


def test_depth_range_and_when_it_is_implausible() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 2.0, (120, 160)).astype(np.float32)
    depth[:, :40] = np.nan   # a quarter without data
    r = depth_range([depth, depth], "d", 0.28, "test")
    assert r.frames == 2 and r.valid_share == pytest.approx(0.75, abs=0.01)
    assert r.percentiles_m[1] == pytest.approx(1.25, abs=0.1) and r.below_min_share == 0.0
    assert implausible(r, CFG, "hint") == ""
    fifth = depth_range([depth / 5], "d", 0.28, "test")           # 0.1-0.4 m: 1/5 of the truth
    assert fifth.below_min_share > CFG.below_min_share
    assert "minimum range 0.28 m" in implausible(fifth, CFG, "hint") and "(hint)" in implausible(fifth, CFG, "hint")
    metres = depth_range([depth * 1000], "d", 0.28, "test")       # millimetres read as metres
    assert "beyond sources.depth_check.max_median_m" in implausible(metres, CFG, "hint")
    empty = depth_range([np.full((8, 8), np.nan, np.float32)], "d", 0.28, "test")
    assert empty.valid_share == 0.0 and implausible(empty, CFG, "hint") == ""
