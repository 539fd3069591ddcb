"""Recordings whose parts disagree (tests/contradictions.py) through `slz detect`: never a silent answer.

Each contradiction is an error (exit 1, one line naming the file and the parts that disagree, nothing
left behind) or a warning that names the fallback and is kept in run.json (``recording.warnings``).
The rows are in docs/FAILURE_MODES.md.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import contradictions as C
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, synth_recording
from test_bad_inputs import error_line, invoke

from slzcli.config import load_config
from slzcli.errors import DatasetError
from slzcli.evaluate.truth import ground_truth_of
from slzcli.slam.pose_checks import stamp_offset_ns
from slzcli.sources import tf_tree
from slzcli.synth.groundtruth import BINDING_KEY, sidecar_paths

REJECTED = "recorded poses rejected: "


def detect(runner: CliRunner, path: Path, out: Path, *args: str) -> tuple[dict, str]:
    res = invoke(runner, "detect", str(path), "-o", str(out), *args)
    assert res.exit_code == 0, res.stderr
    return json.loads((out / "run.json").read_text()), res.stderr


# ----------------------------------------------------------------------------- recorded poses
@pytest.mark.parametrize("case", ["poses_right", "tf_right"])
def test_poses_that_agree_with_the_frames_are_used(runner: CliRunner, tmp_path: Path, case: str) -> None:
    run, stderr = detect(runner, C.CASES[case](tmp_path), tmp_path / "run")
    assert run["summary"]["slam_backend"] == "recorded"
    assert REJECTED not in stderr and not any(REJECTED in w for w in run["recording"]["warnings"])
    site = run["summary"]["site_world"]
    assert site is not None and abs(site[2]) < 0.05  # the ground is at z = 0 in the poses' world


def test_poses_that_start_after_the_first_frames_are_used_from_there(runner: CliRunner, tmp_path: Path) -> None:
    run, stderr = detect(runner, C.poses_start_late(tmp_path), tmp_path / "run")
    assert run["summary"]["slam_backend"] == "recorded" and REJECTED not in stderr
    assert "recorded poses not checked for the first 4 frames (the poses start after them)" in stderr


# case -> what the warning must say (besides "recorded poses rejected" and the fallback)
REJECTIONS = {
    "poses_mm": "their scale disagrees with the depth by",
    "poses_cm": "their scale disagrees with the depth by",
    "pose_upside_down": "put what the camera sees 6.00 m above it",
    "poses_body_frame": "above it",
    "poses_yawed": "away from the direction the images show",
    "poses_1s_late": "the recorded poses are 1 s after the frames",
    "pose_stamps_in_seconds": "stamps in another unit?",
    "poses_static_frames_moving": "the poses show no motion while the images show the camera moving",
}


@pytest.mark.parametrize("case", list(REJECTIONS))
def test_poses_that_contradict_the_frames_are_rejected_naming_the_fallback(runner: CliRunner, tmp_path: Path,
                                                                           case: str) -> None:
    run, stderr = detect(runner, C.CASES[case](tmp_path), tmp_path / "run")
    backend = run["summary"]["slam_backend"]
    assert backend != "recorded"
    warned = [w for w in run["recording"]["warnings"] if w.startswith(REJECTED)]
    assert len(warned) == 1 and REJECTIONS[case] in warned[0], run["recording"]["warnings"]
    assert f"(slam.backend {backend})" in warned[0]
    assert warned[0] in stderr.replace("\n", " ") or REJECTIONS[case] in stderr


def test_recorded_map_points_are_checked_against_the_depth(runner: CliRunner, tmp_path: Path) -> None:
    points = ("--set", f"slam.points_topic={C.POINTS_TOPIC}")
    run, stderr = detect(runner, C.clouds_right(tmp_path), tmp_path / "right", *points)
    assert run["summary"]["slam_backend"] == "recorded" and REJECTED not in stderr
    assert "not checked for scale" not in stderr  # a hover, but the map points' depth gave the scale
    run, _ = detect(runner, C.clouds_mm(tmp_path), tmp_path / "mm", *points)
    warned = [w for w in run["recording"]["warnings"] if w.startswith(REJECTED)]
    assert run["summary"]["slam_backend"] != "recorded"
    assert len(warned) == 1 and "the recorded map points put what the camera sees 1000x as far" in warned[0]


@pytest.mark.parametrize(("case", "factor"), [("poses_mm", 1000.0), ("poses_cm", 100.0)])
def test_the_scale_factor_is_measured_not_guessed(runner: CliRunner, tmp_path: Path, case: str,
                                                  factor: float) -> None:
    """The factor named is the measured one: within 15 % of the true unit factor (1000x and 100x here; the
    depth-implied motion was within 3 % of the true one on eight synth flights, docs/FAILURE_MODES.md)."""
    path = C.CASES[case](tmp_path)
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"), "--set", "slam.backend=recorded")
    error_line(res, path, "recorded poses rejected")
    said = float(res.stderr.split("disagrees with the depth by ")[1].split("x")[0])
    assert factor / 1.15 < said < factor * 1.15
    assert "(slam.backend: recorded; set it to auto" in res.stderr
    assert not (tmp_path / "run").exists()


def test_the_check_can_be_turned_off(runner: CliRunner, tmp_path: Path) -> None:
    run, stderr = detect(runner, C.poses_mm(tmp_path), tmp_path / "run", "--set", "slam.pose_check.frames=0")
    assert run["summary"]["slam_backend"] == "recorded" and REJECTED not in stderr


def test_the_stamp_offset_is_where_most_frames_find_a_pose() -> None:
    frames = np.arange(12) * 100_000_000
    poses = frames + 1_000_000_000
    assert stamp_offset_ns(frames, poses, 50_000_000) == pytest.approx(1e9)
    assert stamp_offset_ns(frames, frames - 300_000_000, 50_000_000) == pytest.approx(-3e8)
    assert stamp_offset_ns(frames, frames + 3_000_000, 50_000_000) == pytest.approx(3e6)


# ----------------------------------------------------------------------------- tf trees
@pytest.mark.parametrize(("case", "cause"), [
    ("tf_two_parents", "/tf: frame 'camera_color_optical_frame' has two parents, 'world' and 'map'"),
    ("tf_cycle", "closes a cycle of child -> parent links world -> camera_color_optical_frame -> world"),
])
def test_a_tf_tree_that_is_not_a_tree_is_refused_naming_the_frames(runner: CliRunner, tmp_path: Path, case: str,
                                                                   cause: str) -> None:
    path = C.CASES[case](tmp_path)
    before = set(tmp_path.iterdir())
    error_line(invoke(runner, "detect", str(path), "-o", str(tmp_path / "run")), path, cause)
    assert set(tmp_path.iterdir()) == before


def test_tf_tree_rules() -> None:
    T = np.eye(4)
    tree: dict = {}
    tf_tree.add_edge(tree, "map", "odom", T)
    tf_tree.add_edge(tree, "odom", "base", T)
    tf_tree.add_edge(tree, "odom", "base", 2 * T)  # the same edge again: a moving frame
    assert tree["base"][1][0, 0] == 2
    with pytest.raises(tf_tree.TfTreeError, match="'base' has two parents, 'odom' and 'map'"):
        tf_tree.add_edge(tree, "map", "base", T)
    with pytest.raises(tf_tree.TfTreeError, match="map -> base -> odom -> map"):
        tf_tree.add_edge(tree, "base", "map", T)
    with pytest.raises(tf_tree.TfTreeError, match="itself as parent"):
        tf_tree.add_edge(tree, "cam", "cam", T)
    assert tf_tree.merge_problem({"cam": ("base", T)}, {"cam": ("world", T)}) is not None
    assert tf_tree.merge_problem({"cam": ("base", T)}, {"base": ("odom", T)}) is None


# ----------------------------------------------------------------------------- depth of another shape
@pytest.mark.parametrize(("case", "shape"), [("aligned_depth_transposed", "depth 120x160 px"),
                                             ("aligned_depth_half_width", "depth 80x120 px")])
def test_aligned_depth_of_another_shape_is_refused_not_stretched(runner: CliRunner, tmp_path: Path, case: str,
                                                                 shape: str) -> None:
    path = C.CASES[case](tmp_path)
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"))
    error_line(res, path, f"{shape} is not of the colour's shape 160x120 px")
    assert "never stretches depth onto colour" in res.stderr
    assert set(tmp_path.iterdir()) == before


def test_aligned_depth_at_half_the_colour_size_is_scaled_with_a_note(runner: CliRunner, tmp_path: Path) -> None:
    run, _ = detect(runner, C.aligned_depth_half_size(tmp_path), tmp_path / "run")
    notes = run["summary"]["pairing"]["notes"]
    assert any("depth 80x60 resized nearest-neighbour to colour 160x120" in n for n in notes)


# ----------------------------------------------------------------------------- ground-truth sidecars
@pytest.fixture(scope="module")
def two_scenes(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("scenes")
    a = synth_recording(folder / "field.mcap", "clear_field", 2, *GAUSSIAN)
    b = synth_recording(folder / "junk.mcap", "no_site", 2, *GAUSSIAN)
    return a, b


def _copy(rec: Path, folder: Path, sidecar_of: Path | None = None) -> Path:
    out = folder / rec.name
    shutil.copy(rec, out)
    for src, dst in zip(sidecar_paths(sidecar_of or rec), sidecar_paths(out), strict=True):
        shutil.copy(src, dst)
    return out


def test_synth_binds_its_sidecar_to_the_recording(two_scenes: tuple[Path, Path], tmp_path: Path,
                                                  runner: CliRunner) -> None:
    a, _ = two_scenes
    header = json.loads(sidecar_paths(a)[1].read_text())
    assert header[BINDING_KEY] == [{"size": a.stat().st_size, "sha256": header[BINDING_KEY][0]["sha256"]}]
    run, _ = detect(runner, _copy(a, tmp_path), tmp_path / "run")
    assert run["summary"]["ground_truth"]["mask"] is not None


def test_a_sidecar_of_another_scene_is_refused(two_scenes: tuple[Path, Path], tmp_path: Path,
                                               runner: CliRunner) -> None:
    a, b = two_scenes
    rec = _copy(a, tmp_path, sidecar_of=b)  # the junk yard's truth beside the field's recording
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(rec), "-o", str(tmp_path / "run"))
    error_line(res, sidecar_paths(rec)[1], "ground truth of another recording: it was written for 'junk.mcap' of "
                                           "scene 'no_site'")
    assert set(tmp_path.iterdir()) == before
    with pytest.raises(DatasetError, match="ground truth of another recording"):
        ground_truth_of(rec, load_config().synth.ground_truth)


def test_an_edited_recording_no_longer_matches_its_sidecar(two_scenes: tuple[Path, Path], tmp_path: Path) -> None:
    rec = _copy(two_scenes[0], tmp_path)
    with open(rec, "r+b") as fh:  # one byte of the recording changed
        fh.seek(rec.stat().st_size // 2)
        byte = fh.read(1)
        fh.seek(-1, 1)
        fh.write(bytes([byte[0] ^ 0xFF]))
    with pytest.raises(DatasetError, match="ground truth of another recording"):
        ground_truth_of(rec, load_config().synth.ground_truth)


def test_an_unbound_sidecar_is_used_with_a_warning(two_scenes: tuple[Path, Path], tmp_path: Path,
                                                   runner: CliRunner) -> None:
    rec = _copy(two_scenes[0], tmp_path)
    header_path = sidecar_paths(rec)[1]
    header = json.loads(header_path.read_text())
    del header[BINDING_KEY]  # as an slz before the binding wrote it
    header_path.write_text(json.dumps(header))
    run, stderr = detect(runner, rec, tmp_path / "run")
    assert "is not bound to its recording" in stderr and run["summary"]["ground_truth"]["mask"] is not None


# ----------------------------------------------------------------------------- CameraInfo of another camera
@pytest.mark.parametrize(("case", "info", "image", "frames"), [
    ("info_of_depth_beside_color", "/camera/color/camera_info", "/camera/color/image_raw",
     ("'camera_depth_optical_frame'", "'camera_color_optical_frame'")),
    ("depth_info_of_another_camera", "/camera/depth/camera_info", "/camera/depth/image_rect_raw",
     ("'camera_infra1_optical_frame'", "'camera_depth_optical_frame'"))])
def test_a_camera_info_of_another_optical_frame_is_refused(runner: CliRunner, tmp_path: Path, case: str, info: str,
                                                           image: str, frames: tuple[str, str]) -> None:
    path = C.CASES[case](tmp_path)
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"))
    error_line(res, path, f"CameraInfo on {info} is for frame {frames[0]} but {image} is in frame {frames[1]}")
    assert "the calibration of another camera" in res.stderr
    assert set(tmp_path.iterdir()) == before


def test_the_colour_camera_info_in_the_colour_frame_is_used(runner: CliRunner, tmp_path: Path) -> None:
    run, _ = detect(runner, C.info_of_the_color_camera(tmp_path), tmp_path / "run")
    assert run["recording"]["intrinsics_source"] == "CameraInfo on /camera/color/camera_info"


@pytest.mark.parametrize("layout", sorted(C.LAYOUTS))
def test_every_known_camera_layout_passes_the_frame_check(tmp_path: Path, layout: str) -> None:
    """Real drivers' frame ids (aligned depth and its CameraInfo in the colour frame, empty ids, a leading
    '/') are no contradiction; the same layout with the CameraInfo in the depth frame is."""
    from slzcli.sources import open_recording
    streams = C.LAYOUTS[layout]
    config = load_config()
    with open_recording(C.camera_layout(tmp_path / f"{layout}.mcap", streams), config) as rec:
        info = rec.info()
    assert info.intrinsics_source.startswith("CameraInfo on " + streams["camera_info"][0])
    if streams["camera_info"][1] and streams["color"][1]:
        wrong = {**streams, "camera_info": (streams["camera_info"][0], "some_depth_optical_frame")}
        with pytest.raises(DatasetError, match="is for frame 'some_depth_optical_frame'"), \
                open_recording(C.camera_layout(tmp_path / f"{layout}_wrong.mcap", wrong), config) as rec:
            rec.info()
