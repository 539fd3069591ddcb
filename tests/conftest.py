"""Shared fixtures: where the repo and ../shared live, and a CLI runner."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from slzcli import interrupt

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
# the real frames: beside the checkout, or wherever SLZ_REALSENSE_DIR says (a clone elsewhere)
REALSENSE = Path(os.environ.get("SLZ_REALSENSE_DIR") or SHARED / "data" / "realsense_floor")
# Tests of the pipeline, not of the depth sensor, render with the gaussian model: the default stereo
# model (an infrared pair matched with SGBM) costs ~3x more per frame; the sensor models have their
# own tests (test_synth_sensor.py) and the default sensor runs end to end in test_sensor_cells.py and
# test_packaging.py.
GAUSSIAN = ("--set", "synth.sensor.model=gaussian")
# Half the default camera (320 x 240, the same field of view) for tests of formats and contracts, not of accuracy:
# a quarter of the pixels to render and detect.
HALF_SIZE = ("--set", "camera.width=320", "--set", "camera.height=240", "--set", "camera.fx=231.0685",
             "--set", "camera.fy=231.0685", "--set", "camera.cx=160", "--set", "camera.cy=120")


def synth_recording(path: Path, scene: str, frames: int, *options: str) -> Path:
    """``slz synth SCENE -o PATH --frames N OPTIONS`` through the CLI (the module fixtures' recordings)."""
    from slzcli.cli import main

    res = CliRunner().invoke(main, ["synth", scene, "-o", str(path), "--frames", str(frames), *options])
    assert res.exit_code == 0, res.output
    return path


# Test files that run whole commands on rendered recordings (synth, detect, compare, batch, SLAM) or whole
# simulated descents, and the property tests (measured: each such test 10-50 s on a loaded machine): marked
# ``slow``, left out by ``make test-fast`` (the edit-run loop); ``make test`` runs everything. A test
# elsewhere can be marked on its own with ``@pytest.mark.slow``. Base names: each is unique across tests/ folders.
SLOW_FILES = frozenset({
    "test_api.py", "test_bad_inputs.py", "test_batch.py", "test_bounds.py", "test_column.py", "test_compare.py",
    "test_control_cli.py", "test_control_montecarlo.py", "test_control_simulate.py", "test_properties.py",
    "test_core.py", "test_detect.py", "test_docs.py", "test_json_schema.py", "test_limits.py", "test_monocular.py",
    "test_outputs_frames.py", "test_outputs_report.py", "test_packaging.py", "test_profiles.py", "test_px4slp.py",
    "test_run_assembly.py", "test_sensor_cells.py", "test_slam.py", "test_slam_segments.py", "test_synth.py",
    "test_synth_sensor.py", "test_timeout.py", "test_touchdown_dispersion.py", "test_user_files.py",
    "test_window.py", "test_writes.py", "test_fused.py", "test_raised_cli.py", "test_tilt_cli.py", "test_same_bits.py",
})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name in SLOW_FILES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _own_computations(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test sees only the computations it started. A stage an earlier test left running in its daemon
    thread (a timed-out or interrupted one) would make ``interrupt.abandoned()`` true for a later test in the same
    worker, and the CLI would then leave through ``os._exit`` (right for a real slz process, which has nothing
    else to do), ending the pytest worker instead of returning exit code 130."""
    monkeypatch.setattr(interrupt, "_running", set())


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture
def realsense_dir() -> Path:
    if not (REALSENSE / "cam_params_realsense.json").is_file():
        pytest.skip(f"real RealSense frames not found at {REALSENSE}")
    return REALSENSE


@contextlib.contextmanager
def fusion_spy() -> Iterator[list[tuple[str, Any]]]:
    """(method, Detection) of every detection each method makes inside the block (``pipeline.step.detect_one``):
    what a test of `slz compare` checks beyond its JSON (the detections themselves, per method)."""
    from slzcli.pipeline import step

    seen: list[tuple[str, Any]] = []
    original = step.detect_one

    def spy(method: Any, *args: Any, **kwargs: Any) -> Any:
        d = original(method, *args, **kwargs)
        seen.append((method.name, d))
        return d

    mp = pytest.MonkeyPatch()
    mp.setattr(step, "detect_one", spy)
    try:
        yield seen
    finally:
        mp.undo()
