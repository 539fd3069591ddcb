"""``slz detect`` as a readable list of steps: frames -> maps -> score -> mask -> SLAM points -> site.

The core has no file I/O: a ``Tracker`` (SLAM backend, gravity alignment, pose and keyframe
logs, the latest map points) tracks the frames, ``detect`` yields a ``types.Detection`` per
frame due, made by a ``Fusion`` without state (maps -> score -> mask -> site). Everything
else consumes the detections as they stream: the run's tables (``tally``), the ground truth
(``evaluate.truth.TruthEvaluator``), the run folder and ``results.mcap``; ``summary.summarise``
sums up. ``detect_recording`` is open / track / detect / sinks / summary; ``slz compare``
tracks once and runs one Fusion per method on the same maps.

Compute first, write after: every frame's stages are timed on their own (maps, score, mask,
slam, select), writing is timed separately and kept out of the per-frame figure. The run
folder is built under a temporary name and put in place at the end, so a failed run leaves
nothing a rerun would trust. Output safety (``outputs/output_dir.py``): ``-o`` must be missing,
empty or a run folder of ``slz detect``, and neither the recording nor a folder holding it; a
rerun with the same key (config values, method, versions, the bytes of every file read:
``fingerprint.py``) is skipped, one with another key replaces a finished run only with
``--force``, and then only the files a run writes.

World frame. Recorded poses are taken as given (REP 103, z up). A SLAM backend's world is
its first camera frame; it is turned into a gravity-aligned frame (z up from the camera
mount, x along the first camera's x, origin at the first camera) so that the slope test
and the Eq. 10 square mean what they say. After a map reset the backend's poses are in a
new world frame (a new map segment, ``slzcli.slam.segments``): each segment is aligned
the same way from its own first tracked frame, and its map points never serve a frame of
another segment.

The committed site. Every detection frame may give a site; the one written to
``landing.json`` is the site confirmed by the most detections (other sites within
``landing.commit_radius_factor`` footprint sides of it in plan, two by default, in the same
map segment: positions in different segments are in different frames), among those that
pass the acceptance test when any do; ties go to the lower normal variance, then to the
later frame. One lucky keyframe cannot outvote a site
seen again and again. The committed site's segment is the run's world frame.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable, Generator, Iterable, Iterator, Sequence
from contextlib import ExitStack, closing
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from slzcli import fingerprint
from slzcli.config import Config
from slzcli.errors import DatasetError, FrameError, OutputError
from slzcli.evaluate.timing import StageTimer
from slzcli.evaluate.truth import TruthEvaluator
from slzcli.evaluate.truth import ground_truth_of as ground_truth_of  # slz compare and tests use it from here
from slzcli.geometry import invert_pose, transform_points
from slzcli.interrupt import call_interruptibly
from slzcli.landing.px4slp import grid_site
from slzcli.landing.select import Candidate, SelectParams, Site, select_site
from slzcli.outputs import output_dir, results_mcap, run_folder
from slzcli.outputs.background import BackgroundWriter
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import KeyframeLog, PoseLog
from slzcli.scoring import Scorer, get_scorer, mask_score
from slzcli.scoring.px4slp import NAME as PX4SLP
from slzcli.scoring.px4slp import Px4SlpMemory, Px4SlpPlanner
from slzcli.slam import MapPoints, SlamBackend, TrackingState, get_backend, with_frame_period
from slzcli.slam.recorded import has_recorded_clouds
from slzcli.sources import check_readable, open_recording
from slzcli.sources.presets import with_noise_prior
from slzcli.sources.read_ahead import read_ahead
from slzcli.sources.window import no_frames_reason
from slzcli.summary import RunState, summarise
from slzcli.terrain.geometry import back_project
from slzcli.terrain.limits import limit_reason
from slzcli.terrain.maps import frame_maps, gravity_up_in_camera
from slzcli.terrain.noise import DepthNoise, NoiseTracker
from slzcli.timeout import StageLimit
from slzcli.types import Detection, Frame, ScoreMap, TerrainMaps

log = logging.getLogger(__name__)
Progress = Callable[[int, int | None], None]
TrackedFrame = tuple[Frame, np.ndarray | None, bool]  # a frame, its world pose (None: lost), detection is due
SPOOL_DIR = ".spool"  # keyframes, candidate rows and site points of a run, inside its temporary run folder


def select_params(config: Config, method: str) -> SelectParams:
    lc, uav = config.landing, config.uav
    bayes = method == "bayes"
    return SelectParams(
        kmeans_k=lc.kmeans_k, normal_radius_m=lc.normal_radius_m, min_cluster_points=lc.min_cluster_points,
        footprint_m=(uav.footprint_m[0], uav.footprint_m[1]),
        min_extent_factor=lc.bayes_min_extent_factor if bayes else lc.min_extent_factor,
        rule="largest" if bayes else "min_normal_variance", seed=lc.seed,
        edge_clearance_m=lc.edge_clearance_factor * max(uav.size_m[:2]), max_tilt_deg=uav.max_slope_deg,
        max_normal_pairs=lc.max_normal_pairs)


def gravity_alignment(first_camera_up: np.ndarray) -> np.ndarray:
    """4x4 ``T_world_slam`` for a SLAM world that is the first camera frame: z up, x along camera x."""
    z = first_camera_up / np.linalg.norm(first_camera_up)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-6:  # camera x points along gravity: use camera z instead
        x = np.array([0.0, 0.0, 1.0]) - z[2] * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z])
    return T


def depth_points(frame: Frame, T_world_camera: np.ndarray, stride_px: int) -> MapPoints:
    """Map points from the depth image on a pixel grid, for poses recorded without a map cloud."""
    xyz_cam = back_project(frame.depth_m[::stride_px, ::stride_px],
                           frame.intrinsics.scaled(*frame.depth_m[::stride_px, ::stride_px].shape[::-1]))
    v, u = np.mgrid[0:frame.depth_m.shape[0]:stride_px, 0:frame.depth_m.shape[1]:stride_px]
    ok = np.all(np.isfinite(xyz_cam), axis=2)
    pc = xyz_cam[ok]
    xyz = transform_points(T_world_camera, pc)
    pixels = np.stack([u[ok], v[ok]], axis=1).astype(np.float64)
    return MapPoints(np.arange(len(xyz), dtype=np.int64), xyz, pixels, frame.index, frame.stamp_ns, T_world_camera)


# ----------------------------------------------------------------------------- tracking
class Tracker:
    """SLAM over the frames of one recording: the backend, the gravity alignment of each map segment,
    the pose and keyframe logs and the latest keyframe's map points; nothing about detection.

    ``slz detect`` and ``slz compare`` track with one and fuse each method on what it holds.
    """

    def __init__(self, config: Config, slam: SlamBackend, keyframes: KeyframeLog | None = None,
                 timer: StageTimer | None = None) -> None:
        """``keyframes``: a log with a spool folder (else a count only); ``timer``: where the ``slam`` stage
        is timed (a run's timer, so its stages keep their order; else its own)."""
        self.config = config
        self.slam = slam
        self.timer = StageTimer() if timer is None else timer
        self.trajectory = PoseLog()  # every frame's stamp, pose (None: not tracked), segment
        self.keyframes = KeyframeLog() if keyframes is None else keyframes
        self.tracking: dict[str, int] = {}  # frames per tracking state
        self.frames = 0
        self.align: dict[int, np.ndarray] = {}  # T_world_slam of each map segment, from its first pose
        self._segment = 0  # map segment of the latest frame
        self._t_submit = 0.0  # when the frame being tracked was submitted
        self._points: MapPoints | None = None  # the latest keyframe's map points (of the current segment)

    @property
    def slam_name(self) -> str:
        return self.slam.name

    @property
    def poses_are_recorded(self) -> bool:
        return self.slam.poses_are_recorded

    @property
    def segment(self) -> int:
        """The SLAM map segment of the latest tracked frame."""
        return self._segment

    @property
    def points(self) -> MapPoints | None:
        """The latest keyframe's map points in the world frame (None: none yet in this map segment)."""
        return self._points

    def latest_slam_ms(self) -> float:
        """The tracking time of the latest frame (ms)."""
        return self.timer.samples_ms["slam"][-1]

    def _world(self, T_slam_camera: np.ndarray | None, segment: int) -> np.ndarray | None:
        if T_slam_camera is None:
            return None
        if segment not in self.align:
            self.align[segment] = np.eye(4) if self.poses_are_recorded else \
                gravity_alignment(gravity_up_in_camera(None, self.config.camera.mount)) @ invert_pose(T_slam_camera)
        return self.align[segment] @ T_slam_camera

    def track(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """SLAM on one frame: the gravity-aligned pose and whether it is a keyframe with map points."""
        self.submit(frame)
        return self.collect(frame)

    def submit(self, frame: Frame) -> None:
        """Start tracking ``frame``: a backend in a worker process tracks it while this process computes."""
        self._t_submit = time.perf_counter()
        self.slam.submit(frame)

    def collect(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """The submitted frame's gravity-aligned pose and whether it is a keyframe with map points.

        Timed as ``slam`` (the tracking time where it ran: the worker's own for ORB-SLAM3) and ``slam_wait``
        (how long this process waited for it, less when the worker tracked while the maps were computed)."""
        slam = self.slam
        t0 = time.perf_counter()
        result = slam.collect()
        points = slam.keyframe() if result.is_keyframe else None
        waited = _lap(t0)
        own = slam.last_track_ms()
        self.timer.add("slam", _lap(self._t_submit) if own is None else own)
        self.timer.add("slam_wait", waited)
        if result.segment != self._segment:  # a new map: the old map's points are in another frame
            self._segment, self._points = result.segment, None
        T = self._world(result.T_world_camera, self._segment)
        self.frames += 1
        self.trajectory.append(frame.stamp_ns, T, self._segment)
        self.tracking[result.state.value] = self.tracking.get(result.state.value, 0) + 1
        if points is not None and T is not None:
            if len(points) == 0 and slam.map_points_from_depth:
                points = depth_points(frame, T, self.config.landing.depth_points_stride_px)
            else:
                points = MapPoints(points.ids, _apply(self.align[self._segment], points.xyz_world), points.pixels,
                                   points.keyframe_index, points.stamp_ns, T)
            self._points = points
            self.keyframes.append(points, self._segment)
        return T, points is not None and result.state == TrackingState.OK


def run_state(tracker: Tracker, config: Config, spool: Path | None = None) -> RunState:
    """A run's accumulators over a tracker's logs (shared, not copied); ``spool``: where site rows go."""
    return RunState(timer=tracker.timer, trajectory=tracker.trajectory, tracking=tracker.tracking,
                    keyframes=tracker.keyframes, sites=SiteLog(spool),
                    noise=NoiseTracker(config.terrain.noise, config.terrain.noise_estimate))


# ----------------------------------------------------------------------------- fusion
@dataclass(frozen=True)
class Fusion:
    """One method's step from terrain maps to a site: score -> mask -> site.

    fuzzy and bayes have no state: the same frame, pose, maps and map points give the same
    Detection, whatever came before; what a run accumulates is added by ``tally``. px4slp (the
    PX4 grid planner) low-passes its grid over the frames, as upstream does: that state is its
    ``memory``, one per Fusion (so per recording and method), reset at a new map segment.
    ``slz compare`` runs one per method on the same maps and points.
    """

    config: Config
    method: str
    scorer: Scorer | Px4SlpPlanner
    params: SelectParams
    memory: Px4SlpMemory | None = field(default=None, compare=False)

    @classmethod
    def of(cls, config: Config, method: str) -> Fusion:
        if method == PX4SLP:
            return cls(config, method, Px4SlpPlanner.from_config(config), select_params(config, method),
                       Px4SlpMemory())
        return cls(config, method, get_scorer(config, method), select_params(config, method))

    def __call__(self, frame: Frame, T_world_camera: np.ndarray | None, maps: TerrainMaps, maps_ms: float,
                 points: MapPoints | None, segment: int) -> Detection:
        """Score, mask and (with a pose, map points and maps that vouch) the site of one frame."""
        if isinstance(self.scorer, Px4SlpPlanner):
            assert self.memory is not None
            return grid_detection(self.scorer, self.memory, self.config, frame, T_world_camera, maps, points, segment)
        t: dict[str, float] = {"maps": maps_ms}
        t0 = time.perf_counter()
        raw = self.scorer(maps)
        t["score"] = _lap(t0)
        t0 = time.perf_counter()
        score = mask_score(self.scorer, raw, frame.depth_m, frame.intrinsics, self.config, maps.work, maps.up_camera)
        t["mask"] = _lap(t0)
        edge = maps.edge_distance_m
        selection = None
        vouched = maps.work is None or maps.work.vouched
        t0 = time.perf_counter()
        if vouched and T_world_camera is not None and points is not None:
            selection = select_site(points.xyz_world, T_world_camera, frame.K, score.mask, score.score,
                                    self.params, edge_distance_m=edge)
        t["select"] = _lap(t0)
        return Detection(frame, T_world_camera, maps, score, points, selection, edge, t, segment)


def grid_detection(planner: Px4SlpPlanner, memory: Px4SlpMemory, config: Config, frame: Frame,
                   T_world_camera: np.ndarray | None, maps: TerrainMaps, points: MapPoints | None,
                   segment: int) -> Detection:
    """px4slp on one frame: grid update from the frame's depth points and pose, pixel mask, the planner's site.

    No terrain map is read but the edge distance (reported, not tested): the ``maps`` time is 0, the
    grid update is the ``score`` stage. Without a pose the grid is not updated (upstream needs the
    vehicle's position) and nothing is land-able. slz's noise limits do not gate it (upstream has none).
    """
    t: dict[str, float] = {"maps": 0.0}
    shape = frame.depth_m.shape
    if T_world_camera is None:
        empty = ScoreMap(planner.name, np.zeros(shape, np.float32), np.zeros(shape, bool))
        return Detection(frame, None, maps, empty, points, None, maps.edge_distance_m,
                         {**t, "score": 0.0, "mask": 0.0, "select": 0.0}, segment)
    t0 = time.perf_counter()
    state, cells = planner.step(memory, frame.depth_m, frame.intrinsics, T_world_camera, segment)
    t["score"] = _lap(t0)
    t0 = time.perf_counter()
    score, mask = planner.pixels(state, cells)
    t["mask"] = _lap(t0)
    t0 = time.perf_counter()
    selection = None
    if points is not None:
        p = planner.params
        selection = grid_site(state.hysteresis, state.mean, state.position, p.cell_size_m, p.smoothing_land_cell,
                              p.can_land_thr, points.xyz_world, T_world_camera, frame.K, mask,
                              (config.uav.footprint_m[0], config.uav.footprint_m[1]), maps.edge_distance_m)
    t["select"] = _lap(t0)
    return Detection(frame, T_world_camera, maps, ScoreMap(planner.name, score, mask), points, selection,
                     maps.edge_distance_m, t, segment)


def detect_frame(frame: Frame, T_world_camera: np.ndarray | None, tracker: Tracker, fusion: Fusion,
                 noise: NoiseTracker) -> Detection:
    """Maps (with the run's depth noise), then the fusion on the tracker's latest map points."""
    maps, maps_ms = posed_maps(frame, T_world_camera, fusion.config, noise.update(frame.depth_m))
    return fusion(frame, T_world_camera, maps, maps_ms, tracker.points, tracker.segment)


def detect(frames: Iterable[TrackedFrame], tracker: Tracker, fusion: Fusion, noise: NoiseTracker,
           limit: StageLimit) -> Iterator[Detection]:
    """The detection core: one Detection per tracked frame that is due, as the frames stream in.

    Nothing is written, counted or kept here: the run folder, results.mcap, the run's tables and
    the ground-truth evaluation consume the detections. ``frames``: ``tracked_frames`` (the
    tracker's points and segment are those of the frame just tracked). Each detection is a
    stage under ``limit``; the consumer's work on it is not.
    """
    for frame, T, due in frames:
        if due:
            with limit.stage(f"detection on frame {frame.index}"):
                try:
                    d = call_interruptibly(detect_frame, frame, T, tracker, fusion, noise)  # seconds of native work
                except FrameError as err:
                    raise DatasetError(limit.where, f"frame {frame.index}: {err}") from err
            yield d


def tally(state: RunState, det: Detection, config: Config) -> None:
    """Add one detection to a run's accumulators: stage times, counts, the no-site evidence, sites."""
    score, work = det.score, det.maps.work
    if score.column_cut > 0 or score.mask.any():
        cut = state.column_cut
        state.column_cut = score.column_cut if cut is None else min(cut, score.column_cut)
    grid = score.method == PX4SLP  # reads no terrain map: the maps' noise limits did not gate it
    if grid and det.selection is not None and det.selection.site is None:
        state.grid_reason = det.selection.reason
    if not grid and work is not None and not work.vouched:
        state.unvouched += 1
        worst = state.worst_unvouched
        if worst is None or work.altitude_m > worst.altitude_m:
            state.worst_unvouched = work
            state.unvouched_reason = limit_reason(work, config.terrain, config.uav)
    for name, ms in det.timings_ms.items():
        state.timer.add(name, ms)
    state.detections += 1
    state.detections_without_depth += not det.maps.valid.any()
    record(state.sites, det)


def record(sites: SiteLog, det: Detection) -> None:
    """Add a detection's site and candidates to the run's tables."""
    sel = det.selection
    if sel is None:
        return
    chosen = _chosen_cluster(sel.candidates, sel.site) if sel.site is not None else None
    sites.add_rows([{
        "frame": det.frame.index, "stamp_ns": det.frame.stamp_ns, "cluster": c.cluster, "points": c.points,
        "x": c.centroid_world[0], "y": c.centroid_world[1], "z": c.centroid_world[2],
        "normal_variance": c.normal_variance, "extent_x_m": c.extent_m[0], "extent_y_m": c.extent_m[1],
        "qualifies": c.qualifies, "reason": c.reason, "chosen": c.cluster == chosen, "segment": det.segment}
        for c in sel.candidates])
    if sel.site is not None:
        assert det.points is not None  # a site is chosen among the map points
        pts = det.points.xyz_world
        limits = det.maps.work.as_dict() if det.maps.work is not None else None
        sites.add_site(det.frame.ref(), sel.site, pts[sel.kept], pts[sel.labels == chosen], limits, det.segment,
                       kept_cluster=sel.labels[sel.kept])


def posed_maps(frame: Frame, T_world_camera: np.ndarray | None, config: Config,
               noise: DepthNoise | None = None) -> tuple[TerrainMaps, float]:
    """The four terrain maps of a frame (with its SLAM pose, when there is one) and their time in ms.

    ``noise``: the run's depth noise (``NoiseTracker.update``); None measures it on this frame alone.
    """
    posed = frame if T_world_camera is None else _with_pose(frame, T_world_camera)
    t0 = time.perf_counter()
    maps = frame_maps(posed, config, noise)
    return maps, _lap(t0)


def _chosen_cluster(candidates: Sequence[Candidate], site: Site) -> int:
    centre = np.asarray(site.center_world)
    return min(candidates, key=lambda c: float(np.linalg.norm(np.asarray(c.centroid_world) - centre))).cluster


def _apply(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return transform_points(T, xyz)


def _with_pose(frame: Frame, T: np.ndarray) -> Frame:
    return replace(frame, T_world_camera=T)


def _lap(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


def commit_radius_m(config: Config) -> float:
    """How close (in plan, metres) two detections' site centres must be to confirm each other."""
    return config.landing.commit_radius_factor * config.uav.footprint_m[0]


def commit_site(sites: list[dict[str, Any]], side_m: float, rule: str = "agree") -> dict[str, Any] | None:
    """The site confirmed by the most detections of its own map segment (see the module docstring).

    Adds ``support`` (agreeing detections, this one included), ``detections`` (sites of the run),
    ``segment`` and ``segment_detections`` (sites of that segment) to the chosen entry.
    ``rule`` ``latest`` (``landing.commit``, the paper's "current keyframe"): the last detection's
    site, accepted or not; its support is still counted.
    """
    if not sites:
        return None
    pool = [s for s in sites if s["site"].accepted] or sites
    if rule == "latest":
        pool = sites
    centres = np.array([s["site"].center_world for s in pool])
    seg = np.array([s["segment"] for s in pool])
    near = np.linalg.norm(centres[:, None, :2] - centres[None, :, :2], axis=2) <= side_m
    support = (near & (seg[:, None] == seg[None, :])).sum(axis=1)
    order = sorted(range(len(pool)), key=lambda i: (-support[i], pool[i]["site"].normal_variance,
                                                      -pool[i]["frame"].index))
    if rule == "latest":
        order = [max(range(len(pool)), key=lambda i: pool[i]["frame"].index)]
    best = dict(pool[order[0]])
    best["support"] = int(support[order[0]])
    best["detections"] = len(sites)
    best["segment"] = int(seg[order[0]])
    best["segment_detections"] = sum(s["segment"] == best["segment"] for s in sites)
    return best


# ----------------------------------------------------------------------------- one recording
@dataclass(frozen=True)
class RunOptions:
    """How to run a recording, beside its config; not in the config hash (they do not change results).

    force: replace a finished run in the run folder (redo it for the same key, replace one of
    another key; only the files a run writes are replaced). method: fuzzy | bayes | px4slp (None:
    scoring.method). timeout_s: bound on each stage in wall time (``--timeout``; None: none).
    """

    force: bool = False
    method: str | None = None
    timeout_s: float | None = None


def detect_recording(path: Path, config: Config, out_dir: Path, options: RunOptions = RunOptions(),
                     progress: Progress | None = None) -> dict[str, Any]:
    """Run detection over one recording into ``out_dir``; returns the run summary (run.json's summary).

    Memory does not grow with the recording: frames are streamed and dropped once written,
    keyframes, candidate rows and site points go to a spool in the temporary run folder; what
    stays per frame is its stamp, pose and stage times (~0.2 KB), per site its summary.
    """
    method = options.method or config.scoring.method
    limit = StageLimit(options.timeout_s, str(path))
    key, done_before = rerun_key(path, config, method, out_dir, options.force, limit)
    if done_before is not None:
        return done_before
    t_start = time.perf_counter()
    with output_dir.build(out_dir, output_dir.DETECT, replace=True) as tmp, ExitStack() as stack:
        with limit.stage("opening the recording"):
            gt = ground_truth_of(path, config)
            truth = None if gt is None else TruthEvaluator(gt)  # a sink: detection never reads the truth
            rec, info, clouds, config = open_inputs(path, config, stack)
        results = results_mcap.open_results(tmp, config, rec.recorded_frames())
        stack.enter_context(results)   # __enter__ returns the writer itself
        has_poses = any(c.role == "pose" and c.topic for c in info.choices)
        slam = stack.enter_context(get_backend(config, has_poses, clouds=clouds))
        tracker = Tracker(config, slam, KeyframeLog(tmp / SPOOL_DIR))
        state = run_state(tracker, config, tmp / SPOOL_DIR)
        noise = state.noise
        assert noise is not None
        # Files are written off the compute path, in order (results.mcap's poses too): closed before
        # results.mcap, dropped unwritten on an error (``outputs/background.py``).
        writer = stack.enter_context(BackgroundWriter(config.output.write_queue))

        def tracked(frame: Frame, T: np.ndarray | None) -> None:  # every frame, before its detection
            writer.submit(f"the pose of frame {frame.index}", results.write_pose, frame.stamp_ns, T, tracker.segment,
                          frame.T_world_camera)

        def write_frame(d: Detection) -> None:  # in the writer thread
            with state.timer.stage("write"):
                overlay = detection_overlay_bgr(d) if config.output.level != "summary" or config.output.results_mcap \
                    else None
                run_folder.write_detection(tmp, d, config, overlay)
                results.write_detection(d, overlay)

        def done(frame: Frame) -> None:  # every frame, after its detection went to the sinks
            if truth is not None:
                truth.frame(frame.stamp_ns)
            if progress is not None:
                progress(tracker.frames, info.expected_frames)

        # Closed first when the run stops early: its decoding thread stops before the recording is closed.
        frames = stack.enter_context(closing(each_frame(tracked_frames(path, rec, tracker, limit), tracked, done)))
        for d in detect(frames, tracker, Fusion.of(config, method), noise, limit):
            tally(state, d, config)  # the sinks: tables, ground truth, files
            if truth is not None:
                truth.detection(d)
            with limit.stage(f"writing {writer.busy_with() or f'frame {d.frame.index}'}"), \
                    state.timer.stage("write_wait"):  # waits only while the writer's queue is full
                writer.submit(f"frame {d.frame.index}", write_frame, d)
        state.frames = tracker.frames
        if state.frames == 0:
            raise DatasetError(path, no_frames_reason(rec.report))
        with limit.stage("writing the run folder"):
            writer.close()  # every frame written before the run's own files and results.mcap's end
            committed = commit_site(state.sites.sites, commit_radius_m(config), config.landing.commit)
            results.write_run(committed)
            result = summarise(path, config, method, info, rec.report, state, tracker.slam_name,
                               tracker.poses_are_recorded, committed, truth, time.perf_counter() - t_start, key)
            run_folder.write_run(tmp, result, state.sites, state.trajectory, state.keyframes)
            stack.close()  # SLAM worker, results.mcap and the recording, before the folder is renamed
            shutil.rmtree(tmp / SPOOL_DIR)
    return result.summary


def rerun_key(path: Path, config: Config, method: str, out_dir: Path, force: bool,
              limit: StageLimit) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The run's key (``fingerprint``) and, when ``out_dir`` holds a finished run of that key and
    ``force`` is off, its summary marked ``skipped`` (else None). Refuses an unusable ``out_dir``
    (OutputError) and one holding a finished run of another key without ``force``."""
    check_readable(path)  # a missing, looping or unreadable input is named before anything else reads it
    output_dir.refuse_inputs(out_dir, [path])
    existing = output_dir.inspect(out_dir, output_dir.DETECT)  # refuses a path that is not a detect run folder
    previous = existing.marker if existing.finished else None
    with limit.stage("hashing the inputs"):
        inputs = fingerprint.run_inputs(path, config, fingerprint.cache_of(existing.marker))
    vers = fingerprint.versions(config)
    key = {"sha256": fingerprint.run_key(config, method, inputs, vers), "method": method, "versions": vers,
           "inputs": inputs, "config": config.to_dict()}  # as asked; run.json's config adds what the recording set
    if previous is not None and not force:
        if (previous.get("key") or {}).get("sha256") == key["sha256"] and "summary" in previous:
            log.info("%s: already done for these inputs and config (%s); use --force to redo", out_dir, config.hash())
            return key, {**previous["summary"], "skipped": True}
        raise OutputError(out_dir, "holds a finished run of other inputs or config ("
                                   f"{fingerprint.what_changed(previous, config, method, inputs, vers)}); "
                                   "use --force to replace it (files slz did not write stay) or another -o")
    return key, None


def open_inputs(path: Path, config: Config, stack: ExitStack) -> tuple[Any, Any, bool, Config]:
    """The open recording (closed with ``stack``), its info, whether its frames carry recorded map clouds, and
    ``config`` with what the recording decides: the camera preset's depth noise prior and the frame period
    ORB-SLAM3 is told (``slam.orbslam3.nominal_period_s: auto``)."""
    rec = stack.enter_context(open_recording(path, config))
    info = rec.info()
    config = with_frame_period(with_noise_prior(config, info.camera_preset), info)
    return rec, info, has_recorded_clouds(info, config), config


def tracked_frames(path: Path, rec: Any, tracker: Tracker, limit: StageLimit) -> Generator[TrackedFrame, None, None]:
    """The frames of an open recording with their SLAM pose and whether detection is due.

    Reading each frame and tracking it are stages under ``limit``; shared by ``slz detect``
    and ``slz compare`` so both read, track and choose detection frames the same way.
    """
    config = tracker.config
    with closing(read_ahead(rec.frames(), config.sources.read_ahead_frames)) as frames:  # decoded in a thread
        yield from _track_each(path, frames, tracker, limit)


def _track_each(path: Path, frames: Iterator[Frame], tracker: Tracker, limit: StageLimit) -> Iterator[TrackedFrame]:
    config = tracker.config
    every = config.landing.every_nth_frame
    read = 0

    def next_frame() -> Frame | None:  # read, checked and handed to SLAM (a worker process starts on it)
        nonlocal read
        with limit.stage(f"reading frame {read}"):
            frame = next(frames, None)
        if frame is not None:
            read += 1
            check_frame_size(path, frame, config.sources.min_image_px)
            tracker.submit(frame)
        return frame

    ahead = config.slam.track_ahead
    frame = next_frame()
    while frame is not None:
        with limit.stage(f"SLAM on frame {frame.index}"):
            T, is_keyframe = tracker.collect(frame)
        after = next_frame() if ahead else None  # tracked (in a SLAM worker) while frame's detection runs
        yield frame, T, (is_keyframe if config.landing.detect_on == "keyframes" else frame.index % every == 0)
        frame = after if ahead else next_frame()


def each_frame(frames: Iterable[TrackedFrame], before: Callable[[Frame, np.ndarray | None], None],
               after: Callable[[Frame], None]) -> Generator[TrackedFrame, None, None]:
    """The frames unchanged, with the per-frame sinks: ``before`` each is handed on, ``after`` once the
    consumer asks for the next one (its detection, if any, has then gone through the sinks)."""
    for frame, T, due in frames:
        before(frame, T)
        yield frame, T, due
        after(frame)


def check_frame_size(path: Path, frame: Frame, min_px: tuple[int, ...]) -> None:
    """Refuse frames too small for feature tracking and the maps' windows (the native trackers throw)."""
    h, w = frame.rgb.shape[:2]
    if w < min_px[0] or h < min_px[1]:
        raise DatasetError(path, f"frame {frame.index} is {w}x{h} px, smaller than sources.min_image_px "
                                 f"{min_px[0]}x{min_px[1]}")
