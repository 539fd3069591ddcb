"""Shared fixtures: where the repo and ../shared live, and a CLI runner."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
REALSENSE = SHARED / "data" / "realsense_floor"


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture
def realsense_dir() -> Path:
    if not (REALSENSE / "cam_params_realsense.json").is_file():
        pytest.skip(f"real RealSense frames not found at {REALSENSE}")
    return REALSENSE
