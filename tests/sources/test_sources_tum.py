"""TUM RGB-D folders: lists, 5000-per-metre depth, association by stamp, ground truth only on request."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from sources_util import known_frame, pose

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.sources import open_recording
from slzcli.sources.tum import parse_stamp


def make_tum(root: Path, n: int = 4, camera_yaml: bool = False) -> list:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines, frames = ["# color images"], ["# depth maps"], ["# ground truth"], []
    for i in range(n):
        f = known_frame(i)
        t = 1305031102.175304 + i * 0.033333
        counts = np.nan_to_num(f.depth_m * 5000.0, nan=0.0).round().astype(np.uint16)
        cv2.imwrite(str(root / "rgb" / f"{i}.png"), cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(root / "depth" / f"{i}.png"), counts)
        rgb_lines.append(f"{t:.6f} rgb/{i}.png")
        depth_lines.append(f"{t + 0.004:.6f} depth/{i}.png")  # 4 ms later, as in the benchmark
        T = pose(i)
        from slzcli.geometry import Pose
        q = Pose.from_matrix(T).as_quat()
        gt_lines.append(f"{t:.6f} {T[0, 3]} {T[1, 3]} {T[2, 3]} {q[0]} {q[1]} {q[2]} {q[3]}")
        frames.append((f, counts))
    depth_lines.append(f"{1305031102.175304 + 10:.6f} depth/0.png")  # a depth with no colour
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    if camera_yaml:
        (root / "camera.yaml").write_text("fx: 525.0\nfy: 525.0\ncx: 319.5\ncy: 239.5\nwidth: 640\nheight: 480\n")
    return frames


def test_parse_stamp_is_exact() -> None:
    assert parse_stamp("1305031102.175304") == 1305031102_175304000
    assert parse_stamp("12") == 12_000_000_000


def test_tum_folder_reads_back(tmp_path: Path) -> None:
    written = make_tum(tmp_path / "seq")
    with open_recording(tmp_path / "seq", load_config()) as rec:
        frames = list(rec.frames())
        info = rec.info()
    assert len(frames) == 4 and rec.report.paired == 4 and rec.report.unpaired_depth == 1
    for got, (want, counts) in zip(frames, written, strict=True):
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(np.isnan(got.depth_m), counts == 0)
        ok = counts > 0
        np.testing.assert_array_equal(got.depth_m[ok], counts[ok].astype(np.float32) / np.float32(5000))
        assert got.T_world_camera is None  # ground truth is not a pose input by default
    # no camera.yaml, no preset in the folder's name: the fallback is said on stderr and in the warnings (run.json)
    assert info.intrinsics_source.startswith("config camera section")
    assert any("no camera.yaml and no camera preset" in w for w in info.warnings)
    assert {c.role: c for c in info.choices}["pose"].topic is None


def test_tum_ground_truth_pose_on_request_and_camera_yaml(tmp_path: Path) -> None:
    make_tum(tmp_path / "seq", camera_yaml=True)
    cfg = load_config(None, ["sources.use_ground_truth_pose=true"])
    with open_recording(tmp_path / "seq", cfg) as rec:
        frames = list(rec.frames())
    for i, f in enumerate(frames):
        assert f.T_world_camera is not None
        np.testing.assert_allclose(f.T_world_camera, pose(i), atol=1e-6)
    # camera.yaml is for 640x480; the images are 32x24, so K is scaled to them.
    assert f.intrinsics.width == 32 and f.intrinsics.fx == pytest.approx(525.0 * 32 / 640)


def test_tum_info_cli_and_missing_depth_list(tmp_path: Path, runner: CliRunner) -> None:
    make_tum(tmp_path / "seq")
    result = runner.invoke(main, ["info", "--json", str(tmp_path / "seq")])
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["frames"] == 4
    (tmp_path / "seq" / "depth.txt").unlink()
    result = runner.invoke(main, ["info", str(tmp_path / "seq")])
    assert result.exit_code == 1 and "depth.txt" in result.stderr and "seq" in result.stderr
