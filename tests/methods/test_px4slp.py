"""px4slp, the PX4-Avoidance safe_landing_planner grid (issue 21): its documented behaviour on analytic inputs,
its site rule, and the three-way ``slz compare`` through the CLI.

The analytic clouds are dense regular lattices (or seeded Gaussian noise), so every expectation follows
from upstream's formulas: a 0.25 m cell of a 1 cm lattice holds 625 points.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, fusion_spy, synth_recording

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.landing.px4slp import choose_patch, grid_site, patch_disk, search_offsets
from slzcli.scoring.px4slp import Px4SlpMemory, Px4SlpParams, Px4SlpPlanner, cell_statistics, update
from slzcli.types import Intrinsics

P = Px4SlpParams.from_config(load_config().scoring.px4slp)   # upstream's defaults (SafeLandingPlannerNode.cfg)
ORIGIN = np.zeros(3)


def lattice(half_m: float = 4.995, step_m: float = 0.01) -> np.ndarray:
    """(N, 2) world x, y of a regular lattice covering the grid around the origin (625 points a cell)."""
    g = np.arange(-half_m, half_m + 1e-9, step_m)
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.stack([x.ravel(), y.ravel()], axis=1)


def cloud(z: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return np.column_stack([xy, z])


def test_defaults_are_upstreams() -> None:
    """SafeLandingPlannerNode.cfg / WaypointGeneratorNode.cfg defaults, and the 40 x 40 grid they give."""
    assert (P.grid_size_m, P.cell_size_m, P.n_points_threshold, P.std_dev_threshold_m) == (10.0, 0.25, 100.0, 0.2)
    assert (P.smoothing_size, P.mean_diff_thr_m, P.max_n_mean_diff_cells, P.min_n_land_cells) == (5, 0.1, 70, 70)
    assert (P.alpha, P.beta, P.can_land_thr, P.smoothing_land_cell) == (0.9, 0.9, 0.4, 6)
    assert P.cells == 40


def test_binning_reproduces_upstreams_unit_test() -> None:
    """test_safe_landing_planner.cpp ``binning_10_1``: vehicle at (4.2, 3.9), 10 m grid of 1 m cells, alpha 0."""
    p = replace(P, cell_size_m=1.0, alpha=0.0)
    pts = np.array([(-4.6, -2.1, 1.213), (15.2, -13.4, 0.987), (4.2, 3.9, 1.145), (-0.5, -1.0, 1.198),
                    (8.9, 8.6, 1.065), (4.2, 2.0, 1.287), (9.1, 8.5, 1.047), (8.7, 8.0, 1.134), (8.7, 8.0, 1.144),
                    (8.7, 8.0, 1.104), (8.7, 8.0, 1.110)])
    st = update(None, pts, np.array([4.2, 3.9, 5.0]), 0, p)
    v = np.array([1.065, 1.047, 1.134, 1.144, 1.104, 1.110])
    assert st.mean[0, 0] == pytest.approx(1.198)
    assert st.mean[9, 9] == pytest.approx(v.mean())
    assert st.mean[5, 3] == pytest.approx(1.287) and st.mean[5, 5] == pytest.approx(1.145)
    assert st.variance[9, 9] == pytest.approx(v.var(), abs=1e-9)   # population variance (Welford's M2 / n)
    assert st.counter.sum() == 9   # the two points outside the grid are dropped


def test_flat_plane_is_landable_and_the_site_is_under_the_vehicle() -> None:
    xy = lattice()
    st = update(None, cloud(np.full(len(xy), -5.0), xy), ORIGIN, 0, P)
    assert st.counter[1:-1, 1:-1].min() >= 600
    # Every cell whose 11 x 11 neighbourhood lies in the grid; the zero padding of the vote leaves the
    # outer ring at most 6 x 11 = 66 land-able neighbours (more than 70 needed) and the corner (1, 1)
    # 7 x 7 = 49, as upstream.
    assert st.land[5:-5, 5:-5].all() and not st.land[0].any() and not st.land[:, -1].any() and not st.land[1, 1]
    assert choose_patch(st.hysteresis > P.can_land_thr, P.smoothing_land_cell) == (0, 0)


def test_a_0_3_m_step_rejects_the_cell_it_cuts_not_the_cells_beside_it() -> None:
    """Upstream's vote rejects a cell only when more than 70 of its 121 neighbours differ by > 0.1 m.

    A 0.3 m step through the middle of a cell column: that column's mean (0.18 m) differs from both
    levels by more than 0.1 m, so all its 121 neighbours but its own column differ: rejected. A column
    beside it has at most 6 x 11 = 66 differing neighbours: land-able. A step on a cell boundary
    rejects nothing (no cell holds both levels, and a 0.3 m step's per-cell std is at most 0.15 m).
    """
    xy = lattice()
    mid = update(None, cloud(np.where(xy[:, 0] > 0.1, 0.3, 0.0), xy), ORIGIN, 0, P)   # cuts column 20 (0..0.25 m)
    assert np.sqrt(mid.variance[20, 1:-1]).max() < P.std_dev_threshold_m     # the per-cell test passes
    assert not mid.land[20, :].any()                                         # the vote rejects it
    assert mid.land[19, 5:-5].all() and mid.land[21, 5:-5].all()            # the cells beside it are land-able
    edge = update(None, cloud(np.where(xy[:, 0] > 0.0, 0.3, 0.0), xy), ORIGIN, 0, P)
    assert edge.land[5:-5, 5:-5].all()
    # The site rule keeps its disk off the rejected column: the first disk on the search rays that
    # avoids row 20 is 7 cells along +x (rings 1-6 of every direction still cover it).
    assert choose_patch(mid.hysteresis > P.can_land_thr, P.smoothing_land_cell) == (7, 0)
    # A raised 0.3 m strip 1 m wide (4 cells): its cells differ from 77 of their neighbours, rejected;
    # the ground beside it is land-able.
    strip = update(None, cloud(np.where(np.abs(xy[:, 0]) < 0.5, 0.3, 0.0), xy), ORIGIN, 0, P)
    assert not strip.land[18:22, :].any() and strip.land[17, 5:-5].all() and strip.land[22, 5:-5].all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_above_the_std_threshold_makes_every_cell_not_landable(seed: int) -> None:
    xy = lattice()
    rng = np.random.default_rng(seed)
    noisy = update(None, cloud(rng.normal(0.0, 0.25, len(xy)), xy), ORIGIN, 0, P)
    # 625 samples a cell: smallest cell std measured 0.223, 0.225, 0.228 (seeds 0-2; 0.2 is > 3 sigma below)
    assert np.sqrt(noisy.variance).min() > P.std_dev_threshold_m
    assert not noisy.land.any()
    assert choose_patch(noisy.hysteresis > P.can_land_thr, P.smoothing_land_cell) is None
    quiet = update(None, cloud(rng.normal(0.0, 0.15, len(xy)), xy), ORIGIN, 0, P)   # largest cell std 0.163-0.166
    assert quiet.land[5:-5, 5:-5].all()


@pytest.mark.parametrize(("slope_deg", "landable"), [(11.0, True), (12.0, False)])
def test_the_vote_is_an_implicit_slope_limit(slope_deg: float, landable: bool) -> None:
    """A ramp along x: cells two columns apart (0.5 m) differ by 0.5 tan(slope), over 0.1 m from 11.3 deg;
    then 8 of the 11 columns (88 > 70 neighbours) differ. The per-cell std stays ~0.015 m."""
    xy = lattice(step_m=0.02)
    st = update(None, cloud(xy[:, 0] * np.tan(np.radians(slope_deg)), xy), ORIGIN, 0, P)
    assert np.sqrt(st.variance[5:-5, 5:-5]).max() < 0.02
    assert st.land[5:-5, 5:-5].all() if landable else not st.land[5:-5, 5:-5].any()


def test_too_few_points_in_a_cell_is_not_landable() -> None:
    xy = lattice(step_m=0.05)   # 25 points a cell, n_points_threshold is 100
    st = update(None, cloud(np.zeros(len(xy)), xy), ORIGIN, 0, P)
    assert st.counter.max() == 25 and not st.land.any()
    assert update(None, cloud(np.zeros(len(xy)), xy), ORIGIN, 0, replace(P, n_points_threshold=25)).land[5:-5,
                                                                                                         5:-5].all()


def test_time_smoothing_with_alpha_and_the_warm_start() -> None:
    xy = lattice()
    first = update(None, cloud(np.zeros(len(xy)), xy), ORIGIN, 0, P)
    assert np.allclose(first.mean, 0.0)
    second = update(first, cloud(np.full(len(xy), 1.0), xy), ORIGIN, 0, P)
    assert np.allclose(second.mean, 0.9 * 0.0 + 0.1 * 1.0)                  # alpha x previous + (1 - alpha) x now
    third = update(second, cloud(np.full(len(xy), 1.0), xy), ORIGIN, 0, P)
    assert np.allclose(third.mean, 0.9 * 0.1 + 0.1 * 1.0)
    # The variance is low-passed the same way (per-frame variance 0 on a plane, ~0.25^2 for a 0 / 0.5 m mix).
    z_mix = np.where(np.arange(len(xy)) % 2 == 0, 0.0, 0.5)
    mixed = update(third, cloud(z_mix, xy), ORIGIN, 0, P)
    assert np.allclose(mixed.variance, 0.1 * 0.25 ** 2, rtol=2e-3)   # 13 of 25 columns at 0.5 m: 0.52 x 0.48 x 0.5^2
    # The count is not smoothed: a frame without points leaves nothing land-able, whatever came before.
    empty = update(third, np.zeros((0, 3)), ORIGIN, 0, P)
    assert not empty.land.any() and np.allclose(empty.mean, 0.9 * third.mean)
    # Hysteresis: beta x previous + (1 - beta) x land.
    assert np.allclose(empty.hysteresis, 0.9 * third.hysteresis)
    # Upstream's cold start blends the first cloud with an all-zero grid; the warm start with itself.
    cold = update(None, cloud(np.full(len(xy), -5.0), xy), ORIGIN, 0, replace(P, warm_start=False))
    assert np.allclose(cold.mean[1:-1, 1:-1], -0.5) and np.allclose(cold.hysteresis, 0.1 * cold.land)
    # A new map segment starts afresh (its world frame is unrelated to the previous one's).
    reset = update(third, cloud(np.full(len(xy), 3.0), xy), ORIGIN, 1, P)
    assert np.allclose(reset.mean[1:-1, 1:-1], 3.0)


def test_cell_statistics_match_the_direct_formulas() -> None:
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-5, 5, (5000, 2)), rng.normal(2.0, 0.3, 5000)])
    count, mean, var = cell_statistics(pts, np.array([-5.0, -5.0]), P)
    ij = np.floor((pts[:, :2] + 5.0) / 0.25).astype(int)
    sel = (ij[:, 0] == 7) & (ij[:, 1] == 11)
    assert count[7, 11] == sel.sum() and mean[7, 11] == pytest.approx(pts[sel, 2].mean())
    assert var[7, 11] == pytest.approx(pts[sel, 2].var())


def test_search_order_is_the_waypoint_generators() -> None:
    off = search_offsets(40, 6)
    assert off[:9].tolist() == [[0, 0], [1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1]]
    assert len(off) == 1 + 8 * 13 and off[-1].tolist() == [13, -13]   # n_iterations = (1 + 40 - 13) / 2 = 14
    assert patch_disk(6).sum() == 137 and patch_disk(6)[0, 6] and not patch_disk(6)[0, 0]


def looking_down(altitude_m: float) -> np.ndarray:
    """T_world_camera of a camera at (0, 0, altitude) looking straight down (optical z = world -z)."""
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    T[:3, 3] = (0.0, 0.0, altitude_m)
    return T


def test_depth_image_to_grid_pixels_and_site() -> None:
    """A camera 5 m over level ground: the pixels of land-able cells are the mask, the site is under the camera."""
    intr = Intrinsics(231.0685, 231.0685, 160.0, 120.0, 320, 240)
    depth = np.full((240, 320), 5.0, np.float32)
    depth[:, :10] = np.nan                                           # no depth: never land-able
    planner, memory, T = Px4SlpPlanner(P), Px4SlpMemory(), looking_down(5.0)
    st, cells = planner.step(memory, depth, intr, T, 0)
    assert memory.previous is st and st.counter.max() >= 100       # ~2.2 cm pixels: ~130 points a cell
    score, mask = planner.pixels(st, cells)
    assert not mask[:, :10].any() and score[:, :10].max() == 0.0
    assert mask[100:140, 140:180].all() and 0.5 < mask.mean() < 1.0   # the view's border cells fail the vote
    world_pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [3.0, 0.0, 0.0]])
    sel = grid_site(st.hysteresis, st.mean, st.position, P.cell_size_m, P.smoothing_land_cell, P.can_land_thr,
                    world_pts, T, intr.K, mask, (0.656, 0.656))
    assert sel.site is not None and sel.site.accepted
    assert np.allclose(sel.site.center_world, (0.0, 0.0, 0.0), atol=1e-6) and sel.site.tilt_deg < 1e-6
    assert sel.labels.tolist() == [0, 0, -1]                        # points within the 1.625 m disk
    assert sel.site.center_camera[2] == pytest.approx(5.0)


# ----------------------------------------------------------------------------- CLI
SMALL = (*GAUSSIAN, "--set", "camera.width=320", "--set", "camera.height=240", "--set", "camera.fx=231.0685",
         "--set", "camera.fy=231.0685", "--set", "camera.cx=160", "--set", "camera.cy=120")


@pytest.fixture(scope="module")
def field_5m(tmp_path_factory) -> Path:
    """clear_field from 5 m at 320 x 240: ~130 points a 0.25 m cell, above upstream's 100."""
    return synth_recording(tmp_path_factory.mktemp("px4") / "field.mcap", "clear_field", 6, "--start", "0,0,5",
                           *SMALL)


def test_compare_three_methods_through_the_cli(field_5m, tmp_path) -> None:
    from click.testing import CliRunner

    out = tmp_path / "cmp"
    with fusion_spy() as seen:
        res = CliRunner().invoke(main, ["compare", str(field_5m), "-o", str(out), "--json",
                                        "--methods", "fuzzy,bayes,px4slp", *SMALL])
    assert res.exit_code == 0, res.output
    rec = json.loads(res.stdout)["recordings"][0]
    assert set(rec["methods"]) == {"fuzzy", "bayes", "px4slp"} and rec["inputs_identical"] is True
    assert len(rec["pairs"]) == 3
    px = rec["methods"]["px4slp"]
    dets = [d for m, d in seen if m == "px4slp"]
    assert len(dets) == px["detections"] == rec["detections"] > 0
    assert all(d.timings_ms["maps"] == 0.0 and d.score.method == "px4slp" for d in dets)
    # Open level grass from 5 m: what the grid calls land-able is truly safe and the committed site is
    # safe. Measured on seeds 0, 1, 2 of this recording: precision 1.000, recall 0.75-0.76, site safe
    # with clearance 5.9-6.1 m (the margin: any false-safe pixel on grass would be a defect).
    gt = px["ground_truth"]
    assert gt["mask"]["precision"] >= 0.99 and gt["mask"]["recall"] > 0.5
    assert px["status"] == "site" and gt["site"]["safe"] is True
    rows = (out / "compare.csv").read_text().splitlines()
    assert sum(",px4slp," in r for r in rows) == 1
    assert "safe_landing_planner" in (out / "report.html").read_text()


def test_detect_with_px4slp_and_bad_method_names(field_5m, tmp_path) -> None:
    from click.testing import CliRunner

    runner = CliRunner()
    run = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(field_5m), "-o", str(run), "--method", "px4slp", "--json", *SMALL])
    assert res.exit_code == 0, res.output
    landing = json.loads((run / "landing.json").read_text())
    assert landing["method"] == "px4slp" and landing["status"] == "site"
    assert "px4slp" in landing["timings_ms"] and landing["timings_ms"]["maps"] == 0.0
    # No 0.25 m cell of a 320x240 frame from 5 m holds 5000 points (the .cfg's maximum): no site, and the reason
    # is the planner's own, not slz's noise limits.
    none = tmp_path / "none"
    res = runner.invoke(main, ["detect", str(field_5m), "-o", str(none), "--method", "px4slp", *SMALL,
                               "--set", "scoring.px4slp.n_points_threshold=5000"])
    assert res.exit_code == 0, res.output
    landing = json.loads((none / "landing.json").read_text())
    assert landing["status"] == "no_safe_site" and landing["reason"].startswith("no disk of 13 cells")
    bad = runner.invoke(main, ["compare", str(field_5m), "-o", str(tmp_path / "c"), "--methods", "fuzzy,px4"])
    assert bad.exit_code == 1 and "--methods" in bad.output and "px4slp" in bad.output
    cfg = runner.invoke(main, ["detect", str(field_5m), "-o", str(tmp_path / "d"), "--method", "px4slp",
                               "--set", "scoring.px4slp.cell_size_m=0"])
    assert cfg.exit_code == 1 and "scoring.px4slp.cell_size_m" in cfg.output
