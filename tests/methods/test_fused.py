"""The fused method through ``slz detect``: a hover's advice in landing.json, the fusion's time in its timings,
and the landing grid of a detection built only when results.mcap is written."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from conftest import HALF_SIZE, synth_recording

from slzcli.cli import main
from slzcli.methods import fused

RECORDED = ("--set", "slam.backend=recorded", "--set", "sources.use_ground_truth_pose=true")


@pytest.fixture(scope="module")
def hover(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """slz synth's default flight (a hover with drift and wobble) over clear_field with its default stereo
    sensor, half size: from its altitude one D4xx frame cannot vouch and a hover does not decorrelate."""
    return synth_recording(tmp_path_factory.mktemp("hover") / "hover.mcap", "clear_field", 9, *HALF_SIZE)


def _count_grids(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the fused method's landing grids as they are built (one entry each)."""
    built: list[int] = []
    orig = fused.landing_grid

    def counted(*a: Any, **k: Any) -> Any:
        built.append(1)
        return orig(*a, **k)

    monkeypatch.setattr(fused, "landing_grid", counted)
    return built


def _detect(rec: Path, out: Path, *sets: str) -> dict[str, Any]:
    res = CliRunner().invoke(main, ["detect", str(rec), "-o", str(out), "--method", "fused", *RECORDED,
                                    "--set", "landing.detect_on=every_nth", "--set", "landing.every_nth_frame=3",
                                    *sets])
    assert res.exit_code == 0, res.output
    return json.loads((out / "landing.json").read_text())


def test_a_hover_without_a_site_is_told_to_move_and_its_fusion_is_timed(hover: Path, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """landing.json of a hover with no site: its advice says more frames will not decide and to move (no
    frames); ``timings_ms.fuse`` is run.json's median of the fusion of every frame, inside ``total``; the
    detections' landing grids reach results.mcap, built as it writes them."""
    built = _count_grids(monkeypatch)
    landing = _detect(hover, tmp_path / "run")
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert landing["status"] == "no_safe_site"
    adv = landing["advice"]
    assert adv["source"] == "fused" and adv["hover"] and adv["frames"] is None
    assert adv["text"].startswith("hovering: more frames will not decide the ground at") and "move: " in adv["text"]
    t = landing["timings_ms"]
    assert t["fuse"] == round(run["timings"]["fuse"]["median_ms"], 3) > 0
    assert t["total"] == pytest.approx(sum(t[k] for k in ("maps", "fused", "mask", "slam", "select", "fuse")),
                                       abs=1e-3)
    assert list(t)[:7] == ["maps", "fused", "mask", "slam", "select", "fuse", "total"]
    assert len(built) == run["summary"]["detections"] == 3
    assert (tmp_path / "run" / "results.mcap").stat().st_size > 0


def test_without_results_mcap_no_landing_grid_is_built(hover: Path, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """No sink writes the detections' landing grids: none is built (the method hands over how to build it)."""
    built = _count_grids(monkeypatch)
    _detect(hover, tmp_path / "run", "--set", "output.results_mcap=false")
    assert not (tmp_path / "run" / "results.mcap").exists()
    assert built == []


def test_the_fused_site_selection_drops_only_the_raised_readings_that_cannot_tell() -> None:
    """The fused verdict runs the raised-surface rule on its cells with every frame's evidence; the per-frame rule
    on a keyframe's sparse SLAM points refuses a fused site only where its reading can tell (margin under the
    tolerance, or raised beyond doubt): on ORB-SLAM3's points at 10 m it called every level cluster "not told"
    and `slz detect --method fused` committed no site on 30 flights (benchmarks/fused_detect.py)."""
    import numpy as np

    from slzcli.config import load_config
    from slzcli.landing.select import select_site
    from slzcli.methods.maps import select_params

    config = load_config(None, [])
    method = fused.fused(config)
    assert method.params.raised is not None and method.params.raised.defer_untold
    per_frame = select_params(config.landing, config.uav, "min_normal_variance", config.landing.min_extent_factor)
    assert per_frame.raised is not None and not per_frame.raised.defer_untold   # the per-frame methods refuse
    # level ground, 40 map points over 3 x 3 m with 0.25 m of noise, seen from 10 m, and level ground around it
    # with 0.25 m of noise: the per-frame rule cannot tell it (margin over the tolerance); the fused one defers
    K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
    T = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 10.0], [0, 0, 0, 1.0]])
    mask = np.ones((480, 640), bool)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        xy = rng.uniform(-1.5, 1.5, (40, 2))
        pts = np.column_stack([xy, rng.normal(0.0, 0.25, 40)])
        ring = rng.uniform(-4.0, 4.0, (4000, 2))
        ring = ring[np.hypot(*ring.T) > 1.5]
        around = np.column_stack([ring, rng.normal(0.0, 0.25, len(ring))])
        base = dataclasses.replace(per_frame, kmeans_k=1)
        refused = select_site(pts, T, K, mask, mask.astype(np.float32), base, around_world=around)
        assert refused.site is None and "not told" in refused.reason, refused.reason
        deferred = select_site(pts, T, K, mask, mask.astype(np.float32),
                               dataclasses.replace(method.params, kmeans_k=1), around_world=around)
        assert deferred.site is not None, deferred.reason
        assert deferred.candidates[0].raised_m is None   # dropped: neither a refusal nor a reading
        # a 1.5 m box top is raised beyond doubt at that noise: refused on both
        top = select_site(pts + np.array([0.0, 0.0, 1.5]), T, K, mask, mask.astype(np.float32),
                          dataclasses.replace(method.params, kmeans_k=1), around_world=around)
        assert top.site is None and "above the ground around it" in top.reason


def test_a_fused_site_the_map_points_do_not_confirm_is_named_with_what_would(tmp_path: Path) -> None:
    """Open level ground from 5 m with low noise: the fused map calls cells safe, and where the SLAM map points are
    too few to confirm a site (here: a cluster needs more points than a keyframe has) the reason says the fused
    terrain's safe cells and its best site come first, then what the points lacked and that more flight over that
    ground gives more of them. It used to give the selection's own line alone ("only 0 of 425 SLAM map points lie
    on the landing mask"), the D435 from 7.5 m over clear_field with ORB-SLAM3 (benchmarks/fused_detect.py)."""
    rec = synth_recording(tmp_path / "low.mcap", "clear_field", 6, "--start", "0,0,5",
                          "--set", "synth.sensor.model=gaussian", *HALF_SIZE)
    landing = _detect(rec, tmp_path / "run", "--set", "landing.min_cluster_points=100000", *HALF_SIZE)
    assert landing["status"] == "no_safe_site"
    reason = landing["reason"]
    assert reason.startswith("the fused terrain calls ") and " cells in view safe (the best at (" in reason
    assert "but the SLAM map points do not confirm a site there: only " in reason
    assert "(at least 100000 needed)" in reason and "more flight over that ground" in reason
