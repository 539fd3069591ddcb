"""What a detection frame writes (``output.level`` / ``slz detect --outputs``), maps.npz's precision,
the write time in the summary, and a failing frame write (issue part 6).

Recordings are the small textured flights of the bad-input corpus, tracked by the odometry backend,
with every frame a detection.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path

import bad_inputs as B
import numpy as np
import pytest
from click.testing import CliRunner

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.outputs import files, run_folder
from slzcli.outputs.recording import RecordingWriter

EVERY = ("--set", "slam.backend=odometry", "--set", "landing.detect_on=every_nth",
         "--set", "landing.every_nth_frame=1")
RUN_FILES = {"run.json", "landing.json", "sites.csv", "points.ply", "trajectory.tum", "keyframes.npz", "results.mcap",
             "report.html"}
HEATMAPS = {"depth_variance.png", "flatness.png", "inclination.png", "steepness.png", "score.png", "mask.png"}
FRAME_FILES = {"summary": None, "maps": {"maps.npz", "overlay.png"}, "all": {"maps.npz", "overlay.png", *HEATMAPS}}
# float16 keeps 11 significant bits: a value v comes back within |v| * 2**-11 (round to nearest); the
# smallest normal float16 is 2**-14, below it the step is 2**-24.
F16_RTOL, F16_ATOL = 2.0**-11, 2.0**-24


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "flight"
    with RecordingWriter(path, "ros2-mcap") as w:
        for i in range(4):
            w.write_frame(B.textured_frame(i))
    return path


def detect(flight: Path, out: Path, *extra: str):
    res = CliRunner().invoke(main, ["detect", str(flight), "-o", str(out), *EVERY, *extra])
    assert "Traceback" not in res.output and "internal error" not in res.stderr, res.stderr
    return res


@pytest.mark.parametrize("level", ["summary", "maps", "all"])
def test_the_level_decides_which_files_a_run_writes(flight, tmp_path, level) -> None:
    out = tmp_path / "run"
    res = detect(flight, out, "--outputs", level)
    assert res.exit_code == 0, res.stderr
    names = {p.name for p in out.iterdir()}
    assert names >= RUN_FILES
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["output"]["level"] == run["summary"]["outputs"] == level
    if FRAME_FILES[level] is None:
        assert "frames" not in names
        return
    folders = sorted((out / "frames").iterdir())
    assert len(folders) == run["summary"]["detections"] == 4
    for folder in folders:
        assert {p.name for p in folder.iterdir()} == FRAME_FILES[level], folder


def test_the_default_level_is_maps_and_the_level_is_in_the_rerun_key(flight, tmp_path) -> None:
    assert load_config().output.level == "maps"
    out = tmp_path / "run"
    assert detect(flight, out).exit_code == 0
    assert detect(flight, out, "--outputs", "maps").exit_code == 0  # the same key: skipped
    assert "skipped" in detect(flight, out, "--outputs", "maps").stdout
    refused = detect(flight, out, "--outputs", "all")
    assert refused.exit_code == 1 and "output.level 'maps' -> 'all'" in refused.stderr, refused.stderr
    assert detect(flight, out, "--outputs", "all", "--force").exit_code == 0
    assert (out / "frames" / "000000" / "flatness.png").is_file()
    assert detect(flight, out, "--outputs", "summary", "--force").exit_code == 0
    assert not (out / "frames").exists()  # the old run's frames/ goes with it


def test_maps_npz_gives_back_the_arrays_to_the_documented_precision(flight, tmp_path, monkeypatch) -> None:
    seen = []
    write = run_folder.write_detection

    def keep(run, det, cfg, *rest) -> None:
        seen.append(det)
        write(run, det, cfg, *rest)

    monkeypatch.setattr(run_folder, "write_detection", keep)
    out = tmp_path / "run"
    assert detect(flight, out).exit_code == 0
    assert len(seen) == 4
    for det in seen:
        with np.load(out / "frames" / f"{det.frame.index:06d}" / "maps.npz") as z:
            got = {k: z[k] for k in z.files}
        want = {"score": det.score.score, "mask": det.score.mask, "valid": det.maps.valid,
                "slope_deg": det.maps.slope_deg, "edge_distance_m": det.edge_m, **det.maps.as_dict()}
        assert set(got) == set(want)
        assert np.array_equal(got["score"], want["score"], equal_nan=True) and got["score"].dtype == np.float32
        assert got["mask"].dtype == got["valid"].dtype == np.bool_
        assert np.array_equal(got["mask"], want["mask"]) and np.array_equal(got["valid"], want["valid"])
        for name in set(want) - {"score", "mask", "valid"}:
            assert got[name].dtype == np.float16 and got[name].shape == want[name].shape, name
            assert np.allclose(got[name], want[name], rtol=F16_RTOL, atol=F16_ATOL, equal_nan=True), name
            assert np.array_equal(np.isnan(got[name]), np.isnan(want[name])), name


def test_the_summary_line_and_run_json_show_the_write_time(flight, tmp_path) -> None:
    out = tmp_path / "run"
    res = detect(flight, out)
    assert res.exit_code == 0, res.stderr
    line = next(ln for ln in res.stdout.splitlines() if "per frame:" in ln)
    write_ms = json.loads((out / "run.json").read_text())["summary"]["timings_ms"]["write"]
    assert f"write {write_ms:.1f} ms" in line, line
    assert write_ms > 0  # four frames were written: the stage was timed
    assert "frames/ (maps.npz, overlay.png)" in res.stdout


def test_a_failing_frame_write_is_one_line_naming_the_file_and_leaves_nothing(flight, tmp_path, monkeypatch) -> None:
    def disk_full(path, members, stored=frozenset()):
        with files.atomic_path(path) as tmp:
            tmp.write_bytes(b"half an archive")
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files, "write_npz_streamed", disk_full)
    out = tmp_path / "run"
    res = detect(flight, out)
    assert res.exit_code == 1
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: error:")]
    assert len(errors) == 1, res.stderr
    assert str(out / "frames" / "000000" / "maps.npz") in errors[0] and "No space left" in errors[0], errors[0]
    assert list(tmp_path.iterdir()) == []  # no run folder, no .run.*.partial
