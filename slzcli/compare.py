"""``slz compare``: the fuzzy score against the Bayes baseline (issue 8, BASELINE.md) and the PX4-Avoidance
grid planner (issue 21, PX4SLP.md) on the same frames.

Only the fusion may differ. SLAM tracks every frame ONCE and the four terrain maps are
computed ONCE per detection frame; each method then scores, masks and selects on those
very arrays and the very same map points (one ``pipeline.run`` over all the methods). Every detection
records what it was given (frame index, stamp, a digest of the map points and of the
maps) and ``check_same_inputs`` refuses a comparison whose methods saw different inputs.

Reported per recording and method: time per stage and per frame (median, p90), the
committed site (``pipeline.commit``, as ``slz detect``), the distance between the
methods' sites (the paper's 1.249 m), the IoU of the methods' masks, and with ground
truth (``slz synth``): mask precision / recall / IoU, whether the site is truly safe, its
clearance, and a precision-recall sweep of every score map (and every single terrain map)
with the area under it.

Decisions:
- Pixel statistics are micro-averaged: counts are summed over all detection frames and
  all pixels (pixels without depth are predicted unsafe), as ``slz detect`` does.
- The sweep predicts ``score > tau`` for ``compare.pr_levels`` thresholds evenly spread on
  [0, 1] on the fused score *before* the safety-margin filter (the score map itself); at
  tau = 1 nothing is predicted and precision counts as 1. The area is the step-wise area
  (average precision, ``CurveCounts.auc``), so a saturated score is not flattered.
- Site distances are horizontal and vertical together (3-D, metres) in the run's world
  frame: both methods share it, so no alignment is needed. After a SLAM map reset two
  committed sites may lie in different map segments (unrelated frames): no distance then.
- Times are per detection frame: ``slam`` is the tracking time of that frame, ``maps`` the
  shared map time (counted for each method, as each would pay it alone; 0 for px4slp, which reads
  no terrain map: its grid update from the depth points is its ``score``), ``frame`` the sum
  of slam, maps, score, mask and select. Frames that are only tracked are not in ``frame``.
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slzcli.bounds import load_json
from slzcli.compare_records import (
    Compared,
    CompareSite,
    CompareSlam,
    Comparison,
    ComparisonFigures,
    Curve,
    FigureFrame,
    FrameDistances,
    InputDigest,
    MapTruth,
    MaskTruth,
    MethodComparison,
    MethodTruth,
    MethodView,
    PairComparison,
    ProfileComparison,
    ProfileRow,
    RecordingComparison,
    SceneRecord,
    StageTimes,
)
from slzcli.config import Config
from slzcli.errors import ConfigError, DatasetError
from slzcli.evaluate.safety import MaskCounts, mask_counts, total
from slzcli.evaluate.slam import ate_by_segment
from slzcli.evaluate.truth import ground_truth_of
from slzcli.geometry import project
from slzcli.landing.commit import commit_radius_m
from slzcli.methods.base import build
from slzcli.methods.registry import names as method_names
from slzcli.outputs import output_dir, report, run_lock
from slzcli.pipeline.commit import commit
from slzcli.pipeline.run import MethodRun as PipelineRun
from slzcli.pipeline.run import Sink
from slzcli.pipeline.run import run as run_methods
from slzcli.pipeline.source import open_source
from slzcli.pipeline.tracking import Tracker, open_slam
from slzcli.slam.segments import segment_table
from slzcli.sources.formats import run_suffixes
from slzcli.summary import RunState, no_site_reason, site_record, site_truth, untracked_frames
from slzcli.synth.groundtruth import GroundTruth, sidecar_paths
from slzcli.terrain.noise import NoiseTracker
from slzcli.timeout import StageLimit
from slzcli.types import CommittedSite, Detection, TerrainMaps, TrackedFrame

log = logging.getLogger(__name__)
Progress = Callable[[int, int | None], None]
STAGES = ("slam", "maps", "score", "mask", "select")


# ----------------------------------------------------------------------------- sweep counts
@dataclass
class CurveCounts:
    """True and false positives of ``value > tau`` for fixed thresholds, summed over frames."""

    thresholds: NDArray[np.float64]
    tp: NDArray[np.int64]
    fp: NDArray[np.int64]
    positives: int = 0

    @classmethod
    def empty(cls, levels: int) -> CurveCounts:
        return cls(np.linspace(0.0, 1.0, levels), np.zeros(levels, np.int64), np.zeros(levels, np.int64))

    def add(self, values: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame: O(n log levels), no sort of the pixels."""
        v = np.nan_to_num(values.astype(np.float64, copy=False), nan=-1.0).ravel()
        t = truth.astype(bool, copy=False).ravel()
        above = np.searchsorted(self.thresholds, v, side="left")  # how many thresholds lie below each value
        levels = self.thresholds.size
        for sel, acc in ((t, self.tp), (~t, self.fp)):
            hist = np.bincount(above[sel], minlength=levels + 1)
            acc += np.cumsum(hist[::-1])[::-1][1:]  # count(value > thresholds[j]) = sum of hist[j + 1:]
        self.positives += int(t.sum())

    def curve(self) -> Curve:
        """(precision, recall) per threshold; precision is 1 where nothing is predicted."""
        pred = self.tp + self.fp
        precision = np.where(pred > 0, self.tp / np.maximum(pred, 1), 1.0)
        recall = self.tp / max(self.positives, 1)
        return precision, recall

    def auc(self) -> float | None:
        """Area under the step-interpolated curve (average precision): sum of recall steps x precision.

        Steps, not trapezoids: a score that saturates (the Bayes probability is exactly 1.0 in
        float32 for most good pixels) gives one big recall jump, which a straight line to the
        ``(0, 1)`` end point would reward with precision it never reaches.
        """
        if self.positives == 0:
            return None
        precision, recall = self.curve()
        order = np.lexsort((-precision, recall))   # recall ascending; at equal recall the best precision first
        r, p = recall[order], precision[order]
        steps = np.diff(np.concatenate([[0.0], r]))
        return float(np.sum(steps * p))


# ----------------------------------------------------------------------------- per-method state
@dataclass
class MethodRun:
    """One method of the comparison: its run (the method and its accumulators) and what only the comparison needs."""

    name: str
    run: PipelineRun
    truth: list[MaskCounts] = field(default_factory=list)  # each detection's mask against the true safe mask
    inputs: list[tuple[int, int, str, str]] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)
    pr: CurveCounts | None = None
    mask_fractions: list[float] = field(default_factory=list)
    views: dict[int, tuple[NDArray[np.uint8], MethodView]] = field(default_factory=dict)  # frame: (rgb, view)

    @property
    def state(self) -> RunState:
        return self.run.state


def digest(*arrays: np.ndarray | None) -> str:
    """A short content digest of arrays (identity of the inputs each method saw)."""
    h = hashlib.blake2b(digest_size=8)
    for a in arrays:
        h.update(b"none" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def maps_digest(maps: TerrainMaps) -> str:
    return digest(*(getattr(maps, n) for n in TerrainMaps.NAMES), maps.valid)


def check_same_inputs(inputs: dict[str, list[tuple[int, int, str, str]]]) -> None:
    """Every method saw the same frames, map points and terrain maps, in the same order; else RuntimeError."""
    names = list(inputs)
    for other in names[1:]:
        if inputs[other] != inputs[names[0]]:
            raise RuntimeError(f"compare: methods {names[0]!r} and {other!r} were given different frames, "
                               "SLAM points or maps; the comparison would not isolate the fusion")


def resolve_methods(methods: tuple[str, ...] | list[str], key: str = "--methods") -> tuple[str, ...]:
    """Validated, de-duplicated method names (at least two; ConfigError naming ``key`` and the bad one)."""
    out: list[str] = []
    for m in methods:
        m = m.strip()
        if m not in method_names():
            raise ConfigError(key, f"unknown method {m!r}; known: {', '.join(method_names())}")
        if m not in out:
            out.append(m)
    if len(out) < 2:
        raise ConfigError(key, f"give at least two different methods to compare, got {', '.join(out)}")
    return tuple(out)


# ----------------------------------------------------------------------------- one recording
def compare_recording(path: Path, config: Config, methods: tuple[str, ...],
                      progress: Progress | None = None, timeout_s: float | None = None) -> Compared:
    """Run every method over one recording, sharing SLAM and maps; returns the numbers and the figure arrays.

    ``timeout_s`` bounds each stage as ``slz detect --timeout`` does (slzcli/timeout.py).
    """
    path = Path(path)
    limit = StageLimit(timeout_s, str(path))
    levels = config.compare.pr_levels
    t_start = time.perf_counter()
    with ExitStack() as stack:
        with limit.stage("opening the recording"):
            truth = ground_truth_of(path, config.synth.ground_truth)
            source, config = open_source(path, config, stack)
        tracker = Tracker(config, open_slam(source, config.slam, stack))
        noise = NoiseTracker(config.terrain.noise, config.terrain.noise_estimate)  # the maps', shared
        runs = {m: MethodRun(m, PipelineRun(build(m, config), RunState()),
                             pr=CurveCounts.empty(levels) if truth is not None else None) for m in methods}
        sink = CompareSink(runs, truth, levels, tracker, source.expected_frames, progress)
        run_methods(source, tracker, [r.run for r in runs.values()], noise, limit, [sink])
    check_same_inputs({m: r.inputs for m, r in runs.items()})
    return _summarise(path, config, methods, runs, tracker, noise, truth, sink.map_curves, sink.map_means,
                      sink.agreement, time.perf_counter() - t_start)


class CompareSink(Sink):
    """What the comparison adds up over the shared frames: each method's inputs, times, masks against the
    truth and the other methods, the single maps' curves, the Figure 6 arrays."""

    def __init__(self, runs: dict[str, MethodRun], truth: GroundTruth | None, levels: int, tracker: Tracker,
                 expected: int | None, progress: Progress | None) -> None:
        self.runs, self.truth, self.tracker, self.expected, self.progress = runs, truth, tracker, expected, progress
        self.map_curves = {n: CurveCounts.empty(levels) for n in TerrainMaps.NAMES}
        self.map_means: dict[str, list[float]] = {f"{n}_{c}": [] for n in TerrainMaps.NAMES for c in ("safe", "unsafe")}
        self.agreement: dict[str, list[MaskCounts]] = {}

    def detected(self, t: TrackedFrame, maps: TerrainMaps, detections: Sequence[Detection]) -> None:
        truth = self.truth
        gt_mask = truth.safe_mask(t.frame.stamp_ns) if truth is not None else None
        dets = dict(zip(self.runs, detections, strict=True))
        for m, d in dets.items():
            _account(self.runs[m], t, maps, d, gt_mask)
        _agree(dets, self.agreement)
        _forget_views(self.runs, next(iter(self.runs)), t.frame.index)
        if gt_mask is not None:
            _map_truth(maps, gt_mask, self.map_curves, self.map_means)

    def done(self, t: TrackedFrame) -> None:
        if self.progress is not None:
            self.progress(self.tracker.frames, self.expected)


def _account(run: MethodRun, t: TrackedFrame, maps: TerrainMaps, d: Detection, gt_mask: np.ndarray | None) -> None:
    """One method's detection of a shared frame, in the comparison's own tables."""
    if gt_mask is not None:
        run.truth.append(mask_counts(d.score.mask, gt_mask))
    run.state.timer.add("slam", t.slam_ms)  # the shared tracking time of the frame, as each method would pay it
    pts = d.points
    frame = t.frame
    run.inputs.append((frame.index, frame.stamp_ns, digest(None if pts is None else pts.ids,
                                                           None if pts is None else pts.xyz_world),
                       maps_digest(maps)))
    run.frame_ms.append(t.slam_ms + sum(d.timings_ms[k] for k in ("maps", "score", "mask", "select")))
    if run.pr is not None and gt_mask is not None:
        run.pr.add(d.score.score, gt_mask)
    run.mask_fractions.append(float(d.score.mask.mean()))
    run.views[frame.index] = (d.frame.rgb, _view(d))


def _forget_views(runs: dict[str, MethodRun], first: str, current: int) -> None:
    """Keep Figure 6 arrays only for frames that may hold the committed site, and the latest frame.

    The committed site (known at the end) is one of the first method's sites, so the other
    frames' arrays can go: memory grows with the frames that gave a site, not with the recording.
    """
    with_site = {s.frame.index for s in runs[first].state.sites.sites}
    for run in runs.values():
        for k in [k for k in run.views if k != current and k not in with_site]:
            del run.views[k]


def _view(d: Detection) -> MethodView:
    """What the Figure 6 panel draws for one method and frame (kept small: float16 score)."""
    sel = d.selection
    corners = None
    if sel is not None and sel.site is not None and d.T_world_camera is not None:
        corners, _ = project(np.asarray(sel.site.corners_world), d.T_world_camera, d.frame.K, d.score.mask.shape)
    return MethodView(d.score.score.astype(np.float16), d.score.mask, None if sel is None else sel.projected,
                      None if sel is None else sel.kept, None if sel is None else sel.labels, corners)


def _agree(dets: dict[str, Detection], agreement: dict[str, list[MaskCounts]]) -> None:
    names = list(dets)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            agreement.setdefault(f"{a}|{b}", []).append(mask_counts(dets[a].score.mask, dets[b].score.mask))


def _map_truth(maps: TerrainMaps, gt_mask: np.ndarray, curves: dict[str, CurveCounts],
               means: dict[str, list[float]]) -> None:
    valid = maps.valid
    for n in TerrainMaps.NAMES:
        values = getattr(maps, n)
        curves[n].add(values, gt_mask)
        for cls, sel in (("safe", gt_mask & valid), ("unsafe", ~gt_mask & valid)):
            if sel.any():
                means[f"{n}_{cls}"].append(float(values[sel].mean()))


def _stats(values: Sequence[float]) -> StageTimes:
    if not values:
        return StageTimes(None, None)
    a = np.asarray(values)
    return StageTimes(round(float(np.median(a)), 3), round(float(np.percentile(a, 90)), 3))


def _method(m: str, run: MethodRun, committed: CommittedSite | None, config: Config, tracker: Tracker,
            truth: GroundTruth | None) -> MethodComparison:
    """One method's entry of a recording: its detections, committed site (or why none), times, inputs, truth."""
    st = run.state
    timing = {k: _stats(st.timer.samples_ms.get(k, [])) for k in STAGES}
    timing["frame"] = _stats(run.frame_ms)
    reason = None if committed is not None else no_site_reason(st, tracker.slam_name, len(tracker.keyframes),
                                                               commit_radius_m(config.landing, config.uav))
    site = None if committed is None else site_record(committed, site_truth(truth, committed))
    ground_truth = None
    if truth is not None:
        counts = total(run.truth)
        mask = MaskTruth(counts.precision, counts.recall, counts.iou, counts.tp, counts.fp, counts.fn, counts.tn)
        ground_truth = MethodTruth(mask=mask, site=None if site is None else site.ground_truth,
                                   pr_auc=run.pr.auc() if run.pr is not None else None,
                                   false_safe_rate=counts.fp / (counts.fp + counts.tn) if counts.fp + counts.tn
                                   else None)
    return MethodComparison(
        method=m, detections=st.detections, sites_found=len(st.sites.sites),
        status="no_safe_site" if committed is None else "site",
        reason=reason, timings_ms=timing,
        site_world=None if site is None else site.center_world,
        site=None if committed is None or site is None else CompareSite(
            frame=committed.frame.index, stamp_ns=committed.frame.stamp_ns, center_world=site.center_world,
            center_camera=site.center_camera, score=site.score, cluster_points=site.cluster.points,
            acceptance=site.acceptance, support=site.support, map_segment=committed.segment),
        mask_fraction=_mask_fraction(run), detections_not_vouched=st.unvouched,
        inputs=tuple(InputDigest(i, t, p, q) for i, t, p, q in run.inputs), ground_truth=ground_truth)


def _summarise(path: Path, config: Config, methods: tuple[str, ...], runs: dict[str, MethodRun], tracker: Tracker,
               noise: NoiseTracker, truth: GroundTruth | None, map_curves: dict[str, CurveCounts],
               map_means: dict[str, list[float]], agreement: dict[str, list[MaskCounts]],
               wall_s: float) -> Compared:
    committed_of = {m: commit(run.state.sites, config.landing, config.uav) for m, run in runs.items()}
    per = {m: _method(m, run, committed_of[m], config, tracker, truth) for m, run in runs.items()}
    pairs = tuple(_pair(a, b, runs, committed_of, agreement.get(f"{a}|{b}", []))
                  for i, a in enumerate(methods) for b in methods[i + 1:])
    scene = maps = None
    if truth is not None:
        header = truth.header
        scene = SceneRecord(header.get("scene"), tuple(header.get("variants", [])), header.get("seed"))
        maps = {n: MapTruth(map_curves[n].auc(), _mean(map_means[f"{n}_safe"]), _mean(map_means[f"{n}_unsafe"]))
                for n in TerrainMaps.NAMES}
    record = RecordingComparison(
        source=str(path), name=recording_name(path), frames=tracker.frames,
        detections=runs[methods[0]].state.detections, slam_backend=tracker.slam_name, tracking=tracker.tracking,
        keyframes=len(tracker.keyframes),
        slam=CompareSlam(maps=len(segment_table(tracker.trajectory.segments(), tracker.trajectory.has_pose(),
                                                tracker.keyframes.per_segment)),
                         ate_rmse_m=_ate_rmse(tracker, truth),
                         frames_digest=digest(np.asarray(tracker.trajectory.stamps)),
                         untracked=untracked_frames(tracker.trajectory.has_pose(), tracker.tracking,
                                                    tracker.slam_name, config.slam.max_untracked_share)),
        inputs_identical=True, methods=per, pairs=pairs, wall_s=round(wall_s, 3), ground_truth=truth is not None,
        depth_noise=noise.summary(), scene=scene, maps=maps)
    return Compared(record, _figures(runs, committed_of, map_curves, truth is not None))


def _ate_rmse(tracker: Tracker, truth: GroundTruth | None) -> float | None:
    """SLAM's ATE (m, each map segment aligned on its own) against the true poses; None without truth or poses."""
    if truth is None:
        return None
    true: list[np.ndarray | None] = []
    for stamp in tracker.trajectory.stamps:
        try:
            true.append(np.asarray(truth.T_world_camera[truth.index_of(stamp)], np.float64))
        except DatasetError:
            true.append(None)
    try:
        return ate_by_segment(tracker.trajectory.poses(), true, tracker.trajectory.segments().tolist()).rmse_m
    except ValueError:  # fewer than 3 tracked frames in every segment
        return None


def _mean(v: list[float]) -> float | None:
    return float(np.mean(v)) if v else None


def _mask_fraction(run: MethodRun) -> float | None:
    return float(np.mean(run.mask_fractions)) if run.mask_fractions else None


def _pair(a: str, b: str, runs: dict[str, MethodRun], committed: dict[str, CommittedSite | None],
          counts: list[MaskCounts]) -> PairComparison:
    ca, cb = committed[a], committed[b]
    dist = None
    if ca is not None and cb is not None and ca.segment == cb.segment:  # else: two unrelated SLAM maps
        dist = float(np.linalg.norm(np.asarray(ca.site.center_world) - np.asarray(cb.site.center_world)))
    per_frame = []
    sites_a = {s.frame.index: s.site for s in runs[a].state.sites.sites}
    sites_b = {s.frame.index: s.site for s in runs[b].state.sites.sites}
    for k in sorted(set(sites_a) & set(sites_b)):
        gap = np.asarray(sites_a[k].center_world) - np.asarray(sites_b[k].center_world)
        per_frame.append(float(np.linalg.norm(gap)))
    agree = total(counts)
    return PairComparison(
        methods=(a, b), site_distance_m=dist,
        per_frame_site_distance_m=FrameDistances(float(np.mean(per_frame)) if per_frame else None, len(per_frame)),
        mask_iou=agree.iou,
        # both masks empty in every frame: agreement says nothing (it would be 1 on any input)
        masks_empty=agree.tp + agree.fp + agree.fn == 0,
        mask_agreement=(agree.tp + agree.tn) / max(agree.tp + agree.fp + agree.fn + agree.tn, 1))


def _figures(runs: dict[str, MethodRun], committed: dict[str, CommittedSite | None],
             map_curves: dict[str, CurveCounts], has_truth: bool) -> ComparisonFigures:
    """Arrays for the figures (not JSON): the Figure 6 frame, PR curves, timing samples."""
    first = next(iter(runs))
    frames = list(runs[first].views)
    fig_frame = None
    if frames:
        c = committed[first]
        index = c.frame.index if c is not None else frames[-1]
        fig_frame = FigureFrame(index, runs[first].views[index][0], {m: r.views[index][1] for m, r in runs.items()})
    curves: dict[str, Curve] = {}
    if has_truth:
        curves = {m: r.pr.curve() for m, r in runs.items() if r.pr is not None}
        curves.update({f"map:{n}": c.curve() for n, c in map_curves.items()})
    timings = {m: {**{k: list(r.state.timer.samples_ms.get(k, [])) for k in STAGES}, "frame": list(r.frame_ms)}
               for m, r in runs.items()}
    return ComparisonFigures(fig_frame, curves, timings)


def recording_name(path: Path) -> str:
    name = Path(path).name.rstrip("/") or "recording"
    for suffix in run_suffixes():
        name = name.removesuffix(suffix)
    return name


# ----------------------------------------------------------------------------- variants
def render_variants(path: Path, config: Config, out_dir: Path, variants: tuple[str, ...],
                    progress: Progress | None = None) -> list[Path]:
    """Re-render a synth recording's scene once per variant (same flight, seed and frames) into ``out_dir``."""

    from slzcli.synth import record

    header_path = sidecar_paths(path)[1]
    if not header_path.is_file():
        raise DatasetError(path, f"--variants needs a `slz synth` recording ({header_path.name} not found)")
    header = load_json(header_path, "ground-truth header (.gt.json)")
    try:
        base = tuple(header.get("variants", []))
        options = dict(scene=str(header["scene"]), frames=int(header["frames"]), rate_hz=float(header["rate_hz"]),
                       path=str(header["path"]), seed=int(header["seed"]),
                       start_m=tuple(float(v) for v in header["start_m"]))
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError) as err:
        raise DatasetError(header_path, f"unreadable synth header ({err})") from err
    out = []
    for v in variants:
        target = Path(out_dir) / f"{options['scene']}_{v}.mcap"
        opts = record.SynthOptions(**options, variants=(*(x for x in base if x != v), v))  # type: ignore[arg-type]
        record.synthesize(target, opts, config, progress=None, force=True)
        out.append(target)
        if progress is not None:
            progress(len(out), len(variants))
    return out


# ----------------------------------------------------------------------------- the command
def _unique_names(results: list[Compared]) -> list[Compared]:
    """Recordings with the same file name in different folders get _2, _3, ... (their figure folders)."""
    seen: dict[str, int] = {}
    out = []
    for r in results:
        n = seen[r.record.name] = seen.get(r.record.name, 0) + 1
        out.append(r if n == 1 else replace(r, record=replace(r.record, name=f"{r.record.name}_{n}")))
    return out


def compare(paths: list[Path], config: Config, out_dir: Path, methods: tuple[str, ...] | None = None, *,
            variants: bool = False, force: bool = False, progress: Progress | None = None,
            timeout_s: float | None = None) -> Comparison:
    """Compare the methods over each recording (and, with ``variants``, its scene's variants) into ``out_dir``.

    ``timeout_s`` bounds each stage of each recording and the final write (not the rendering of variants).
    """
    methods = resolve_methods(methods) if methods else resolve_methods(config.compare.methods, "compare.methods")
    for p in paths:
        if not Path(p).exists():
            raise DatasetError(p, "no such file or folder")
        if variants and not sidecar_paths(p)[1].is_file():  # fail before the long work, not after it
            raise DatasetError(p, f"--variants needs a `slz synth` recording ({sidecar_paths(p)[1].name} not found)")
    output_dir.refuse_inputs(out_dir, [Path(p) for p in paths])
    existing = output_dir.inspect(out_dir, output_dir.COMPARE)  # refuses a path that is not a compare folder
    output_dir.check_names(existing, [recording_name(Path(p)) for p in paths])  # before the long work
    with run_lock.claim(out_dir), output_dir.build(out_dir, output_dir.COMPARE, replace=force) as tmp:
        results = _unique_names([compare_recording(Path(p), config, methods, progress, timeout_s) for p in paths])
        variant_results: list[Compared] = []
        if variants:
            for p, base in zip(paths, results, strict=True):
                folder = tmp / "variants" / base.record.name
                for rec_path in render_variants(Path(p), config, folder, config.compare.variants):
                    r = compare_recording(rec_path, config, methods, progress, timeout_s)
                    variant_results.append(replace(r, record=replace(r.record, variant_of=base.record.name)))
        with StageLimit(timeout_s, str(out_dir)).stage("writing the comparison"):
            summary = report.write_comparison(tmp, config, methods, results, variant_results)
    return summary


# ----------------------------------------------------------------------------- profiles
def profile_row(result: RecordingComparison, profile: str, method: str) -> ProfileRow:
    """One recording under one profile: what ``slz compare --profiles`` and benchmarks/ablation.py report."""
    m = result.methods[method]
    gt = m.ground_truth
    mask = None if gt is None else gt.mask
    site = None if gt is None else gt.site
    t = m.timings_ms
    return ProfileRow(
        recording=result.name, profile=profile, method=method, frames=result.frames, detections=m.detections,
        slam_backend=result.slam_backend, tracking=result.tracking, slam_maps=result.slam.maps,
        ate_rmse_m=result.slam.ate_rmse_m, precision=None if mask is None else mask.precision,
        recall=None if mask is None else mask.recall, iou=None if mask is None else mask.iou,
        pr_auc=None if gt is None else gt.pr_auc, status=m.status, reason=m.reason,
        site_safe=None if site is None else site.get("safe"),
        clearance_m=None if site is None else site.get("clearance_m"),
        frame_ms_median=t["frame"].median_ms, maps_ms_median=t["maps"].median_ms, slam_ms_median=t["slam"].median_ms)


def compare_profiles(paths: list[Path], configs: dict[str, Config], out_dir: Path, method: str | None = None, *,
                     force: bool = False, progress: Progress | None = None,
                     timeout_s: float | None = None) -> ProfileComparison:
    """Each recording under each profile (a whole config: SLAM, maps, fusion, commit), into ``out_dir``.

    Profiles may change SLAM, so keyframes and detection frames may differ; every profile reads the
    same recording frames (checked by their stamps). ``method``: the fusion of every profile (None:
    each profile's ``scoring.method``).
    """
    if len(configs) < 2:
        raise ConfigError("--profiles", f"give at least two different profiles to compare, got {', '.join(configs)}")
    if method is not None and method not in method_names():
        raise ConfigError("--methods", f"unknown method {method!r}; known: {', '.join(method_names())}")
    for p in paths:
        if not Path(p).exists():
            raise DatasetError(p, "no such file or folder")
    output_dir.refuse_inputs(out_dir, [Path(p) for p in paths])
    output_dir.inspect(out_dir, output_dir.COMPARE)
    rows: list[ProfileRow] = []
    with run_lock.claim(out_dir), output_dir.build(out_dir, output_dir.COMPARE, replace=force) as tmp:
        for p in paths:
            stamps: dict[str, str] = {}
            for name, cfg in configs.items():
                m = method or cfg.scoring.method
                r = compare_recording(Path(p), cfg, (m,), progress, timeout_s).record
                stamps[name] = r.slam.frames_digest
                rows.append(profile_row(r, name, m))
            if len(set(stamps.values())) > 1:
                raise RuntimeError(f"compare: profiles {', '.join(stamps)} read different frames of {p}")
        summary = ProfileComparison(tuple(configs), {n: c.hash() for n, c in configs.items()},
                                    tuple(str(p) for p in paths), tuple(rows))
        report.write_profiles(tmp, summary, configs)
    return summary
