"""The funnel (slzcli/funnel.py): what each filter between the depth image and a site left, and the no-site
reason built from it.

One synthetic frame per step, made so that this step is the one that empties the landing mask (the score
threshold, the footprint clearance, the descent column, the noise limits) or, with a mask, where the map
points or the clusters fail: each frame goes through ``mask_score`` and ``select_site`` as ``slz detect``
runs them and through the run's ``tally``, and the reason must name that step and what would change it.
Then the real RealSense frames as a realsense-ros bag through the CLI, and the bench profile on a close-range
synth flight.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, HALF_SIZE
from sources_util import realsense_recording

from slzcli.cli import main
from slzcli.config import PROFILE_DIR, Config, load_config, read_yaml_mapping
from slzcli.funnel import BENCH_COLUMN_M, MASK_STEPS, FrameFunnel, FunnelLog, mask_funnel
from slzcli.landing.commit import commit_radius_m
from slzcli.landing.select import select_site
from slzcli.methods.base import build
from slzcli.methods.maps import fuzzy
from slzcli.pipeline.step import tally
from slzcli.scoring import MaskParams, get_scorer, mask_score
from slzcli.slam import MapPoints
from slzcli.summary import RunState, no_site_reason
from slzcli.terrain.limits import working_scale
from slzcli.terrain.noise import SCALES_PX, DepthNoise
from slzcli.types import Detection, Frame, Intrinsics, TerrainMaps

K = Intrinsics(fx=320.0, fy=320.0, cx=160.0, cy=120.0, width=320, height=240)
UP = np.array([0.0, 0.0, -1.0])   # world up in a camera looking straight down


def down_pose(altitude_m: float) -> np.ndarray:
    """T_world_camera of a camera at altitude_m looking straight down (camera x = world x, y = -world y)."""
    T = np.diag([1.0, -1.0, -1.0, 1.0])
    T[2, 3] = altitude_m
    return T


def ground_points(altitude_m: float, half_m: float, n: int, seed: int = 0) -> np.ndarray:
    """n map points on the ground (z = 0), uniform in a square of half side half_m under the camera."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-half_m, half_m, (n, 2)), np.zeros(n)])


def detection(cfg: Config, score: np.ndarray, altitude_m: float, *, work=None, xyz=None,
              steepness: float = 1.0, slope_deg: float = 0.0) -> Detection:
    """One detection frame over level ground at altitude_m with this score, as ``pipeline.Fusion`` makes it."""
    depth = np.full((K.height, K.width), altitude_m, np.float32)
    valid = np.ones(depth.shape, bool)
    one = np.ones(depth.shape, np.float32)
    maps = TerrainMaps(one, one, one, np.full(depth.shape, steepness, np.float32), valid,
                       np.full(depth.shape, slope_deg, np.float32), None, work, UP)
    sm = mask_score(get_scorer(cfg.scoring, cfg.mask), score.astype(np.float32), depth, K, MaskParams.of(cfg), work, UP)
    frame = Frame(0, 0, np.zeros((K.height, K.width, 3), np.uint8), depth, K)
    T = down_pose(altitude_m)
    points = selection = None
    if xyz is not None:
        points = MapPoints(np.arange(len(xyz)), xyz, np.zeros((len(xyz), 2)), 0, 0, T)
        selection = select_site(xyz, T, K.K, sm.mask, sm.score, fuzzy(cfg).params)
    return Detection(frame, T, maps, sm, points, selection, None, {}, 0)


def reason_of(cfg: Config, *dets: Detection) -> tuple[str, RunState]:
    state, method = RunState(), build("fuzzy", cfg)
    for d in dets:
        tally(state, d, method, cfg.terrain, cfg.uav)
    return no_site_reason(state, "odometry", 1, commit_radius_m(cfg.landing, cfg.uav)), state


# ----------------------------------------------------------------------------- the counts
def test_mask_funnel_is_non_increasing_and_names_the_step_that_emptied_it() -> None:
    """Counts as the mask makes them (a smoothed pixel may pass the footprint and not the raw threshold)
    are made non-increasing; the step that emptied the mask is the first that left none."""
    m = mask_funnel(100, (90, 40, 45, 0, 0), 0.5, 0.9, 0.86, 2.0, 5.0, (5.0, 3.75))
    assert m.left == (90, 40, 40, 0, 0)
    assert m.removed() == {"threshold": 50, "footprint": 0, "column": 40, "noise": 0}
    assert m.emptied_by() == "column"
    assert mask_funnel(100, (0, 0, 0, 0, 0), 0.5, 0.0, 0.86, 2.0, None, None).emptied_by() is None
    assert mask_funnel(100, (90, 40, 30, 20, 10), 0.5, 0.9, 0.86, 2.0, 5.0, None).emptied_by() is None


def test_the_counts_are_those_of_the_masks_each_step_makes() -> None:
    """Level ground at 5 m, score 1 on the left half, 0.3 on the right: the threshold keeps the left half
    exactly; the footprint and column steps keep what the mask keeps; the noise step is the mask itself."""
    cfg = load_config()
    score = np.full((K.height, K.width), 0.3, np.float32)
    score[:, : K.width // 2] = 1.0
    d = detection(cfg, score, 5.0)
    f = d.score.funnel
    assert f is not None and f.pixels == K.width * K.height
    assert f.left[:2] == (K.width * K.height, K.width * K.height // 2)
    assert f.left[-1] == int(d.score.mask.sum()) > 0
    assert f.left[2] >= f.left[3] == f.left[4]      # no noise limits given: the mask is the column step's
    assert f.column_m == cfg.control.desired_depth_m and f.depth_m == pytest.approx(5.0)
    assert f.view_m == pytest.approx((5.0, 3.75))


# ----------------------------------------------------------------------------- one reason per step
def test_the_score_threshold_emptying_the_mask_is_named_with_the_lowest_map() -> None:
    """Every pixel scores 0.3 < 0.5; the steepness map is the lowest (the ground slopes 40 deg against
    gravity as given): the reason names the threshold, the best score and the mount as what would change it."""
    cfg = load_config()
    d = detection(cfg, np.full((K.height, K.width), 0.3), 5.0, steepness=0.05, slope_deg=40.0)
    reason, state = reason_of(cfg, d, d)
    assert d.score.funnel is not None and d.score.funnel.emptied_by() == "threshold"
    assert reason.startswith("the landing mask was empty in all 2 detection frames: the score threshold removed "
                             "the most (100% of")
    assert "best there 0.30" in reason and "steepness (median 0.05)" in reason and "slope a median 40 deg" in reason
    assert "camera.mount" in reason and "SLAM map point" not in reason
    assert state.funnel.as_dict()["frames_emptied_by"]["threshold"] == 2


def test_the_footprint_clearance_emptying_the_mask_is_named_with_the_view() -> None:
    """Good ground (score 1) cut by bad strips 0.2 m wide every 0.5 m, at 5 m: 60 % of the pixels pass the
    threshold but no 0.86 m square fits between the strips."""
    cfg = load_config()
    u = (np.arange(K.width) - K.cx) * 5.0 / K.fx        # ground x of each column (m)
    score = np.where(np.mod(u, 0.5) < 0.2, 0.0, 1.0)[None, :].repeat(K.height, axis=0)
    d = detection(cfg, score, 5.0)
    f = d.score.funnel
    assert f is not None and f.left[1] > 0.5 * f.left[0] and f.emptied_by() == "footprint"
    reason, _ = reason_of(cfg, d)
    assert "the footprint clearance removed the most" in reason
    assert "the step that emptied it: the footprint clearance in 1" in reason
    assert "0.86 m footprint square" in reason and "view spans ~5.0 x 3.8 m" in reason
    assert "uav.footprint_m" in reason and "envelope" not in reason   # 5 m is above the 2 m hover


def test_the_descent_column_emptying_the_mask_is_named_with_the_envelope() -> None:
    """Level good ground 1.9 m below: the footprint fits in the middle of the view, but the 2 m column's top
    is behind the camera everywhere; the camera is closer than the hover: out of the UAV's envelope."""
    cfg = load_config()
    d = detection(cfg, np.ones((K.height, K.width)), 1.9)
    f = d.score.funnel
    assert f is not None and f.left[2] > 0 and f.emptied_by() == "column"
    reason, _ = reason_of(cfg, d)
    assert "the step that emptied it: the descent column in 1" in reason
    assert "final descent's column (control.desired_depth_m 2 m above the ground) was out of view" in reason
    assert "outside this UAV's envelope" in reason and "--profile bench" in reason


def test_the_noise_limits_emptying_the_mask_are_named() -> None:
    """Level good ground at 10 m, a frame that vouches only up to 9 m: the noise step removes what the
    footprint and the column left, and the most."""
    cfg = load_config()
    noise = DepthNoise(tuple(0.0005 for _ in SCALES_PX), "config")
    work = replace(working_scale(noise, 10.0, K.fx, cfg.terrain, cfg.uav), vouched=True, vouch_depth_m=9.0)
    d = detection(cfg, np.ones((K.height, K.width)), 10.0, work=work)
    f = d.score.funnel
    assert f is not None and f.left[3] > 0 and f.emptied_by() == "noise"
    reason, state = reason_of(cfg, d)
    assert state.unvouched == 0
    assert "the noise limits removed the most" in reason and "the noise limits vouch" in reason


def test_a_mask_without_map_points_on_it_says_more_flight() -> None:
    """The mask holds the middle of the view, the keyframe's map points all lie near the image border."""
    cfg = load_config()
    xyz = ground_points(10.0, 4.9, 400)
    xyz = xyz[np.max(np.abs(xyz[:, :2]) / [5.0, 3.75], axis=1) > 0.9]   # outside the column's share
    d = detection(cfg, np.ones((K.height, K.width)), 10.0, xyz=xyz)
    assert d.score.mask.any() and d.selection is not None and not d.selection.kept.any()
    reason, state = reason_of(cfg, d)
    assert reason.startswith(f"the landing mask held {int(d.score.mask.sum())} px over 1 of 1 detection frames, "
                             f"but none of the {d.selection.in_view} SLAM map points in view")
    assert "more flight" in reason
    row = state.funnel.as_dict()["frames"][0]
    assert row["map_points"] == {"keyframe": len(xyz), "in_view": d.selection.in_view, "on_mask": 0}


def test_clusters_failing_the_extent_test_are_counted_by_test() -> None:
    """Map points on the mask, but all within a 0.3 m square: every cluster is smaller than the footprint."""
    cfg = load_config()
    d = detection(cfg, np.ones((K.height, K.width)), 10.0, xyz=ground_points(10.0, 0.15, 60))
    sel = d.selection
    assert sel is not None and sel.site is None and sel.candidates
    assert {c.test for c in sel.candidates} == {"extent"}
    reason, state = reason_of(cfg, d)
    assert reason.startswith("no cluster of mask-filtered map points met the footprint in any detection frame")
    assert f"of {len(sel.candidates)} clusters: {len(sel.candidates)} extent below the footprint" in reason
    assert "smaller uav.footprint_m" in reason
    funnel = state.funnel.as_dict()
    assert funnel["clusters_failed"] == {"extent": len(sel.candidates)}
    assert [c["failed"] for c in funnel["frames"][0]["clusters"]] == ["extent"] * len(sel.candidates)


def test_without_mask_counts_the_reason_is_left_to_the_caller() -> None:
    """px4slp's ScoreMap has no mask counts: its grid has its own reason (docs/PX4SLP.md)."""
    log = FunnelLog()
    log.add(FrameFunnel(0, None, (10, 10, 0)))
    assert log.reason() is None and not log.mask_always_empty()
    assert log.as_dict()["frames"] == [{"frame": 0, "map_points": {"keyframe": 10, "in_view": 10, "on_mask": 0},
                                        "clusters": [], "site": None}]


def test_the_bench_profile_is_what_the_envelope_message_names() -> None:
    bench = load_config(profile="bench")
    assert bench.control.desired_depth_m == BENCH_COLUMN_M
    assert max(bench.uav.footprint_m) == 0.2
    assert set(read_yaml_mapping(PROFILE_DIR / "bench.yaml")) == {"uav", "control", "terrain", "landing"}


# ----------------------------------------------------------------------------- through the CLI
@pytest.fixture
def floor_bag(realsense_dir: Path, tmp_path: Path) -> Path:
    """The 10 real RealSense frames as a realsense-ros ROS 1 bag (colour, aligned 16UC1 depth, camera_info)."""
    return realsense_recording(realsense_dir, tmp_path / "floor.bag", "ros1")


def test_the_real_frames_reason_names_the_filter_that_emptied_the_mask(floor_bag: Path, tmp_path: Path,
                                                                     runner) -> None:
    """The real floor, hand-held at 0.8-1.5 m and looking forward (its tilt given, roughly: pitch 80 deg):
    every detection frame's mask is empty. Measured (odometry, every frame): the threshold removed 99 % of the
    pixels with depth and emptied 6 of the 10 masks, the footprint the other 4 (without the tilt: the threshold
    all 10, the steepness map lowest, the surfaces sloping a median 67 deg). The reason names the filter,
    not the SLAM points, and says the data is out of the UAV's envelope; run.json, report.html and
    results.mcap hold each frame's funnel."""
    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(floor_bag), "-o", str(out), "--json", "--set", "slam.backend=odometry",
                               "--set", "landing.detect_on=every_nth", "--set", "camera.mount.pitch_deg=80"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["status"] == "no_safe_site" and summary["detections"] == 10
    assert summary["depth_limits"]["vouched"] is True and 0.8 < summary["depth_limits"]["altitude_m"] < 1.6
    reason = summary["reason"]
    assert "SLAM map point" not in reason
    run = json.loads((out / "run.json").read_text())
    funnel = run["funnel"]
    assert funnel["steps"] == list(MASK_STEPS) and len(funnel["frames"]) == 10
    assert funnel["mask_px"]["noise"] == 0 and funnel["mask_px"]["depth"] > 2_000_000
    emptied = funnel["frames_emptied_by"]
    assert sum(emptied.values()) == 10
    removed = {s: funnel["mask_px"][a] - funnel["mask_px"][s] for a, s in itertools.pairwise(MASK_STEPS)}
    main_step = max(removed, key=lambda s: removed[s])
    names = {"threshold": "the score threshold", "footprint": "the footprint clearance",
             "column": "the descent column", "noise": "the noise limits"}
    assert reason.startswith(f"the landing mask was empty in all 10 detection frames: {names[main_step]} removed "
                             "the most")
    for step, n in emptied.items():
        if n:
            assert f"{names[step]} in {n}" in reason
    assert "outside this UAV's envelope" in reason and "--profile bench" in reason
    page = (out / "report.html").read_text()
    assert "id=funnel>" in page and page.count("<tr>") >= 11
    from mcap.reader import make_reader
    with (out / "results.mcap").open("rb") as fh:
        rows = [json.loads(bytes(m.data[8:]).rstrip(b"\0").decode()) for _, _, m in
                make_reader(fh).iter_messages(topics=["/slz/funnel"])]
    assert [r["frame"] for r in rows] == list(range(10))
    assert [r["mask_px"] for r in rows] == [f["mask_px"] for f in funnel["frames"]]


def test_the_bench_profile_finds_a_safe_site_where_the_default_is_out_of_its_envelope(tmp_path: Path,
                                                                                      runner) -> None:
    """A clear field from 1.5 m: the default vehicle's 2 m column cannot be in view (no site, the column and
    the envelope named); the bench profile's small vehicle lands, on truly safe ground."""
    rec = tmp_path / "low.mcap"
    res = runner.invoke(main, ["synth", "clear_field", "-o", str(rec), "--frames", "3", "--start", "0,0,1.5",
                               *GAUSSIAN, *HALF_SIZE])
    assert res.exit_code == 0, res.output
    default = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "a"), "--json", *HALF_SIZE])
    assert default.exit_code == 0, default.output
    s = json.loads(default.stdout)
    assert s["status"] == "no_safe_site"
    assert "the descent column in" in s["reason"] and "outside this UAV's envelope" in s["reason"]
    bench = runner.invoke(main, ["detect", str(rec), "-o", str(tmp_path / "b"), "--json", "--profile", "bench",
                                 *HALF_SIZE])
    assert bench.exit_code == 0, bench.output
    b = json.loads(bench.stdout)
    assert b["status"] == "site", b["reason"]
    assert b["ground_truth"]["site"]["safe"] is True
    rows = json.loads((tmp_path / "b" / "run.json").read_text())["funnel"]["frames"]
    assert any(r["site"] is not None and r["site"]["accepted"] for r in rows)
    assert all(r["best_score"] is None for r in rows)     # only taken when no pixel passed the threshold


def test_the_real_frames_fused_reason_names_the_verdicts_test(floor_bag: Path, tmp_path: Path, runner) -> None:
    """The same real frames through the fused method: nothing in view is decided safe, and the reason says which
    of the verdict's tests left no cell (the score: 181 cells seen, the footprint's windows seen whole around 6 of
    them, the flatness map lowest), and that the camera, 0.9 m from the ground, flew below the descent column.
    run.json and report.html hold each tracked detection frame's cell counts, in the verdict's order."""
    from slzcli.fusion.funnel import CELL_STEPS

    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(floor_bag), "-o", str(out), "--json", "--method", "fused",
                               "--set", "slam.backend=odometry", "--set", "landing.detect_on=every_nth",
                               "--set", "camera.mount.pitch_deg=80"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["status"] == "no_safe_site" and summary["site_world"] is None
    reason = summary["reason"]
    assert reason.startswith("nothing in view is decided safe by the fused terrain: no landing square among the ")
    assert "lowest of the four maps" in reason
    assert "outside this UAV's envelope" in reason and "--profile bench" in reason
    rows = [f["cells"] for f in json.loads((out / "run.json").read_text())["funnel"]["frames"] if "cells" in f]
    assert rows and summary["tracking"]["ok"] == len(rows)
    for cells in rows:
        assert list(cells) == list(CELL_STEPS) and cells["seen"] > 0 and cells["safe"] == 0
        assert list(cells.values()) == sorted(cells.values(), reverse=True)
    page = (out / "report.html").read_text()
    table = page[page.index("The fused verdict's cells in view"):]
    table = table[:table.index("</table>")]
    assert table.count("<tr>") == 1 + len(rows)   # the header, then one row a tracked detection frame
    assert f"<td>{rows[-1]['seen']}</td>" in table
