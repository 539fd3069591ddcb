"""SLAM map segments (issue 15): after a map reset the run keeps each map apart.

A fake backend replays a synth flight's true poses as two maps (lost on one frame between
them, the second map in an arbitrary frame of its own, as the odometry's reinit gives):
each segment is aligned on its own, the site is committed within one segment, there is
one TUM file per segment, results.mcap has one frame pair per segment, run.json and the
CLI count the maps. The real case: the realsense_floor frames, where ORB-SLAM3 resets.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import GAUSSIAN, synth_recording
from scipy.spatial.transform import Rotation
from sources_util import realsense_recording

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.evaluate.slam import ate, ate_by_segment, rpe, umeyama
from slzcli.geometry import invert_pose
from slzcli.outputs.summary_json import summary_json
from slzcli.pipeline import RunOptions, detect_recording
from slzcli.pipeline import tracking as tracking_module
from slzcli.pipeline.commit import commit_site
from slzcli.pipeline.tracking import depth_points, gravity_alignment
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.segments import Segment, primary_segment, segment_table
from slzcli.synth.groundtruth import load_ground_truth
from slzcli.terrain.maps import gravity_up_in_camera
from slzcli.types import FoundSite, Frame

FRAMES = 14
LOST = 3          # frame 3 is lost; frames 0-2 are map 0, frames 4-13 map 1
POINT_STRIDE_PX = 8
TOL_NS = 1_000_000


def _rigid(euler_deg: tuple[float, float, float], t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


# The second map's world: not its first camera (the odometry starts a new map at the last known pose).
SECOND_MAP = _rigid((20.0, -35.0, 50.0), (3.0, -1.0, 2.0))


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM reader as evo's (file_interface.read_tum_trajectory_file): '#' comments, 8 numbers a row,
    'timestamp tx ty tz qx qy qz qw'; independent of slz's own parse_tum."""
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert all(len(r) == 8 for r in rows), path
    data = np.array(rows, dtype=float).reshape(-1, 8)
    assert np.all(np.diff(data[:, 0]) > 0), f"{path}: stamps not increasing"
    assert np.allclose(np.linalg.norm(data[:, 4:], axis=1), 1.0, atol=1e-6), f"{path}: not unit quaternions"
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(data[:, 4:]).as_matrix()  # scipy: x, y, z, w like TUM
    T[:, :3, 3] = data[:, 1:4]
    return data[:, 0], T


class TwoMaps(BackendBase):
    """True poses as two SLAM maps; every tracked frame a keyframe with depth points (in its map's frame)."""

    name = "twomaps"

    def __init__(self, truth, keyframes_in: tuple[int, ...] = (0, 1)) -> None:
        self.truth = truth
        self.keyframes_in = keyframes_in
        self._kf: MapPoints | None = None

    def track(self, frame: Frame) -> TrackResult:
        self._kf = None
        if frame.index == LOST:
            return TrackResult(frame.index, frame.stamp_ns, TrackingState.LOST, None, segment=0)
        segment = int(frame.index > LOST)
        first = self.truth.T_world_camera[0 if segment == 0 else LOST + 1]
        world = np.eye(4) if segment == 0 else SECOND_MAP
        T_true = self.truth.T_world_camera[self.truth.index_of(frame.stamp_ns, TOL_NS)]
        T = world @ invert_pose(first) @ T_true
        if segment in self.keyframes_in:
            self._kf = depth_points(frame, T, POINT_STRIDE_PX)
        return TrackResult(frame.index, frame.stamp_ns, TrackingState.OK, T, self._kf is not None,
                           0 if self._kf is None else len(self._kf), segment)

    def keyframe(self) -> MapPoints | None:
        return self._kf


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("seg") / "clear_field.mcap", "clear_field", FRAMES, *GAUSSIAN)


@pytest.fixture
def two_maps(monkeypatch, flight):
    truth = load_ground_truth(flight)
    monkeypatch.setattr(tracking_module, "get_backend", lambda config, has_poses=False, **kw: TwoMaps(truth))
    return truth


# ----------------------------------------------------------------------------- pure functions
@dataclass(frozen=True)
class _Site:
    """The fields commit_site reads."""

    center_world: tuple[float, float, float]
    score: float
    accepted: bool
    edge_clearance_m: float | None = None


def _site(x: float, y: float, score: float, accepted: bool = True) -> _Site:
    return _Site((x, y, 0.0), score, accepted)


class _Frame:
    def __init__(self, index: int) -> None:
        self.index = index


def test_commit_site_counts_support_only_within_a_segment() -> None:
    """Map 1's site at (0, 0.1) is not confirmed by map 0's two sites there: different frames."""
    sites = [FoundSite(_Frame(i), _site(x, y, score), n, None, seg)  # type: ignore[arg-type]  # what commit reads
             for n, (i, x, y, score, seg) in enumerate(
        [(0, 0.0, 0.0, 0.80, 0), (1, 0.1, 0.0, 0.80, 0), (5, 0.0, 0.1, 0.95, 1), (6, 9.0, 9.0, 0.85, 1),
         (7, 9.1, 9.0, 0.85, 1)])]
    best = commit_site(sites, side_m=1.0)
    assert best is not None
    # Four sites confirmed by two detections each: the higher score (map 1's pair at (9, 9)) wins; of the pair,
    # equal in score and centrality, the lower x. Counting across maps, frame 5's site (the best score) would be
    # confirmed and win.
    assert (best.frame.index, best.segment, best.support) == (6, 1, 2)
    assert best.detections == 5 and best.segment_detections == 3


def test_ate_is_aligned_per_segment_and_rpe_skips_the_reset() -> None:
    rng = np.random.default_rng(0)
    truth = [_rigid(tuple(rng.normal(0, 5, 3)), (0.1 * i, np.sin(i / 4), 3.0)) for i in range(30)]
    segs = [0] * 12 + [1] * 18
    frames = [_rigid((0, 0, 0), (0, 0, 0)), _rigid((10.0, 70.0, -30.0), (4.0, 5.0, -6.0))]
    est = [frames[s] @ T for s, T in zip(segs, truth, strict=True)]
    est[12] = None  # lost on the first frame of map 1... then tracked
    res = ate_by_segment(est, truth, segs)
    assert set(res.per_segment) == {0, 1} and res.n == 29 and res.rmse_m < 1e-9
    assert ate(est, truth).rmse_m > 0.5  # one alignment over two maps fits neither
    assert rpe(est, truth, segments=segs).trans_rmse_m < 1e-9
    assert rpe(est, truth).n == rpe(est, truth, segments=segs).n  # frame 12 is lost: no pair crosses
    est[12] = frames[1] @ truth[12]
    assert rpe(est, truth).trans_rmse_m > 1.0 and rpe(est, truth, segments=segs).n == 28
    few = ate_by_segment(est, truth, [0] * 28 + [1, 1])
    assert set(few.per_segment) == {0} and few.skipped == {1: 2}


def test_segment_table_and_primary_segment() -> None:
    segs = np.array([0, 0, 0, 1, 1, 1, 2, 2])
    has_pose = np.array([1, 0, 1, 0, 1, 1, 1, 0], bool)
    table = segment_table(segs, has_pose, {1: 3})
    assert table == [Segment(0, 2, 0, 2, 0), Segment(1, 2, 4, 5, 3), Segment(2, 1, 6, 6, 0)]
    assert primary_segment(table, None) == 0  # most tracked frames, the earlier on a tie
    assert primary_segment(table, 2) == 2 and primary_segment([], None) is None


# ----------------------------------------------------------------------------- the pipeline
def test_two_maps_stay_apart_in_every_output(two_maps, flight, tmp_path) -> None:
    out = tmp_path / "run"
    summary: dict[str, Any] = summary_json(detect_recording(flight, load_config(), out, RunOptions()))
    slam = summary["slam"]
    assert slam["maps"] == 2 and slam["backend"] == "twomaps"
    assert [(s["segment"], s["first_frame"], s["last_frame"], s["frames_tracked"], s["keyframes"])
            for s in slam["segments"]] == [(0, 0, LOST - 1, LOST, LOST),
                                            (1, LOST + 1, FRAMES - 1, FRAMES - 1 - LOST, FRAMES - 1 - LOST)]
    landing = json.loads((out / "landing.json").read_text())
    assert summary["status"] == "site"
    # Measured: map 1's best site is confirmed by 5 of its 10 detections, map 0's by 2 of its 3 (with the
    # plan-view mask of issue 16; 4 of 10 before it). Counted across maps it would be more.
    k = landing["map_segment"]
    assert k == slam["segment"] == 1 and landing["frame"]["index"] > LOST
    support = landing["site"]["support"]
    assert support["detections_agreeing"] == 5 and support["detections_with_site_in_map_segment"] == FRAMES - LOST - 1
    assert "segment 1 (of 2 maps" in landing["world_frame"]

    # One TUM file per segment; trajectory.tum is the site's segment.
    stamps = np.array(two_maps.stamps_ns) * 1e-9
    tum = {s: read_tum(out / f"trajectory.seg{s}.tum") for s in (0, 1)}
    assert np.allclose(tum[0][0], stamps[:LOST]) and np.allclose(tum[1][0], stamps[LOST + 1:])
    assert (out / "trajectory.tum").read_bytes() == (out / f"trajectory.seg{k}.tum").read_bytes()
    # Each segment is gravity-aligned from its own first pose: that camera at the origin, mount attitude.
    G = gravity_alignment(gravity_up_in_camera(None, load_config().camera.mount))
    for s in (0, 1):
        np.testing.assert_allclose(tum[s][1][0], G, atol=1e-6)
    # ... and each is a rigid copy of the truth: aligned per segment the ATE is nil.
    gt = summary["ground_truth"]
    assert gt["slam_ate_rmse_m"] < 1e-4 and [s["segment"] for s in gt["slam_ate_segments"]] == [0, 1]
    assert gt["slam_rpe"]["pairs"] == FRAMES - 3  # 0-1, 1-2, 4-5, ..., 8-9: none across the reset
    # The site is in trajectory.tum's frame: through that segment's alignment to the true world
    # it lands on the ground-truth position of the site.
    true_T = two_maps.T_world_camera[[two_maps.index_of(round(t * 1e9), TOL_NS) for t in tum[k][0]]]
    al = umeyama(tum[k][1][:, :3, 3], true_T[:, :3, 3])
    centre = al.R @ np.asarray(landing["site"]["center_world"]) + al.t
    np.testing.assert_allclose(centre[:2], landing["site"]["ground_truth"]["true_xy"], atol=1e-4)

    # keyframes.npz knows each keyframe's segment; points.ply's map points are the site's segment's.
    kf = np.load(out / "keyframes.npz")
    assert kf["kf_segment"].tolist() == [0] * LOST + [1] * (FRAMES - LOST - 1)
    mine = kf["point_xyz_world"][kf["kf_segment"][kf["point_kf"]] == k]
    assert _ply_map_points(out / "points.ply") == len(np.unique(mine, axis=0))  # each map point once

    # results.mcap: map K's poses, clouds and site in map_K / <camera>_K (map / the recording's camera for map 0).
    frames = _mcap_frames(out / "results.mcap")
    cam, cam1 = "camera_color_optical_frame", "camera_color_optical_frame_1"
    assert frames["/tf"] == [("map", cam)] * LOST + [("map_1", cam1)] * (FRAMES - LOST - 1)
    assert frames["/slz/camera_pose"] == [("map", "")] * LOST + [("map_1", "")] * (FRAMES - LOST - 1)
    assert frames["/slz/mask"] == [(cam, "")] * LOST + [(cam1, "")] * (FRAMES - LOST - 1)
    assert frames["/slz/map_points"] == [("map", "")] * LOST + [("map_1", "")] * (FRAMES - LOST - 1)
    assert frames["/slz/landing_site"] == [("map_1", "")]


def test_a_new_map_never_uses_the_old_maps_points(monkeypatch, flight, tmp_path) -> None:
    """Map 1 makes no keyframe: its frames have no map points to select from (map 0's are in another frame)."""
    truth = load_ground_truth(flight)
    monkeypatch.setattr(tracking_module, "get_backend", lambda config, has_poses=False, **kw: TwoMaps(truth, (0,)))
    config = load_config(overrides=["landing.detect_on=every_nth", "landing.every_nth_frame=1"])
    summary = detect_recording(flight, config, tmp_path / "run", RunOptions())
    assert summary.detections == FRAMES
    with (tmp_path / "run" / "sites.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    frames = {int(r["frame"]) for r in rows}
    assert frames and max(frames) < LOST  # candidates only on map 0's frames, where its points are
    assert {r["segment"] for r in rows} == {"0"}


def test_compare_counts_the_maps_and_measures_no_distance_across_them(monkeypatch, flight, tmp_path, runner) -> None:
    truth = load_ground_truth(flight)
    monkeypatch.setattr(tracking_module, "get_backend", lambda config, has_poses=False, **kw: TwoMaps(truth))
    res = runner.invoke(main, ["compare", str(flight), "-o", str(tmp_path / "cmp"), "--json"])
    assert res.exit_code == 0, res.output
    rec = json.loads(res.stdout)["recordings"][0]
    assert rec["slam"]["maps"] == 2 and "started 2 maps" in res.stderr
    segs = {m: e["site"]["map_segment"] for m, e in rec["methods"].items()}
    (pair,) = rec["pairs"]
    assert (pair["site_distance_m"] is None) == (segs["fuzzy"] != segs["bayes"]), segs


def test_cli_says_how_many_maps_and_warns_once(two_maps, flight, tmp_path, runner) -> None:
    res = runner.invoke(main, ["detect", str(flight), "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert "SLAM twomaps, 2 maps)" in res.stdout.splitlines()[0]
    warnings = [ln for ln in res.stderr.splitlines() if "WARNING" in ln]
    assert len(warnings) == 1 and "started 2 maps" in warnings[0] and "summary.slam" in warnings[0]
    res = runner.invoke(main, ["detect", str(flight), "-o", str(tmp_path / "run"), "--json"])
    assert json.loads(res.stdout)["slam"]["maps"] == 2 and len(res.stderr.strip().splitlines()) == 1


def _ply_map_points(path: Path) -> int:
    """The map points of a points.ply (every role but the square's corners)."""
    from slzcli.outputs.points import ROLES, read_points_ply

    return int(np.sum(read_points_ply(path)["role"] != ROLES.index("corner")))


def _mcap_frames(path: Path) -> dict[str, list[tuple[str, str]]]:
    """Per topic, each message's (frame id, child frame id) in file order."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, list[tuple[str, str]]] = {}
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            assert schema is not None
            msg: Any = store.deserialize_cdr(message.data, schema.name)  # a message class of the typestore
            if channel.topic == "/tf":
                ids = [(t.header.frame_id, t.child_frame_id) for t in msg.transforms]
            elif hasattr(msg, "markers"):
                ids = [(msg.markers[0].header.frame_id, "")]
            elif not hasattr(msg, "header"):  # a frame's funnel row (std_msgs/String): in no frame
                continue
            else:
                ids = [(msg.header.frame_id, "")]
            out.setdefault(channel.topic, []).extend(ids)
    return out


# ----------------------------------------------------------------------------- the real case
@pytest.fixture
def floor_recording(realsense_dir: Path, tmp_path: Path) -> Path:
    """The 10 real RealSense frames in a ROS 2 MCAP (30 Hz stamps), written with the rosbags writer."""
    return realsense_recording(realsense_dir, tmp_path / "floor.mcap", "mcap")


@pytest.mark.parametrize("backend, overrides", [
    pytest.param("orbslam3", (), id="orbslam3"),
    # a new map after one lost frame: the built-in fallback's reinit, on the same frames
    pytest.param("odometry", ("slam.odometry.reinit_after_frames=1",), id="odometry-reinit")])
def test_real_frames_where_slam_resets_give_one_trajectory_per_map(floor_recording, tmp_path, runner,
                                                                   backend, overrides) -> None:
    if backend == "orbslam3":
        pytest.importorskip("pyorbslam3", reason="optional pyorbslam3 (slz[orbslam3]) not installed")
    args = ["detect", str(floor_recording), "-o", str(tmp_path / "run"), "--json", "--set", f"slam.backend={backend}"]
    for o in overrides:
        args += ["--set", o]
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    slam = json.loads(res.stdout)["slam"]
    # Measured: ORB-SLAM3 starts 5 maps on these 10 frames (every lost frame ends a map), the odometry 5.
    assert slam["maps"] >= 2
    warnings = [ln for ln in res.stderr.splitlines() if "WARNING" in ln and "maps" in ln]
    assert len(warnings) == 1 and f"started {slam['maps']} maps" in warnings[0]
    out = tmp_path / "run"
    # the hand-held camera looks forward at a floor: gravity from the scene (the straight-down mount is 60+ deg off)
    assert json.loads(res.stdout)["gravity"]["source"] == "scene"
    seen: list[float] = []
    for s in slam["segments"]:
        stamps, T = read_tum(out / s["trajectory"])
        assert len(stamps) == s["frames_tracked"]
        # each map aligned from its own first pose: z up from that frame's gravity, x along its camera's x
        np.testing.assert_allclose(T[0], gravity_alignment(T[0][2, :3]), atol=1e-6)
        seen.extend(stamps)
    assert len(seen) == len(set(seen)) == json.loads(res.stdout)["tracking"]["ok"]
    assert (out / "trajectory.tum").read_bytes() == (out / f"trajectory.seg{slam['segment']}.tum").read_bytes()
    tf = _mcap_frames(out / "results.mcap")["/tf"]
    assert {w for w, _ in tf} == {s["mcap_frame"] for s in slam["segments"]}
