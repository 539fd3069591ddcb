"""Every case of the bad-input corpus (tests/bad_inputs.py) through `slz info` and `slz detect`.

The documented behaviour (docs/FAILURE_MODES.md): either exit 1 with ONE line
``slz: error: <file>: <cause>`` and nothing left behind (no run folder, no temporary),
or exit 0 with a warning and a result that says what was skipped or why there is no site.
Never a traceback, never an "internal error".
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import bad_inputs as B
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.methods import registry
from slzcli.sources import open_recording

# case -> (cause in the `slz info` error or None when info succeeds, cause in the `slz detect` error)
FAILS: dict[str, tuple[str | None, str]] = {
    "empty": ("empty file", "empty file"),
    "garbage": ("not a ROS 1 bag", "not a ROS 1 bag"),
    "wrong_magic": ("bad magic", "bad magic"),
    "cut_header": ("no readable topics", "no readable topics"),
    "cut_ros1": ("cut short", "cut short"),
    "unsupported_depth_encoding": (None, "unsupported depth encoding '64FC1'"),  # info reads stamps only
    "one_pixel": (None, "smaller than sources.min_image_px"),
    "corrupt_compressed_colour": (None, "not a decodable jpeg/png"),
    "ros2_cut_db": ("malformed", "malformed"),
    "ros2_missing_storage": ("database files are missing", "database files are missing"),
    # issue 15: validated before use, named (these were silently wrong or an "internal error")
    "camera_info_principal_outside": ("CameraInfo on /camera/aligned_depth_to_color/camera_info: principal point "
                                      "(cx, cy) = (-1e+06, -1e+06) px is outside the 160x120 image",) * 2,
    "camera_info_size_zero": ("width = 0 px must be >= 1",) * 2,
    "camera_info_fx_huge": ("fx = 1e+300 px gives a horizontal field of view of 9.17e-297 deg",) * 2,
    "camera_info_aspect_mismatch": (None, "frame 0 (/camera/color/image_raw): CameraInfo on "
                                          "/camera/aligned_depth_to_color/camera_info: intrinsics for 160x160 px do "
                                          "not fit the 160x120 px images"),
    "symlink_loop": ("symbolic link loop",) * 2,
    "tum_camera_width_zero": ("camera.yaml: width = 0 px must be >= 1",) * 2,
    "tum_camera_fx_negative": ("camera.yaml: fx = -128 px must be > 0",) * 2,
    "tum_camera_fx_nan": ("camera.yaml: fx = nan is not a finite number",) * 2,
    "tum_camera_fx_huge": ("camera.yaml: fx = 1e+300 px gives a horizontal field of view",) * 2,
    "huge_jpeg_frames": (None, "30000x30000 px (900.0 MP) is over sources.max_image_px"),  # info reads no pixels
    # issue 29: an OpenCV size mismatch in terrain/maps.py before (info reads no depth values)
    "depth_metres_in_16uc1": (None, "frame 0: median depth 0.006 m puts one working block"),
    "depth_bigendian_flag": (None, "is the depth in the unit its encoding says"),
    "depth_1e27": (None, "frame 0: median depth 1e-27 m"),
    # issue 29: sizes and kinds checked before a byte is read (a FIFO hung, sparse files cost their size)
    "fifo_recording": ("not a regular file or folder (a FIFO)",) * 2,
    "tum_sparse_rgb_txt": ("rgb.txt: is 3072 MiB, larger than 256 MiB",) * 2,
    "ros2_sparse_metadata": ("metadata.yaml: is 3072 MiB, larger than 64 MiB",) * 2,
}
# one frame of four over sources.max_image_px: skipped with one warning, counted, the run goes on
OVERSIZED = {"huge_png_frame": "12000x9000 px", "over_opencv_limit_frame": "40000x30000 px",
             "huge_raw_depth_frame": "Image 16UC1 of 30000x30000 px"}
RESULTS = ("cut_middle", "cut_before_footer", "mismatched_sizes", "camera_info_zeros", "depth_all_nan",
           "depth_constant", "stamps_backwards", "duplicated_messages", "no_texture", "short_image_data",
           "camera_info_nan", "stamps_all_zero", "stamps_all_zero_log_zero", "stamps_duplicated", "two_depth_topics",
           "pose_nan", "tum_missing_images", "depth_3e38")
OTHER = {"very_large", "log_time_near_2_64", "mcap_huge_chunk"}  # tests of their own below
assert set(FAILS) | set(RESULTS) | set(OVERSIZED) | OTHER == set(B.RECORDINGS)


# Progress lines off a terminal (output.progress_every_s): not errors.
PROGRESS = ("slz: detect: ", "slz: synth ", "slz: compare: ", "slz: monte carlo: ")

def invoke(runner: CliRunner, *args: str):
    res = runner.invoke(main, list(args))
    assert "Traceback" not in res.output and "internal error" not in res.stderr, res.stderr
    return res


def error_line(res, path: Path, cause: str) -> None:
    assert res.exit_code == 1, res.output
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: error:")]
    assert len(errors) == 1, res.stderr
    assert path.name in errors[0] and cause in errors[0], errors[0]
    assert not [ln for ln in res.stderr.splitlines() if not ln.startswith(("slz: error:", "slz: WARNING:", *PROGRESS))]


def detect_json(runner: CliRunner, path: Path, out: Path) -> tuple[dict, str]:
    res = invoke(runner, "detect", str(path), "-o", str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    landing = json.loads((out / "landing.json").read_text())
    assert landing["status"] == summary["status"]
    if landing["status"] == "no_safe_site":
        assert landing["reason"]
    assert json.loads((out / "run.json").read_text())["summary"]["frames"] == summary["frames"]
    return summary, res.stderr


@pytest.mark.parametrize("case", list(FAILS))
def test_unreadable_input_is_one_line_and_leaves_nothing(runner: CliRunner, tmp_path: Path, case: str) -> None:
    path = B.RECORDINGS[case](tmp_path)
    before = set(tmp_path.iterdir())
    info_cause, detect_cause = FAILS[case]
    res = invoke(runner, "info", str(path), "--json")
    if info_cause is None:
        assert res.exit_code == 0 and json.loads(res.stdout)["frames"] > 0
    else:
        error_line(res, path, info_cause)
    out = tmp_path / "run"
    error_line(invoke(runner, "detect", str(path), "-o", str(out)), path, detect_cause)
    assert set(tmp_path.iterdir()) == before  # no run folder, no temporary beside it


@pytest.mark.parametrize("case", ["cut_middle", "cut_before_footer"])
def test_cut_short_mcap_runs_on_what_was_recovered(runner: CliRunner, tmp_path: Path, case: str) -> None:
    path = B.RECORDINGS[case](tmp_path)
    info = json.loads(invoke(runner, "info", str(path), "--json").stdout)
    assert 0 < info["frames"] < 6 and "recovered" in info["warnings"][0]
    summary, stderr = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == info["frames"]
    assert "recovered" in stderr and path.name in stderr
    assert any("recovered" in n for n in summary["pairing"]["notes"])


def test_depth_smaller_than_colour_is_resized_and_noted(runner: CliRunner, tmp_path: Path) -> None:
    summary, _ = detect_json(runner, B.mismatched_sizes(tmp_path), tmp_path / "run")
    assert summary["frames"] == 3
    assert any("resized nearest-neighbour" in n for n in summary["pairing"]["notes"])


def test_camera_info_of_zeros_falls_back_to_the_config_camera_with_one_warning(runner: CliRunner,
                                                                                 tmp_path: Path) -> None:
    path = B.camera_info_zeros(tmp_path)
    res = invoke(runner, "info", str(path), "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["intrinsics_source"] == "config camera section"
    assert res.stderr.count("no usable K") == 1  # once, not once per message
    summary, _ = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 3
    assert any("CameraInfo" in n and "not usable" in n for n in summary["pairing"]["notes"])


def test_camera_info_of_nan_is_refused_like_zeros(runner: CliRunner, tmp_path: Path) -> None:
    """A NaN K used to pass the check and reach ORB-SLAM3 ("fx must be a real number", no file named)."""
    path = B.camera_info_nan(tmp_path)
    res = invoke(runner, "info", str(path), "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["intrinsics_source"] == "config camera section"
    assert "no usable K" in res.stderr
    summary, _ = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 3


def test_one_torn_depth_message_skips_that_frame_and_counts_it(runner: CliRunner, tmp_path: Path) -> None:
    path = B.short_image_data(tmp_path)
    summary, stderr = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 3 and summary["pairing"]["undecodable"] == 1 and summary["pairing"]["paired"] == 4
    assert "data has" in stderr and path.name in stderr


def test_depth_all_nan_is_no_safe_site_with_a_reason(runner: CliRunner, tmp_path: Path) -> None:
    summary, _ = detect_json(runner, B.depth_all_nan(tmp_path), tmp_path / "run")
    assert summary["status"] == "no_safe_site" and summary["frames"] == 3
    assert summary["reason"].startswith("no valid depth in any of the ") and "depth_unit_16u_m" in summary["reason"]


def test_depth_all_one_value_is_flat_ground(runner: CliRunner, tmp_path: Path) -> None:
    summary, _ = detect_json(runner, B.depth_constant(tmp_path), tmp_path / "run")
    assert summary["status"] == "site"
    assert summary["site_world"][2] == pytest.approx(-B.ALTITUDE_M, abs=0.05)  # the floor, 6 m below the camera


def test_stamps_going_backwards_are_put_in_order(runner: CliRunner, tmp_path: Path) -> None:
    """The reader hands the frames on in header-stamp order, and the run keeps that order. The count is
    asserted on the reader: ORB-SLAM3 need not track every frame of a 4-frame recording (it tracked 2 or 3
    of them in some runs, more often under load), so trajectory.tum is checked for order only."""
    path = B.stamps_backwards(tmp_path)
    with open_recording(path, load_config()) as rec:
        read = [f.stamp_ns for f in rec.frames()]
    assert len(read) == 4 and read == sorted(read)
    out = tmp_path / "run"
    summary, _ = detect_json(runner, path, out)
    assert summary["frames"] == 4
    stamps = [float(ln.split()[0]) for ln in (out / "trajectory.tum").read_text().splitlines()
              if ln and not ln.startswith("#")]
    assert stamps and stamps == sorted(stamps)
    rows = [ln.split(",") for ln in (out / "sites.csv").read_text().splitlines()[1:]]
    by_frame = sorted({(int(r[0]), int(r[1])) for r in rows})
    assert [s for _, s in by_frame] == sorted(s for _, s in by_frame)  # later frame, later stamp


def test_duplicated_messages_are_dropped_and_counted(runner: CliRunner, tmp_path: Path) -> None:
    path = B.duplicated_messages(tmp_path)
    info = json.loads(invoke(runner, "info", str(path), "--json").stdout)
    assert info["frames"] == 3 and info["pairing"]["unpaired_color"] == 0
    summary, _ = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 3
    assert any("6 duplicated" in n for n in summary["pairing"]["notes"])


def test_textureless_frames_track_nothing_and_say_so(runner: CliRunner, tmp_path: Path) -> None:
    summary, _ = detect_json(runner, B.no_texture(tmp_path), tmp_path / "run")
    assert summary["status"] == "no_safe_site" and summary["detections"] == 0
    assert "keyframe" in summary["reason"]
    assert "ok" not in summary["tracking"]


def test_very_large_frame_finishes_in_a_subprocess(tmp_path: Path) -> None:
    """4000x3000: no hang, no memory blow-up (a subprocess with a timeout guards the test run)."""
    path = B.very_large(tmp_path)
    out = tmp_path / "run"
    for args in (["info", str(path), "--json"], ["detect", str(path), "-o", str(out), "--json"]):
        proc = subprocess.run([sys.executable, "-m", "slzcli.cli", *args], capture_output=True, text=True,
                              timeout=180)
        assert proc.returncode == 0, proc.stderr
        assert json.loads(proc.stdout)["frames"] == 1
    assert json.loads((out / "landing.json").read_text())["status"] in ("site", "no_safe_site")


@pytest.mark.parametrize("case", list(OVERSIZED))
def test_a_frame_over_the_pixel_bound_is_skipped_with_one_warning(runner: CliRunner, tmp_path: Path,
                                                                  case: str) -> None:
    """Read from the header before decoding (the tester's 12000x9000 PNG cost 3.4 GB; over OpenCV's own
    limit, cv2.imdecode threw and the whole recording ended as an internal error)."""
    path = B.RECORDINGS[case](tmp_path)
    summary, stderr = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 3 and summary["pairing"]["undecodable"] == 1
    warnings = [ln for ln in stderr.splitlines() if "max_image_px" in ln]
    assert len(warnings) == 1 and OVERSIZED[case] in warnings[0] and path.name in warnings[0], stderr
    assert "frame at stamp" in warnings[0] and "skipped" in warnings[0]
    assert "1 frame(s) over sources.max_image_px 16777216 px were skipped" in summary["pairing"]["notes"]
    # no libpng noise
    assert not [ln for ln in stderr.splitlines() if not ln.startswith(("slz: WARNING:", *PROGRESS))], stderr


def test_every_frame_over_the_bound_warns_once_and_counts(runner: CliRunner, tmp_path: Path) -> None:
    path = B.huge_jpeg_frames(tmp_path)
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"))
    assert res.stderr.count("slz: WARNING:") == 1, res.stderr  # three frames: one warning, then counted
    # raising the bound lets the header through, and the (empty) JPEG is then just undecodable
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"), "--set", f"sources.max_image_px={2**30}")
    error_line(res, path, "not a decodable jpeg/png")


@pytest.mark.parametrize("case,key,cause", [
    ("config_wrong_type", "mask.threshold", "expected a number"),
    ("config_unknown_key", "mask.treshold", "unknown key"),
    ("config_not_a_mapping", "", "must be a mapping"),
    ("config_bad_yaml", "", "not valid YAML"),
    ("config_latin1", "", "not UTF-8 text (nor UTF-16 with a byte-order mark): invalid continuation byte"),
    ("config_utf16_no_bom", "", "not UTF-8 text"),
    ("config_binary", "", "not UTF-8 text"),
    ("config_deep", "", "nested too deeply for the YAML parser"),
    ("config_contradictory", "terrain.flatness.canny_low", "must be <= terrain.flatness.canny_high"),
    ("config_alias_bomb", "", "more than 100000 values once its aliases are expanded"),
    ("config_alias_small_bomb", "landing.kmeans_k", "expected an integer, got a list [[[[...]"),
    ("config_too_deep", "", "nested more than 32 levels deep"),
    ("config_too_large", "", "file is larger than 1024 KiB"),
    ("config_long_value", "scoring.method", f"must be one of {', '.join(registry.names())}; got 'xxxxx"),
])
def test_bad_config_file_is_one_line_naming_file_and_key(runner: CliRunner, tmp_path: Path, case: str, key: str,
                                                         cause: str) -> None:
    rec = B.good(tmp_path, n=2)
    cfg = B.CONFIGS[case](tmp_path)
    before = set(tmp_path.iterdir())
    for cmd in (["info", str(rec)], ["detect", str(rec), "-o", str(tmp_path / "run")]):
        res = invoke(runner, *cmd, "--config", str(cfg))
        error_line(res, cfg, cause)
        assert key in res.stderr
        assert len(res.stderr) < 400, f"{len(res.stderr)} characters"  # values are quoted short, never whole
    assert set(tmp_path.iterdir()) == before


@pytest.mark.parametrize("value,cause", [
    (B.alias_bomb(5), "expected an integer, got a list [[[[...]"),                # 59,049 values when printed
    (B.alias_bomb(9), "value refused: more than 100000 values once its aliases are expanded"),
    ("1" + "0" * 5000, "value refused: a value cannot be read"),          # int() of 5,000 digits
    ("[" * 100 + "]" * 100, "nested more than 32 levels deep"),
])
def test_bad_set_value_is_one_short_line(runner: CliRunner, tmp_path: Path, value: str, cause: str) -> None:
    res = invoke(runner, "config", "dump", "--set", f"landing.kmeans_k={value}")
    assert res.exit_code == 1 and "landing.kmeans_k" in res.stderr and cause in res.stderr, res.stderr
    assert len(res.stderr.splitlines()) == 1 and len(res.stderr) < 300


def test_a_normal_radius_joining_too_many_pairs_is_one_line_naming_the_key(runner: CliRunner,
                                                                          tmp_path: Path) -> None:
    rec = B.good(tmp_path, n=2)
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(rec), "-o", str(tmp_path / "run"), "--set", "landing.normal_radius_m=1000",
                 "--set", "landing.max_normal_pairs=100", "--set", "landing.detect_on=every_nth")
    assert res.exit_code == 1 and res.stderr.startswith("slz: error: landing.normal_radius_m: 1000 m joins")
    assert len(res.stderr.splitlines()) == 1
    assert set(tmp_path.iterdir()) == before


@pytest.mark.parametrize("footprint", ["[1000, 1000]", "[1.0e6, 1.0e6]", "[1e6, 1e6]"])
def test_a_footprint_larger_than_the_view_is_no_site_without_a_huge_kernel(runner: CliRunner, tmp_path: Path,
                                                                          footprint: str) -> None:
    """2.4 GB and 414 TiB before: the landing mask's minimum filter built its kernel first."""
    import tracemalloc

    rec = B.good(tmp_path, n=2)
    out = tmp_path / "run"
    tracemalloc.start()   # numpy reports its array allocations to tracemalloc: the kernel would be counted
    try:
        res = invoke(runner, "detect", str(rec), "-o", str(out), "--json", "--set", f"uav.footprint_m={footprint}",
                     "--set", "landing.detect_on=every_nth")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["status"] == "no_safe_site" and summary["detections"] == 2
    # Measured: 12.6 MB traced at [1000, 1000] (31 MB with the real footprint, which finds a site);
    # the kernel alone was 455 MB. A bound of 100 MB leaves 3x over the larger of the two.
    assert peak < 100e6, f"{peak / 1e6:.0f} MB traced"


@pytest.mark.parametrize("backend,cause", [("orbslam3", "ORB-SLAM3 cannot track frame 0 (1x1 px)"),
                                           ("odometry", "ORB features cannot be found in frame 0 (1x1 px)")])
def test_tracker_failure_below_the_size_floor_is_named_not_internal(runner: CliRunner, tmp_path: Path, backend: str,
                                                                    cause: str) -> None:
    """With the size check lowered, the tracker's own exception comes out as one line naming frame and size."""
    from slzcli.slam import orbslam3

    if backend == "orbslam3" and not orbslam3.available():
        pytest.skip("pyorbslam3 not installed")
    path = B.one_pixel(tmp_path)
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"), "--set", "sources.min_image_px=[1, 1]",
                 "--set", f"slam.backend={backend}")
    error_line(res, path, cause)
    assert set(tmp_path.iterdir()) == before


# ----------------------------------------------------------------------------- issue 15: stamps, topics, poses
def warnings_of(stderr: str) -> list[str]:
    lines = stderr.splitlines()
    assert all(ln.startswith(("slz: WARNING:", "slz: error:", *PROGRESS)) for ln in lines), stderr  # one line each
    return [ln for ln in lines if ln.startswith("slz: WARNING:")]


def stamp_warnings_of(stderr: str) -> list[str]:
    """The warnings about stamps (ORB-SLAM3 on these 10 flat frames may also restart its map, or not,
    depending on how its threads are scheduled: a warning of its own)."""
    return [w for w in warnings_of(stderr) if "message(s)" in w]


def test_header_stamps_of_zero_use_the_log_time_with_one_counted_warning_per_stream(runner: CliRunner,
                                                                                     tmp_path: Path) -> None:
    path = B.stamps_all_zero(tmp_path)
    summary, stderr = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 10
    warned = stamp_warnings_of(stderr)
    assert len(warned) == 2 and all("10 of 10 message(s) have header stamp 0" in w for w in warned)
    assert "/camera/color/image_raw" in warned[0] and "/camera/aligned_depth_to_color/image_raw" in warned[1]
    assert sum("header stamp 0" in n for n in summary["pairing"]["notes"]) == 2


def test_one_stamp_for_ten_different_frames_is_warned_and_counted(runner: CliRunner, tmp_path: Path) -> None:
    """Ten images under one stamp became one frame with only a run.json note; now a warning says so."""
    path = B.stamps_duplicated(tmp_path)
    res = invoke(runner, "info", str(path), "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["frames"] == 1
    assert any("9 of 10 message(s) repeat the stamp of a different earlier message" in w
               for w in warnings_of(res.stderr))
    summary, stderr = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 1
    warned = stamp_warnings_of(stderr)
    assert len(warned) == 1 and "/camera/color/image_raw: 9 of 10" in warned[0] and path.name in warned[0]
    # identical depth images under one stamp are a recorded-twice duplicate: a note, no warning
    assert any("9 of 10 message(s) repeat" in n for n in summary["pairing"]["notes"])


def test_stamps_and_log_times_all_zero_say_so(runner: CliRunner, tmp_path: Path) -> None:
    summary, stderr = detect_json(runner, B.stamps_all_zero_log_zero(tmp_path), tmp_path / "run")
    assert summary["frames"] == 1
    warned = warnings_of(stderr)
    assert any("header stamp 0" in w for w in warned) and any("repeat the stamp" in w for w in warned)


def test_log_times_beyond_int64_are_skipped_with_a_count_not_an_overflow(runner: CliRunner, tmp_path: Path) -> None:
    path = B.log_time_near_2_64(tmp_path)
    res = invoke(runner, "info", str(path), "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["frames"] == 0
    assert any("4 of 4 message(s) have a stamp out of range" in w for w in warnings_of(res.stderr))
    before = set(tmp_path.iterdir())
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"))
    error_line(res, path, "no frame has a usable stamp (first: stamp 18446744073709550616 ns is beyond 2^63 ns")
    assert set(tmp_path.iterdir()) == before


def test_depth_topic_is_chosen_by_encoding_before_name(runner: CliRunner, tmp_path: Path) -> None:
    """An rgb8 /camera/depth/colorized sorted before the 16UC1 topic and won; every frame then failed."""
    path = B.two_depth_topics(tmp_path)
    info = json.loads(invoke(runner, "info", str(path), "--json").stdout)
    assert info["streams"]["depth"]["topic"] == "/camera/depth/image_rect_raw"
    assert "/camera/depth/colorized (rgb8)" in info["streams"]["depth"]["reason"]
    summary, _ = detect_json(runner, path, tmp_path / "run")
    assert summary["frames"] == 4 and summary["pairing"]["undecodable"] == 0


def test_a_nan_pose_is_refused_at_the_source_with_one_warning(runner: CliRunner, tmp_path: Path) -> None:
    """A NaN position reached the maps ("must be a finite 4x4 matrix, got shape (4, 4)", no file named)."""
    path = B.pose_nan(tmp_path)
    out = tmp_path / "run"
    res = invoke(runner, "detect", str(path), "-o", str(out), "--json", "--set", "landing.detect_on=every_nth")
    assert res.exit_code == 0, res.stderr
    warned = warnings_of(res.stderr)
    bad = [w for w in warned if "pose on /camera/pose not usable" in w]
    assert len(bad) == 1 and "non-finite position" in bad[0] and path.name in bad[0]
    # the one other warning: 1 frame of 4 without a pose is over slam.max_untracked_share
    assert len(warned) == 2 and "could not track 1 of 4 frames" in "".join(w for w in warned if w not in bad)
    summary = json.loads(res.stdout)
    assert summary["frames"] == 4 and summary["tracking"] == {"ok": 3, "lost": 1}
    assert "nan" not in (out / "trajectory.tum").read_text().lower()


def test_missing_tum_images_are_one_warning_and_a_count(runner: CliRunner, tmp_path: Path) -> None:
    summary, stderr = detect_json(runner, B.tum_missing_images(tmp_path), tmp_path / "run")
    assert summary["frames"] == 5 and summary["pairing"]["undecodable"] == 25
    # the images' warnings only: ORB-SLAM3 loses one of the 5 frames left in ~1 run of 15 (its threads), which
    # adds the untracked frames' own warnings (measured: 1 of 12 runs on 9493d33's code, 1 of 18 after)
    warned = [w for w in warnings_of(stderr) if ".png" in w]
    assert len(warned) == 1 and "rgb/5.png" in warned[0] and "counted, not shown" in warned[0]
    assert any(n.startswith("25 of 30 frame(s) not readable") for n in summary["pairing"]["notes"])


# ----------------------------------------------------------------------------- issue 15: land simulate, values
@pytest.mark.parametrize("case,cause", [
    ("landing_collinear", "site.corners_world: corners 0 and 1 are 0.6 m apart; the Eq. 10 square of uav.footprint_m"),
    ("landing_tiny", "site.corners_world: corners 0 and 1 are 2e-09 m apart"),
    ("landing_identical", "site.corners_world: corners 0 and 1 are 0 m apart"),
    ("landing_deep", "nested more than 64 levels deep"),
])
def test_a_landing_target_that_is_not_the_footprint_square_is_refused(runner: CliRunner, tmp_path: Path, case: str,
                                                                      cause: str) -> None:
    """Collinear, 1e-9 m or coincident corners 'landed' or ended as corners_lost with exit 0."""
    run = B.LANDINGS[case](tmp_path)
    res = invoke(runner, "land", "simulate", str(run), "--start", "0,0,3")
    error_line(res, run / "landing.json", cause)
    assert not (run / "ibvs").exists()


def test_a_landing_square_of_another_footprint_names_the_key(runner: CliRunner, tmp_path: Path) -> None:
    run = B.landing_good(tmp_path)
    res = invoke(runner, "land", "simulate", str(run), "--start", "0,0,3", "--set", "uav.footprint_m=[0.5, 0.5]")
    error_line(res, run / "landing.json", "uav.footprint_m = [0.5, 0.5]")
    assert "use the config slz detect used" in res.stderr


@pytest.mark.parametrize("args,option", [
    (["--start", "nan,0,10"], "--start"),      # wrote a bare NaN into metrics.json with exit 0
    (["--start", "0,0,inf"], "--start"),
    (["--start", "0,0"], "--start"),           # was exit 1 from deep inside
    (["--seed", "-1"], "--seed"),              # was "internal error (ValueError ...)"
])
def test_bad_land_simulate_values_are_usage_errors(runner: CliRunner, tmp_path: Path, args: list[str],
                                                   option: str) -> None:
    run = B.landing_good(tmp_path)
    res = invoke(runner, "land", "simulate", str(run), *args)
    assert res.exit_code == 2 and option in res.stderr, res.output
    assert not (run / "ibvs").exists()


@pytest.mark.parametrize("value", ["nan", "inf", "1e300", "0", "-2"])
def test_bad_timeouts_are_usage_errors(runner: CliRunner, tmp_path: Path, value: str) -> None:
    """nan, inf and 1e300 were accepted; the timer then raised OverflowError ("internal error")."""
    rec = B.good(tmp_path, n=2)
    before = set(tmp_path.iterdir())
    for cmd in (["detect", str(rec), "-o", str(tmp_path / "run")], ["compare", str(rec), "-o", str(tmp_path / "c")]):
        res = invoke(runner, *cmd, "--timeout", value)
        assert res.exit_code == 2 and "--timeout" in res.stderr, res.output
    assert set(tmp_path.iterdir()) == before


def test_synth_rate_nan_is_a_usage_error(runner: CliRunner, tmp_path: Path) -> None:
    res = invoke(runner, "synth", "clear_field", "-o", str(tmp_path / "f.mcap"), "--rate", "nan", "--frames", "1")
    assert res.exit_code == 2 and "--rate" in res.stderr
    assert not list(tmp_path.iterdir())


def test_every_json_slz_writes_is_strict(tmp_path: Path) -> None:
    """NaN and inf become null (no value); the writer never emits bare NaN."""
    import math

    from slzcli.outputs.files import json_text, write_json

    obj = {"a": float("nan"), "b": [1.0, float("inf")], "c": np.float32("nan"), "d": np.array([np.nan, 2.0])}
    write_json(tmp_path / "x.json", obj)
    text = (tmp_path / "x.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [1.0, None], "c": None, "d": [None, 2.0]}
    assert json.loads(json_text({"x": -math.inf}, indent=None)) == {"x": None}


# ----------------------------------------------------------------------------- issue 15: read and write errors
def _fail_for(monkeypatch: pytest.MonkeyPatch, target: object, name: str, under: Path, err: int, strerror: str,
              arg: int = 0) -> None:
    """Make ``target.name`` raise OSError(err) when its argument ``arg`` lies under ``under``."""
    import errno as _errno  # noqa: F401 - callers pass errno values

    real = getattr(target, name)

    def fake(*args: object, **kw: object) -> object:
        if str(args[arg]).startswith(str(under)):
            raise OSError(err, strerror)
        return real(*args, **kw)

    monkeypatch.setattr(target, name, fake)


def test_an_unreadable_recording_is_exit_1_and_one_line(runner: CliRunner, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """click pre-checked readability: exit 2 and four usage lines. (Root reads everything, hence the patch.)"""
    import builtins
    import errno

    rec = B.good(tmp_path, n=2)
    _fail_for(monkeypatch, builtins, "open", rec, errno.EACCES, "Permission denied")
    for cmd in (["info", str(rec)], ["detect", str(rec), "-o", str(tmp_path / "run")]):
        error_line(invoke(runner, *cmd), rec, "cannot read (Permission denied)")
    assert not (tmp_path / "run").exists()


def test_an_unreadable_tum_list_names_the_file(runner: CliRunner, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    folder = B.tum_missing_images(tmp_path)
    _fail_for(monkeypatch, os, "open", folder / "rgb.txt", errno.EACCES, "Permission denied")  # bounds.read_regular
    error_line(invoke(runner, "info", str(folder)), folder / "rgb.txt", "rgb.txt: cannot read (Permission denied)")


@pytest.mark.parametrize("where", ["png", "spool", "results_mcap"])
def test_disk_full_during_detect_names_the_file_and_leaves_nothing(runner: CliRunner, tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch,
                                                                   where: str) -> None:
    """ENOSPC was "internal error (OSError: [Errno 28] No space left on device)", no path named."""
    import builtins
    import errno

    from slzcli.outputs import recording

    rec = B.good(tmp_path, n=3)
    out = tmp_path / "out" / "run"
    out.parent.mkdir()
    if where == "png":  # every atomic file write (PNGs, JSON, CSV, PLY, npz)
        _fail_for(monkeypatch, Path, "write_bytes", out.parent, errno.ENOSPC, "No space left on device")
        # overlay.png: the first file a frame folder gets at the default --outputs maps
        cause = "/frames/000000/overlay.png: cannot write (No space left on device)"
    elif where == "spool":
        real_open = builtins.open

        def open_full(file: Any, mode: str = "r", *a: Any, **kw: Any) -> Any:  # builtins.open's many overloads
            if "a" in mode and str(file).startswith(str(out.parent)):
                raise OSError(errno.ENOSPC, "No space left on device")
            return real_open(file, mode, *a, **kw)

        monkeypatch.setattr(builtins, "open", open_full)
        cause = "/.spool/"
    else:
        def write_full(self: object, *a: object) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(recording._McapBackend, "write", write_full)
        cause = "results.mcap: cannot write (No space left on device)"
    res = invoke(runner, "detect", str(rec), "-o", str(out))
    error_line(res, out, cause)
    assert str(out) in res.stderr and ".partial" not in res.stderr  # the run folder's name, not its temporary one
    assert list(out.parent.iterdir()) == []


@pytest.mark.parametrize("where", ["recording", "sidecar", "preview"])
def test_disk_full_during_synth_names_the_file_and_leaves_nothing(runner: CliRunner, tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch,
                                                                  where: str) -> None:
    import errno
    import shutil

    from slzcli.outputs import recording

    def full(*a: object, **kw: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    out = tmp_path / "f.mcap"
    if where == "recording":
        monkeypatch.setattr(recording._McapBackend, "write", full)
        named = "f.mcap: cannot write"
    elif where == "sidecar":
        monkeypatch.setattr(shutil, "copyfileobj", full)
        named = "f.mcap.gt.npz: cannot write"
    else:
        real = Path.write_bytes
        monkeypatch.setattr(Path, "write_bytes", lambda p, data: full() if "preview" in p.name else real(p, data))
        named = "f.mcap.preview.png: cannot write"
    res = invoke(runner, "synth", "clear_field", "-o", str(out), "--frames", "2", *GAUSSIAN)
    error_line(res, out, named)
    assert list(tmp_path.iterdir()) == []  # all or nothing: no recording without its ground truth


def test_a_read_only_batch_folder_names_summary_json(runner: CliRunner, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """PermissionError on summary.json was an internal error. (Patched: root may write anywhere.)"""
    import errno
    import os

    for d in ("a", "b"):
        (tmp_path / d).mkdir()
    recs = [B.good(tmp_path / d, n=2) for d in ("a", "b")]
    out = tmp_path / "ro"
    out.mkdir()
    _fail_for(monkeypatch, os, "open", out, errno.EACCES, "Permission denied")
    _fail_for(monkeypatch, os, "mkdir", out, errno.EACCES, "Permission denied")
    res = invoke(runner, "detect", *map(str, recs), "-o", str(out), "--workers", "1")
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: error:")]
    assert res.exit_code == 1 and len(errors) == 1, res.stderr
    assert "summary.json: cannot write (Permission denied)" in errors[0]
    assert list(out.iterdir()) == []


def test_python_warnings_are_one_line_each_and_repeats_counted(runner: CliRunner, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """numpy RuntimeWarnings reached stderr as 'file.py:196: RuntimeWarning: ...' plus the source line."""
    from slzcli.sources import info_text as it

    real = it.info_text

    def noisy(info: object, *rest: object) -> str:  # info_text(info, depth)
        with np.errstate(invalid="warn"):
            for _ in range(5):
                np.float32(np.inf) - np.float32(np.inf)  # "invalid value encountered in scalar subtract"
        return real(info, *rest)  # type: ignore[arg-type]

    monkeypatch.setattr(it, "info_text", noisy)
    res = invoke(runner, "info", str(B.good(tmp_path, n=2)))
    assert res.exit_code == 0
    warned = warnings_of(res.stderr)
    assert len(warned) == 2, res.stderr
    assert warned[0].startswith("slz: WARNING: RuntimeWarning: invalid value encountered")
    assert "4 repeat(s)" in warned[1]


@pytest.mark.parametrize("writer", ["write_npz", "write_npz_streamed"])
@pytest.mark.parametrize("nth_close", [1, 2])
def test_an_interrupt_while_an_npz_is_written_stays_an_interrupt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                 writer: str, nth_close: int) -> None:
    """A SIGTERM landing in a member's close became ValueError ("Can't close the ZIP file while there is an
    open writing handle") and later "Exception ignored in ZipFile.__del__ ... Traceback" (1 in 16 tries)."""
    import gc
    import sys
    import zipfile

    from slzcli.outputs import files

    unraisable: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: unraisable.append(f"{u.exc_type.__name__} in {u.object}"))
    zip_write_file: Any = zipfile._ZipWriteFile  # type: ignore[attr-defined]  # private, not in typeshed
    real = zip_write_file.close
    calls = {"n": 0}

    def close(self: object) -> None:
        calls["n"] += 1
        if calls["n"] == nth_close:
            raise KeyboardInterrupt  # what the SIGTERM handler raises, at the worst moment
        real(self)

    monkeypatch.setattr(zip_write_file, "close", close)
    arrays = {"x": np.arange(10), "y": np.ones(3)}
    with pytest.raises(KeyboardInterrupt):
        if writer == "write_npz":
            files.write_npz(tmp_path / "a.npz", **arrays)
        else:
            files.write_npz_streamed(tmp_path / "a.npz", dict(arrays))
    gc.collect()
    assert unraisable == [] and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("case,cause", [
    ("out_users_folder", "is not an slz detect run folder"),
    ("out_holds_the_recording", "holds the input"),
    ("out_is_the_input_bag", "is the input recording"),
    ("out_is_a_compare_folder", "is an slz compare folder, not an slz detect run folder"),
])
def test_output_folder_slz_did_not_make_is_refused_and_left_as_it_was(runner: CliRunner, tmp_path: Path, case: str,
                                                                       cause: str) -> None:
    rec, out = B.OUTPUTS[case](tmp_path)
    before = sorted((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in tmp_path.rglob("*"))
    res = invoke(runner, "detect", str(rec), "-o", str(out), "--set", "slam.backend=odometry")
    error_line(res, out, cause)
    assert sorted((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in tmp_path.rglob("*")) == before
