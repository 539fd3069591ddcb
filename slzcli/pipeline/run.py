"""One detection run, read as its steps: open the source, track it, hand every tracked frame to the
methods, add their detections to each method's accumulators and to the sinks, commit, sum up.

``run`` is the one frame loop: ``slz detect`` (``detect_recording``: the run folder, results.mcap and
the ground truth as sinks), the Python API (``detect_in_memory``: nothing written), ``slz compare``
(several methods on the same tracked frames and maps: ``compare.py``'s sink) and batch workers call it.

Output safety (``outputs/output_dir.py``): ``-o`` must be missing, empty or a run folder of ``slz
detect``, and neither the recording nor a folder holding it; a rerun with the same key (config values,
method, versions, the bytes of every file read: ``fingerprint.py``) is skipped, one with another key
replaces a finished run only with ``--force``, and then only the files a run writes. The run folder is
built under a temporary name and put in place at the end, so a failed run leaves nothing a rerun would
trust. Memory does not grow with the recording: frames are streamed and dropped once written;
keyframes, candidate rows and site points go to a spool in the temporary run folder.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path

from slzcli import fingerprint
from slzcli.config import Config
from slzcli.errors import DatasetError, FrameError, OutputError
from slzcli.evaluate.truth import TruthEvaluator, ground_truth_of
from slzcli.interrupt import call_interruptibly
from slzcli.methods.base import Method, build
from slzcli.outputs import output_dir, results_mcap, run_folder
from slzcli.outputs.background import BackgroundWriter
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.summary_json import read_summary
from slzcli.outputs.trajectory import KeyframeLog
from slzcli.pipeline.commit import commit
from slzcli.pipeline.source import FramesSource, Source, open_source
from slzcli.pipeline.step import step, tally
from slzcli.pipeline.tracking import Tracker, open_slam, track
from slzcli.records import JsonObject, RunSummary
from slzcli.sources import check_readable
from slzcli.sources.window import no_frames_reason
from slzcli.summary import RunFacts, RunState, summarise
from slzcli.terrain.noise import NoiseTracker
from slzcli.timeout import StageLimit
from slzcli.types import Detection, Frame, RunResult, TerrainMaps, TrackedFrame

log = logging.getLogger(__name__)
Progress = Callable[[int, int | None], None]
SPOOL_DIR = ".spool"  # keyframes, candidate rows and site points of a run, inside its temporary run folder


@dataclass(frozen=True)
class RunOptions:
    """How to run a recording, beside its config; not in the config hash (they do not change results).

    force: replace a finished run in the run folder (redo it for the same key, replace one of
    another key; only the files a run writes are replaced). method: a registered method (None:
    scoring.method). timeout_s: bound on each stage in wall time (``--timeout``; None: none).
    """

    force: bool = False
    method: str | None = None
    timeout_s: float | None = None


@dataclass(eq=False)
class MethodRun:
    """One method of a run and what its detections add up to."""

    method: Method
    state: RunState


class Sink:
    """What consumes a run as it streams (the run folder, results.mcap, the ground truth, progress, the
    comparison); each hook does nothing unless a sink overrides it."""

    def tracked(self, t: TrackedFrame) -> None:
        """Every frame, once tracked, before its detections."""

    def detected(self, t: TrackedFrame, maps: TerrainMaps, detections: Sequence[Detection]) -> None:
        """A frame due: its maps and each method's detection (in the order of the run's methods)."""

    def done(self, t: TrackedFrame) -> None:
        """Every frame, once its detections went through the sinks."""


def run(source: Source, tracker: Tracker, runs: Sequence[MethodRun], noise: NoiseTracker, limit: StageLimit,
        sinks: Sequence[Sink] = ()) -> None:
    """Track every frame of ``source``, show it to every method, detect on the frames due (the maps once,
    every method on them), add each detection to its method's accumulators, hand everything to ``sinks``.

    Each detection frame is a stage under ``limit``; what the sinks do is not. DatasetError when the
    source gave no frame.
    """
    config = tracker.config
    methods = [r.method for r in runs]
    frames = track(source, tracker, limit)
    try:  # closed first when the run stops early: its decoding thread stops before the recording is closed
        for t in frames:
            for s in sinks:
                s.tracked(t)
            for r in runs:
                for name, ms in (r.method.observe(t) or {}).items():  # a stateful method's per-frame stages
                    r.state.timer.add(name, ms)
            if t.due:
                with limit.stage(f"detection on frame {t.frame.index}"):
                    try:
                        maps, dets = call_interruptibly(step, t, methods, config, noise)  # seconds of native work
                    except FrameError as err:  # the frame's content: name the recording and the frame
                        raise DatasetError(source.path, f"frame {t.frame.index}: {err}") from err
                for r, d in zip(runs, dets, strict=True):
                    tally(r.state, d, r.method, config.terrain, config.uav)
                for s in sinks:
                    s.detected(t, maps, dets)
            for s in sinks:
                s.done(t)
    finally:
        frames.close()
    for r in runs:
        r.state.frames = tracker.frames
    if tracker.frames == 0:
        raise DatasetError(source.path, no_frames_reason(source.report()))


def method_run(config: Config, method: str, tracker: Tracker, spool: Path | None = None) -> MethodRun:
    """The one method of a detect run, its accumulators over the tracker's logs (shared, not copied);
    ``spool``: where its site rows go."""
    state = RunState(timer=tracker.timer, trajectory=tracker.trajectory, tracking=tracker.tracking,
                     keyframes=tracker.keyframes, sites=SiteLog(spool),
                     noise=NoiseTracker(config.terrain.noise, config.terrain.noise_estimate))
    return MethodRun(build(method, config), state)


def finish(source: Source, config: Config, mr: MethodRun, tracker: Tracker, truth: TruthEvaluator | None,
           wall_s: float, key: JsonObject) -> RunResult:
    """The committed site (``landing.commit``) and landing.json / run.json of a finished run."""
    committed = commit(mr.state.sites, config.landing, config.uav)
    facts = RunFacts(source.path, mr.method.name, tracker.slam_name, tracker.poses_are_recorded, source.info(),
                     source.report(), wall_s, key)
    return summarise(facts, config, mr.state, committed, truth)


class TruthSink(Sink):
    """The ground-truth evaluation of a one-method run (detection never reads the truth)."""

    def __init__(self, truth: TruthEvaluator) -> None:
        self.truth = truth

    def detected(self, t: TrackedFrame, maps: TerrainMaps, detections: Sequence[Detection]) -> None:
        for d in detections:
            self.truth.detection(d)

    def done(self, t: TrackedFrame) -> None:
        self.truth.frame(t.frame.stamp_ns)


# ----------------------------------------------------------------------------- in memory (the Python API)
def detect_in_memory(source: Source, config: Config, method: str, limit: StageLimit,
                     truth: TruthEvaluator | None = None) -> RunResult:
    """A run with its accumulators in memory and nothing written: the API's result."""
    t_start = time.perf_counter()
    # the keyframes' map points spool to a temporary folder, as slz detect's do to its run folder: the summary
    # reads them (the site's height above the ground) and memory does not grow with the recording
    with tempfile.TemporaryDirectory(prefix="slz-spool-") as spool:
        with ExitStack() as stack:
            tracker = Tracker(config, open_slam(source, config.slam, stack), KeyframeLog(Path(spool)))
            mr = method_run(config, method, tracker)
            assert mr.state.noise is not None
            run(source, tracker, [mr], mr.state.noise, limit, [] if truth is None else [TruthSink(truth)])
        key: JsonObject = {"sha256": None, "method": method, "inputs": {}}
        return finish(source, config, mr, tracker, truth, time.perf_counter() - t_start, key)


def detect_recording_in_memory(path: Path, config: Config, method: str, limit: StageLimit) -> RunResult:
    """A recording read once, nothing written (the API without ``out_dir``)."""
    with ExitStack() as stack:
        with limit.stage("opening the recording"):
            gt = ground_truth_of(path, config.synth.ground_truth)
            source, config = open_source(path, config, stack)
        return detect_in_memory(source, config, method, limit, None if gt is None else TruthEvaluator(gt))


def detect_frames(frames: Iterable[Frame], config: Config, method: str, limit: StageLimit) -> RunResult:
    """Frames in memory (any iterable of ``Frame``), nothing read from or written to disk."""
    return detect_in_memory(FramesSource.of(iter(frames)), config, method, limit)


# ----------------------------------------------------------------------------- slz detect
class RunFolderSink(Sink):
    """results.mcap and the run folder's per-frame files, written off the compute path, in order, by a
    background writer (``outputs/background.py``); progress once a frame went through."""

    def __init__(self, tmp: Path, config: Config, results: results_mcap.ResultsMcap | results_mcap.NoResults,
                 writer: BackgroundWriter, state: RunState, limit: StageLimit, tracker: Tracker,
                 expected: int | None, progress: Progress | None) -> None:
        self.tmp, self.config, self.results, self.writer = tmp, config, results, writer
        self.state, self.limit, self.tracker, self.expected, self.progress = state, limit, tracker, expected, progress

    def tracked(self, t: TrackedFrame) -> None:
        self.writer.submit(f"the pose of frame {t.frame.index}", self.results.write_pose, t.frame.stamp_ns,
                           t.T_world_camera, t.segment, t.frame.T_world_camera)

    def detected(self, t: TrackedFrame, maps: TerrainMaps, detections: Sequence[Detection]) -> None:
        for d in detections:
            with self.limit.stage(f"writing {self.writer.busy_with() or f'frame {d.frame.index}'}"), \
                    self.state.timer.stage("write_wait"):  # waits only while the writer's queue is full
                self.writer.submit(f"frame {d.frame.index}", self._write_frame, d)

    def _write_frame(self, d: Detection) -> None:  # in the writer thread
        with self.state.timer.stage("write"):
            output = self.config.output
            overlay = detection_overlay_bgr(d) if output.level != "summary" or output.results_mcap else None
            run_folder.write_detection(self.tmp, d, self.config, overlay)
            self.results.write_detection(d, overlay)

    def done(self, t: TrackedFrame) -> None:
        if self.progress is not None:
            self.progress(self.tracker.frames, self.expected)


def detect_recording(path: Path, config: Config, out_dir: Path, options: RunOptions = RunOptions(),
                     progress: Progress | None = None) -> RunSummary:
    """Run detection over one recording into ``out_dir``; returns the run summary (run.json's summary)."""
    method = options.method or config.scoring.method
    limit = StageLimit(options.timeout_s, str(path))
    key, done_before = rerun_key(path, config, method, out_dir, options.force, limit)
    if done_before is not None:
        return done_before
    t_start = time.perf_counter()
    with output_dir.build(out_dir, output_dir.DETECT, replace=True) as tmp, ExitStack() as stack:
        with limit.stage("opening the recording"):
            gt = ground_truth_of(path, config.synth.ground_truth, key.digests)  # the recording's digests once
            truth = None if gt is None else TruthEvaluator(gt)  # a sink: detection never reads the truth
            source, config = open_source(path, config, stack)
        results = results_mcap.open_results(tmp, config, source.recording.recorded_frames())
        stack.enter_context(results)   # __enter__ returns the writer itself
        tracker = Tracker(config, open_slam(source, config.slam, stack), KeyframeLog(tmp / SPOOL_DIR))
        mr = method_run(config, method, tracker, tmp / SPOOL_DIR)
        state = mr.state
        assert state.noise is not None
        # closed before results.mcap, dropped unwritten on an error
        writer = stack.enter_context(BackgroundWriter(config.output.write_queue))
        sinks: list[Sink] = [RunFolderSink(tmp, config, results, writer, state, limit, tracker,
                                           source.expected_frames, progress)]
        if truth is not None:
            sinks.insert(0, TruthSink(truth))
        run(source, tracker, [mr], state.noise, limit, sinks)
        with limit.stage("writing the run folder"):
            writer.close()  # every frame written before the run's own files and results.mcap's end
            outputs = getattr(mr.method, "write_outputs", None)  # a method's own run-wide files (fused: its map)
            landing_grid = outputs(tmp) if outputs is not None else None   # and the landing map they hold
            wall_s = time.perf_counter() - t_start
            result = finish(source, config, mr, tracker, truth, wall_s, key.json())
            results.write_run(result.committed, landing_grid)
            run_folder.write_run(tmp, result, state.sites, state.trajectory, state.keyframes)
            stack.close()  # SLAM worker, results.mcap and the recording, before the folder is renamed
            shutil.rmtree(tmp / SPOOL_DIR)
    return result.summary


@dataclass(frozen=True)
class RunKey:
    """A run's key (``fingerprint``): run.json's ``key`` once the inputs are hashed, perhaps in the background
    (``fingerprint.PendingInputs``) while the run starts."""

    config: Config
    method: str
    versions: dict[str, str | None]
    inputs: dict[str, list[fingerprint.Entry]] | fingerprint.PendingInputs

    def hashed(self) -> dict[str, list[fingerprint.Entry]]:
        """The inputs with their digests (waits for the hashing)."""
        return self.inputs.result() if isinstance(self.inputs, fingerprint.PendingInputs) else self.inputs

    def json(self) -> JsonObject:
        """run.json's ``key`` (waits for the hashing)."""
        inputs = self.hashed()
        return {"sha256": fingerprint.run_key(self.config, self.method, inputs, self.versions), "method": self.method,
                "versions": self.versions, "inputs": inputs,
                "config": self.config.to_dict()}  # as asked; run.json's config adds what the recording set

    def digests(self) -> dict[str, fingerprint.Entry]:
        """The digests of the files read, by path (``fingerprint.cache_of``; waits for the hashing)."""
        return fingerprint.cache_of({"key": {"inputs": self.hashed()}})


def rerun_key(path: Path, config: Config, method: str, out_dir: Path, force: bool,
              limit: StageLimit) -> tuple[RunKey, RunSummary | None]:
    """The run's key (``fingerprint``) and, when ``out_dir`` holds a finished run of that key and
    ``force`` is off, its summary marked ``skipped`` (else None). Refuses an unusable ``out_dir``
    (OutputError) and one holding a finished run of another key without ``force``. When there is no
    finished run to compare the key with (or ``force`` replaces it anyway), the inputs are hashed in the
    background: the key is only recorded, at the end of the run."""
    check_readable(path)  # a missing, looping or unreadable input is named before anything else reads it
    output_dir.refuse_inputs(out_dir, [path])
    existing = output_dir.inspect(out_dir, output_dir.DETECT)  # refuses a path that is not a detect run folder
    previous = existing.marker if existing.finished else None
    cache = fingerprint.cache_of(existing.marker)
    vers = fingerprint.versions(config)
    if previous is None or force:
        return RunKey(config, method, vers, fingerprint.PendingInputs(path, config, cache)), None
    with limit.stage("hashing the inputs"):
        inputs = fingerprint.run_inputs(path, config, cache)
    key = RunKey(config, method, vers, inputs)
    if (previous.get("key") or {}).get("sha256") == key.json()["sha256"] and "summary" in previous:
        log.info("%s: already done for these inputs and config (%s); use --force to redo", out_dir, config.hash())
        return key, replace(read_summary(previous["summary"]), skipped=True)
    raise OutputError(out_dir, "holds a finished run of other inputs or config ("
                               f"{fingerprint.what_changed(previous, config, method, inputs, vers)}); "
                               "use --force to replace it (files slz did not write stay) or another -o")
