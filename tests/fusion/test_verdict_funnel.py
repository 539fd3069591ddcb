"""Why the fused verdict calls nothing safe (slzcli/fusion/funnel.py): the test that left no cell, in words.

Scenes from tests/fusion_scene.py; every reading below was measured on seeds 0-2 (beside each limit).
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
from fusion_scene import fly

from slzcli.fusion.funnel import CELL_STEPS
from slzcli.fusion.verdict import SAFE

SEEDS = range(3)
QUIET: dict[str, Any] = {"a_per_m": 0.0005, "white": 0.2, "corr_px": 2.0}   # one pixel's std 3 cm at 8 m
SCENES: dict[str, tuple[list[str], dict[str, Any]]] = {
    "level": ([], {**QUIET, "frames": 20, "step_m": 0.2}),
    "slope": ([], {**QUIET, "frames": 20, "step_m": 0.2, "slope_deg": 30.0}),
    "hover": ([], {"a_per_m": 0.002, "white": 0.2, "corr_px": 2.0, "frames": 20, "step_m": 0.0}),
    # 1.5 m up the view is ~1.6 m across, narrower than a landing square with the maps' windows (2.4 m)
    "narrow": ([], {**QUIET, "frames": 30, "step_m": 0.1, "altitude_m": 1.5}),
    # a small UAV (0.2 m footprint, so its square fits the view) 1.8 m up, under its 2 m descent column
    "column": (["uav.footprint_m=[0.2,0.2]", "mask.smooth_m=0", "terrain.inclination.radius_m=0.15"],
               {**QUIET, "frames": 30, "step_m": 0.1, "altitude_m": 1.8, "region_m": 5.0}),
}


def _last(scene: str, seed: int) -> tuple[Any, Any]:
    sets, kw = SCENES[scene]
    *_, (_, ft, fm) = fly(sets, seed=seed, **kw)
    return ft, fm


@pytest.mark.parametrize("scene", list(SCENES))
def test_the_counts_are_the_verdicts_tests_in_order(scene: str) -> None:
    """Each count is what the tests before it left (non-increasing), the first the seen cells, the last the SAFE
    ones; a scene with safe cells has no test that emptied it."""
    for seed in SEEDS:
        _, fm = _last(scene, seed)
        f = fm.funnel
        assert len(f.left) == len(CELL_STEPS)
        assert list(f.left) == sorted(f.left, reverse=True)
        assert f.left[0] == int(np.count_nonzero(fm.region.seen))
        assert f.left[-1] == int(np.count_nonzero(fm.verdict == SAFE))
        assert (f.left[-1] > 0) == (f.emptied_by() is None)


def test_steep_ground_names_its_slope_and_the_camera_tilt() -> None:
    """A 30 deg slope seen from 8 m: the score left no cell, the lowest map is steepness, the ground reads 30 deg
    (seeds 0-2: 30) and the reason says to give the camera's tilt if it does not look straight down."""
    for seed in SEEDS:
        ft, fm = _last("slope", seed)
        assert fm.funnel.emptied_by() == "score"
        why = fm.why_none(ft.depth_m)
        assert "lowest of the four maps" in why and "is steepness" in why
        slope = float(re.search(r"slopes a median (\d+) deg", why).group(1))  # type: ignore[union-attr]
        assert 25 <= slope <= 35
        assert "camera.mount" in why


def test_noise_read_as_a_slope_is_not_blamed_on_the_ground() -> None:
    """A hover over level ground with noisy depth: the plane over the footprint reads 13 deg (seeds 0-2), within
    the 40-41 deg the fused noise hides; the reason says the noise may be what slopes, not to tilt the camera."""
    for seed in SEEDS:
        ft, fm = _last("hover", seed)
        assert fm.funnel.emptied_by() == "score"
        why = fm.why_none(ft.depth_m)
        assert "the noise, not the ground, may be what slopes" in why
        assert "camera.mount" not in why


def test_a_view_narrower_than_the_landing_square_says_so() -> None:
    """From 1.5 m the strip seen is narrower than a landing square with its windows: the score passes on 278 cells
    (seeds 0-2), none decided because none has its square seen whole, which the reason says (not the noise), with
    the camera below the descent column named too, and no advice promises frames that would not decide it."""
    for seed in SEEDS:
        ft, fm = _last("narrow", seed)
        assert fm.funnel.emptied_by() == "decided" and fm.funnel.covered == 0
        why = fm.why_none(ft.depth_m)
        assert "narrower than a landing square" in why and "noise" not in why
        assert "outside this UAV's envelope" in why
        # no "N more frames": the noise is not what holds these squares (the advice said "1 more frame")
        assert ft.advice(fm) is None


def test_below_the_descent_column_names_the_column() -> None:
    """A 0.2 m UAV 1.8 m up: 9152 cells (seeds 0-2) pass every test but the 2 m descent column, which no frame
    saw; the reason names the column and the camera's 1.8 m."""
    for seed in SEEDS:
        ft, fm = _last("column", seed)
        assert fm.funnel.emptied_by() == "column" and fm.funnel.left[4 - 1] > 0
        why = fm.why_none(ft.depth_m)
        assert "column above the ground (from control.desired_depth_m 2 m up) was seen clear" in why
        assert "camera was 1.8 m from the ground" in why
        assert ft.advice(fm) is None   # more frames from 1.8 m never see the column (the advice said "1 more frame")


def _funnel(left: tuple[int, ...], **kw: Any) -> Any:
    from slzcli.fusion.funnel import CellFunnel

    base: dict[str, Any] = {"threshold": 0.5, "best_score": 0.4, "whole": left[0], "window_m": 0.7, "covered": 0,
                            "decided_window_m": 2.4, "unsafe": 0, "max_step_m": 0.09, "max_slope_deg": 15.0,
                            "column_m": 2.0}
    return CellFunnel(left, **{**base, **kw})


def test_each_test_that_can_empty_the_funnel_is_named() -> None:
    """The text for the tests no synthetic scene above empties first (the tolerances, a raised surface), the first
    empty test after a non-empty one, and the envelope note only below the column and without a safe cell."""
    assert _funnel((0, 0, 0, 0, 0, 0)).text() == "no cell in view was measured"
    assert _funnel((0, 0, 0, 0, 0, 0)).emptied_by() is None
    tol = _funnel((90, 60, 40, 0, 0, 0))
    assert tol.emptied_by() == "tolerances"
    assert tol.text().startswith("every one of the 40 decided cells holds in its landing square a step or a slope "
                                 "that its noise limit added puts beyond the UAV's tolerance")
    raised = _funnel((90, 60, 40, 30, 20, 0))
    assert raised.emptied_by() == "safe"
    assert raised.text() == "the 20 cells that pass every other test lie on surfaces the raised-surface rule refused"
    noisy = _funnel((90, 60, 0, 0, 0, 0), covered=12)
    assert noisy.text().endswith("all undecided: the fused depth noise still hides a step or slope the UAV cannot "
                                 "take there")
    assert "outside this UAV's envelope" in noisy.text(camera_depth_m=1.2)
    assert "outside this UAV's envelope" not in noisy.text(camera_depth_m=2.5)
    some = _funnel((90, 60, 40, 30, 20, 10))
    assert some.emptied_by() is None and some.text(camera_depth_m=1.2) == "10 of the 90 cells in view are safe"
