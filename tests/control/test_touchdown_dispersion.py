"""uav.touchdown_dispersion_m: the landing simulation's p95 touch-down error added to the site's clearance.

`slz land simulate --runs N` measures where the UAV really touches down around a site; `slz detect
--set uav.touchdown_dispersion_m=<p95>` adds that to `uav.margin_m` on every side of the footprint,
so the mask (and slz synth's ground truth, tests/synth/test_synth.py) keep that much more clearance.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.control.montecarlo import table
from slzcli.scoring import MaskParams, get_scorer, mask_score
from slzcli.types import Intrinsics

K = Intrinsics(fx=320.0, fy=320.0, cx=159.5, cy=119.5, width=320, height=240)
UP = np.array([0.0, 0.0, -1.0])   # world up in a camera looking straight down
ALTITUDE_M = 5.0
HALF_OPEN_M = 1.0                 # the good ground: a 2 m x 2 m square under the camera


def _open_square_score() -> np.ndarray:
    u = (np.arange(K.width) - K.cx) * ALTITUDE_M / K.fx
    v = (np.arange(K.height) - K.cy) * ALTITUDE_M / K.fy
    return ((np.abs(u)[None, :] < HALF_OPEN_M) & (np.abs(v)[:, None] < HALF_OPEN_M)).astype(np.float32)


@pytest.mark.parametrize("dispersion_m", [0.0, 0.1, 0.2, 0.3])
def test_dispersion_shrinks_the_mask_by_its_plan_width(dispersion_m: float) -> None:
    """Level ground, score 1 on a 2 m square: the mask is the square eroded by half the filter side, so its
    plan width is 2 - (0.656 + 2 (margin + dispersion)). Measured widths (row, column) for dispersion 0, 0.1,
    0.2, 0.3 m: (1.06, 0.95), (0.78, 0.80), (0.63, 0.63), (0.36, 0.38) m against analytic 1.14, 0.94, 0.74, 0.54:
    short by 0.08-0.19 m, from the plan raster's cells (side / 8 = 0.107-0.182 m) straddling the square's edge on
    both sides. Limits: at most the analytic width + 1 pixel, at least analytic - 2 cells - 1 pixel."""
    cfg = load_config(None, [f"uav.touchdown_dispersion_m={dispersion_m}"])
    assert cfg.uav.clearance_m == pytest.approx(cfg.uav.margin_m + dispersion_m)
    sm = mask_score(get_scorer(cfg.scoring, cfg.mask), _open_square_score(),
                    np.full((K.height, K.width), ALTITUDE_M, np.float32), K, MaskParams.of(cfg), up_camera=UP)
    side = max(cfg.uav.footprint_m) * cfg.mask.margin_factor + 2 * cfg.uav.clearance_m
    analytic = 2 * HALF_OPEN_M - side
    cell, px = side / cfg.mask.plan_cells_per_footprint, ALTITUDE_M / K.fx
    for width in (sm.mask[int(K.cy)].sum() * px, sm.mask[:, int(K.cx)].sum() * px):
        assert analytic - 2 * cell - px <= width <= analytic + px


def test_montecarlo_text_prints_the_detect_override() -> None:
    from slzcli.control.montecarlo import PERCENTILES, SUMMARY_FIELDS
    empty = {"count": 0, "mean": None, **{f"p{p}": None for p in PERCENTILES}}
    summary = {"runs": 1, "successes": 1, "success_rate": 1.0, "failures": {},
               **{name: empty for name in SUMMARY_FIELDS}, "landing_dispersion_p95_m": 0.123}
    assert "slz detect --set uav.touchdown_dispersion_m=0.13`" in table(summary)


def test_detect_takes_the_dispersion_through_the_cli(runner, tmp_path: Path) -> None:
    """The same recording detected with 0 and 0.1 m dispersion: the larger clearance's mask lies inside the
    smaller one's and is smaller (playground at 5 m: the rims around its obstacles widen; measured 6064 -> 3660
    safe pixels, seed 0), and run.json records it."""
    rec = tmp_path / "r.mcap"
    res = runner.invoke(main, ["synth", "playground", "-o", str(rec), "--frames", "1", "--start", "0,0,5", *GAUSSIAN])
    assert res.exit_code == 0, res.output
    masks = []
    for d in (0.0, 0.1):
        out = tmp_path / f"run{d}"
        res = runner.invoke(main, ["detect", str(rec), "-o", str(out), "--set", f"uav.touchdown_dispersion_m={d}"])
        assert res.exit_code == 0, res.output
        assert json.loads((out / "run.json").read_text())["config"]["uav"]["touchdown_dispersion_m"] == d
        masks.append(np.load(out / "frames" / "000000" / "maps.npz")["mask"])
    assert masks[0].sum() > masks[1].sum() > 0
    assert not (masks[1] & ~masks[0]).any()


def test_a_negative_dispersion_is_refused_in_one_line(runner) -> None:
    res = runner.invoke(main, ["config", "dump", "--set", "uav.touchdown_dispersion_m=-0.1"])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "uav.touchdown_dispersion_m" in lines[0] and "Traceback" not in res.stderr
