"""The Python API (``slzcli.detect``, ``slzcli.load_config``, the types): the docs/USAGE.md example runs as written,
frames in memory write nothing, a recording gives the same site in memory, in a run folder and through the CLI."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, HALF_SIZE, REPO, synth_recording

import slzcli
from slzcli.cli import main
from slzcli.errors import ConfigError, DatasetError


def readme_example() -> str:
    text = (REPO / "docs" / "USAGE.md").read_text()
    section = text[text.index("## Python API"):]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "no python block under ## Python API"
    return match.group(1)


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    # half size: the API and its agreement with the CLI are held here, not accuracy
    return synth_recording(tmp_path_factory.mktemp("api") / "flight.mcap", "clear_field", 6, *GAUSSIAN, *HALF_SIZE)


def test_readme_example_runs_as_written(flight: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    for f in flight.parent.iterdir():  # the example's flight.mcap (and its ground truth) in the folder it runs in
        (tmp_path / f.name).symlink_to(f)
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    exec(compile(readme_example(), "docs/USAGE.md", "exec"), namespace)  # our own docs
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("site [") and printed[1] == "site site", printed
    assert (tmp_path / "runs" / "flight" / "run.json").is_file()      # the out_dir call, as slz detect -o
    run = namespace["run"]
    assert isinstance(run, slzcli.RunResult) and run.summary["frames"] == 6


def test_frames_in_memory_write_nothing(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    K = slzcli.Intrinsics(fx=230.0, fy=230.0, cx=160.0, cy=120.0, width=320, height=240)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (0.0, 0.0, 10.0)
    rng = np.random.default_rng(1)

    def frames():  # a generator: frames stream in, as from a driver
        for i in range(3):
            yield slzcli.Frame(i, 10**9 + i * 33_333_333, rng.integers(0, 256, (240, 320, 3), dtype=np.uint8),
                               np.full((240, 320), 10.0, dtype=np.float32), K, T)

    result = slzcli.detect(frames())
    assert list(tmp_path.iterdir()) == []
    s = result.summary
    assert (s["source"], s["frames"], s["status"], s["slam_backend"]) == ("<frames>", 3, "site", "recorded")
    assert abs(s["site_world"][2]) < 0.05            # on the flat ground at z = 0 (10 m below the camera)
    assert result.landing["status"] == "site" and result.run["recording"]["format"] == "frames"
    with pytest.raises(DatasetError, match="no frame given"):
        slzcli.detect([])
    with pytest.raises(DatasetError, match="out_dir needs a recording path"):
        slzcli.detect(frames(), out_dir=tmp_path / "run")


def test_a_recording_in_memory_in_a_run_folder_and_through_the_cli_agree(flight: Path, tmp_path: Path,
                                                                         runner) -> None:
    # the built-in odometry: deterministic, where ORB-SLAM3's threads gave three runs different sites under load
    config = slzcli.load_config(overrides=["sources.window.max_frames=4", "slam.backend=odometry"])
    memory = slzcli.detect(flight, config)
    folder = slzcli.detect(str(flight), config, out_dir=tmp_path / "run")
    res = runner.invoke(main, ["detect", str(flight), "-o", str(tmp_path / "cli"), "--max-frames", "4", "--json",
                               "--set", "slam.backend=odometry"])
    assert res.exit_code == 0, res.output
    cli = json.loads(res.stdout)
    assert memory.summary["site_world"] == folder.summary["site_world"]
    assert cli["site_world"] == pytest.approx(memory.summary["site_world"], abs=1e-6)   # --json rounds to 1e-6
    assert memory.summary["frames"] == folder.summary["frames"] == cli["frames"] == 4
    assert memory.landing["site"]["corners_world"] == folder.landing["site"]["corners_world"]
    assert "ground_truth" in memory.summary       # the synth sidecars are read in memory too
    assert not list(flight.parent.glob("runs"))   # nothing written beside the recording


def test_load_config_layers_a_file_and_overrides(tmp_path: Path) -> None:
    user = tmp_path / "my.yaml"
    user.write_text("mask:\n  threshold: 0.7\n")
    config = slzcli.load_config(user, ["landing.kmeans_k=4"])
    assert isinstance(config, slzcli.Config)
    assert config.mask.threshold == 0.7 and config.landing.kmeans_k == 4
    with pytest.raises(ConfigError) as err:
        slzcli.load_config(overrides=["mask.nope=1"])
    assert err.value.key == "mask.nope" and isinstance(err.value, slzcli.SlzError)


def test_import_slzcli_is_light() -> None:
    """The package and the command line import without numpy, OpenCV or SLAM (they load on first use)."""
    code = ("import sys, slzcli; heavy = [m for m in ('numpy', 'cv2', 'open3d', 'click') if m in sys.modules]; "
            "print(heavy); slzcli.detect, slzcli.Frame; print('numpy' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[:2] == ["[]", "True"]
    proc = subprocess.run([sys.executable, "-c", "import sys, slzcli.cli; print('numpy' in sys.modules)"],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "False", proc.stdout + proc.stderr
    with pytest.raises(AttributeError):
        slzcli.no_such_name  # noqa: B018
