"""The measuring helpers of benchmarks/fusion_matrix.py: the numbers the docs' flight matrix rests on.

The matrix itself runs on rendered flights (minutes of CPU each); these hold what it computes from them: flight
names parse back to their cell, the code hash ignores comments but not code, the calibration reads a stated std
that is right as 1 and one that is half the truth as 2, and the model's step limit orders the motions as the
filter must (more motion, more looks, down to the floor the error fixed to the ground leaves).
"""

from __future__ import annotations

import importlib
import itertools
import math
import sys
from pathlib import Path
from types import ModuleType, SimpleNamespace

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def fm() -> ModuleType:
    sys.path.insert(0, str(BENCH))
    try:
        return importlib.import_module("fusion_matrix")
    finally:
        sys.path.remove(str(BENCH))


@pytest.fixture(scope="module")
def render() -> ModuleType:
    sys.path.insert(0, str(BENCH))
    try:
        return importlib.import_module("fusion_render")
    finally:
        sys.path.remove(str(BENCH))


@pytest.mark.parametrize("scene, alt, sensor, motion", [("clear_field", 7.5, "d435", "4"),
                                                        ("parking_lot", 10.0, "gauss0.003", "hover"),
                                                        ("office", 12.0, "d455", "8")])
def test_a_rendered_flight_name_parses_back_to_its_cell(fm: ModuleType, render: ModuleType, scene: str, alt: float,
                                                        sensor: str, motion: str) -> None:
    name = render.flight_name(scene, alt, sensor, motion, 2, 30, 15.0)
    meta = fm.parse_name(name)
    assert meta == {"scene": scene, "altitude_m": alt, "sensor": sensor,
                    "motion": "hover" if motion == "hover" else float(motion), "seed": 2, "frames": 30, "rate_hz": 15.0}
    assert fm.parse_name("notes") is None


def test_the_code_hash_ignores_comments_and_docstrings_not_code(fm: ModuleType) -> None:
    code = 'def f(x):\n    """Why."""\n    return x + 1  # one\n'
    assert fm._semantic(code) == fm._semantic('def f(x):\n    """Why, moved to tests/top/."""\n    return x + 1\n')
    assert fm._semantic(code) != fm._semantic('def f(x):\n    """Why."""\n    return x + 2\n')
    yaml = "a: 1.0   # m; project\nb: [1, 2]\n"
    assert fm._semantic(yaml, ".yaml") == fm._semantic("a: 1.0   # m; measured\nb: [1, 2]\n", ".yaml")
    assert fm._semantic(yaml, ".yaml") != fm._semantic("a: 2.0\nb: [1, 2]\n", ".yaml")


def _flat_region(h: np.ndarray, var: np.ndarray, cell: float = 0.1) -> SimpleNamespace:
    return SimpleNamespace(shape=h.shape, origin_m=(-5.0, -5.0), cell_m=cell, seen=np.ones(h.shape, bool), h=h,
                           var=var)


@pytest.mark.parametrize("stated_over_true, spread", [(1.0, 1.0), (0.5, 2.0), (2.0, 0.5)])
def test_calibration_reads_the_ratio_of_true_to_stated_error(fm: ModuleType, stated_over_true: float,
                                                             spread: float) -> None:
    """Level ground at 3 m with a depth bias of 0.2 m: the bias is removed, the spread is true / stated std (on 10,000
    cells the robust spread's own scatter is ~1 %: a 5 % margin)."""
    rng = np.random.default_rng(0)
    n = 100
    truth = {"raster_height": np.full((400, 400), 3.0, np.float32), "raster_origin": np.array([-10.0, -10.0]),
             "raster_res": np.float64(0.05)}
    sigma = 0.03
    h = 3.2 + rng.normal(0.0, sigma, (n, n))
    cal = fm.calibration(truth, _flat_region(h, np.full((n, n), (stated_over_true * sigma) ** 2)))
    assert cal is not None and abs(cal["bias_m"] - 0.2) < 0.005
    assert cal["open"]["spread_robust"] == pytest.approx(spread, rel=0.05)
    # no object: the region's outer cells (their neighbours unknown) are not level, the OPEN_CELLS inside them near
    inner = n - 2 * (fm.OPEN_CELLS + 1)
    assert cal["open"]["cells"] == inner * inner
    assert cal["open"]["cells"] + cal["near"]["cells"] == (n - 2) ** 2


def test_calibration_leaves_the_ground_near_an_object_out_of_the_open_figure(fm: ModuleType) -> None:
    """A 1 m box on level ground: cells within OPEN_CELLS of it are "near", the box itself is not level; the open
    figure holds the rest (less the region's rim)."""
    rng = np.random.default_rng(1)
    hr = np.zeros((400, 400), np.float32)
    hr[190:210, 190:210] = 1.0                       # 1 m x 1 m at the centre of the raster (0.05 m pixels)
    truth = {"raster_height": hr, "raster_origin": np.array([-10.0, -10.0]), "raster_res": np.float64(0.05)}
    n = 100
    h = rng.normal(0.0, 0.02, (n, n))
    cal = fm.calibration(truth, _flat_region(h, np.full((n, n), 0.02 ** 2)))
    assert cal is not None and cal["near"] is not None
    # open: the inner square of the flat case less the box, its unlevel ring and OPEN_CELLS around them (a disc
    # of that radius at the corners: between the two squares)
    inner = (n - 2 * (fm.OPEN_CELLS + 1)) ** 2
    assert inner - (12 + 2 * fm.OPEN_CELLS) ** 2 <= cal["open"]["cells"] <= inner - 12 ** 2
    assert cal["open"]["spread_robust"] == pytest.approx(1.0, rel=0.05)


def test_the_model_step_falls_with_motion_to_the_floor(fm: ModuleType) -> None:
    """More motion, more decorrelated looks: hover >= 2 m >= 4 m >= 8 m >= the floor, which is sqrt(fixed_fraction)
    of one frame's limit; a still hover keeps what the shared error holds (at most one frame's limit), and the step
    grows with altitude."""
    from slzcli.config import load_config
    from slzcli.fusion.measure import FusionParams, cell_sigma_m, frame_limit_ratios
    from slzcli.types import DepthNoise

    cfg = load_config(None, [])
    params = FusionParams.from_config(cfg)
    noise = DepthNoise.white(0.0012, "config")
    f = 462.0
    for z in (5.0, 7.5, 10.0):
        steps = [fm.predicted_step_m(noise, z, f, m, 30, cfg, params) for m in (0.0, 2.0, 4.0, 8.0, math.inf)]
        assert all(a >= b for a, b in itertools.pairwise(steps)), steps
        ratio, _ = frame_limit_ratios(noise, z, f, cfg, params)
        one = ratio * float(cell_sigma_m(noise, z, f, params.cell_m))
        assert steps[-1] == pytest.approx(math.sqrt(params.fixed_fraction) * one, rel=1e-9)
        assert steps[0] <= one * (1 + 1e-9)
        assert steps[3] < 0.5 * steps[0]      # 8 m in 30 frames: ~20 decorrelation lengths at these altitudes
    assert fm.predicted_step_m(noise, 10.0, f, 4.0, 30, cfg, params) > fm.predicted_step_m(noise, 5.0, f, 4.0, 30, cfg,
                                                                                          params)
