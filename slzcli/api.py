"""The Python API: ``slzcli.detect`` and ``slzcli.load_config`` (re-exported, lazily, by ``slzcli``).

``detect`` runs the same steps as ``slz detect`` (``pipeline``: Tracker -> ``detect`` -> ``tally``
-> ``commit_site`` -> ``summarise``) on a recording or on frames already in memory:

- frames (any iterable of ``slzcli.Frame``, e.g. from a driver or numpy arrays): nothing is read
  from or written to disk; the result is a ``RunResult`` in memory.
- a recording path without ``out_dir``: read once, nothing written, the same ``RunResult``.
- a recording path with ``out_dir``: exactly ``slz detect RECORDING -o OUT_DIR`` (the run folder,
  the rerun key, ``force``); the result is read back from the run folder it wrote.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, closing
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

from slzcli.config import Config, load_config
from slzcli.errors import DatasetError

if TYPE_CHECKING:  # numpy comes with these: imported at the first call, so `import slzcli.cli` stays light
    from slzcli.pipeline import TrackedFrame
    from slzcli.timeout import StageLimit
    from slzcli.types import Frame, RunResult

__all__ = ["detect", "load_config"]
FRAMES_SOURCE = "<frames>"  # the source named in a result made from frames in memory


def detect(source: str | Path | Iterable[Frame], config: Config | None = None, out_dir: str | Path | None = None,
           *, method: str | None = None, force: bool = False, timeout_s: float | None = None) -> RunResult:
    """Detect the landing site of one recording or of a stream of frames (see the module docstring).

    ``config``: ``load_config(...)`` (default: the packaged defaults). ``method``: fuzzy | bayes
    (default ``scoring.method``). ``force`` and ``timeout_s`` as ``slz detect --force --timeout``.
    Frames need rgb (uint8 HxWx3), depth_m (float32 metres, NaN = none), intrinsics and a stamp;
    with ``T_world_camera`` on every frame the poses are used as recorded, else SLAM tracks them.
    Raises SlzError subclasses (ConfigError, DatasetError, ...) naming the file or key.
    """
    from slzcli.pipeline import RunOptions, detect_recording
    from slzcli.timeout import StageLimit

    config = load_config() if config is None else config
    method = method or config.scoring.method
    if isinstance(source, (str, Path)):
        path = Path(source)
        if out_dir is not None:
            out = Path(out_dir)
            detect_recording(path, config, out, RunOptions(force, method, timeout_s))
            return _read_run(out)
        return _in_memory(path, config, method, StageLimit(timeout_s, str(path)))
    if out_dir is not None:
        raise DatasetError(FRAMES_SOURCE, "out_dir needs a recording path: frames in memory are not written")
    return _run_frames(iter(source), None, config, method, StageLimit(timeout_s, FRAMES_SOURCE))


def _read_run(out: Path) -> RunResult:
    """The RunResult of a run folder ``slz detect`` wrote (``committed``: None, it is not stored)."""
    from slzcli.bounds import load_json
    from slzcli.types import RunResult

    run = load_json(out / "run.json", "run.json")
    landing = load_json(out / "landing.json", "landing.json")
    slam = run["summary"].get("slam") or {}
    primary = slam.get("segment")
    return RunResult(landing, run, None, primary, primary if slam.get("maps", 1) > 1 else None)


def _in_memory(path: Path, config: Config, method: str, limit: StageLimit) -> RunResult:
    from slzcli.pipeline import open_inputs

    with ExitStack() as stack:
        rec, info, clouds, config = open_inputs(path, config, stack)  # as slz detect
        return _run_frames(iter(rec.frames()), (path, rec, info, clouds), config, method, limit)


def _run_frames(frames: Iterator[Frame], opened: tuple[Any, ...] | None, config: Config, method: str,
                limit: StageLimit) -> RunResult:
    """The detection core over frames, with the run's accumulators in memory: nothing written."""
    from slzcli import pipeline
    from slzcli.evaluate.truth import TruthEvaluator
    from slzcli.slam import get_backend
    from slzcli.sources import RecordingInfo
    from slzcli.sources.window import no_frames_reason
    from slzcli.summary import summarise
    from slzcli.types import PairingReport

    t_start = time.perf_counter()
    truth = None
    first: Frame | None = None
    if opened is None:
        first = next(frames, None)
        if first is None:
            raise DatasetError(FRAMES_SOURCE, "no frame given")
        stamps: list[int] = []

        def counted(it: Iterator[Frame]) -> Iterator[Frame]:
            for f in it:
                stamps.append(f.stamp_ns)
                yield f

        frames = counted(_chain(first, frames))
        path, has_poses, clouds = Path(FRAMES_SOURCE), first.T_world_camera is not None, False
        rec = SimpleNamespace(frames=lambda: frames, report=PairingReport())
    else:
        path, rec, info, clouds = opened
        has_poses = any(c.role == "pose" and c.topic for c in info.choices)
        gt = pipeline.ground_truth_of(path, config)
        truth = None if gt is None else TruthEvaluator(gt)
    with ExitStack() as stack:
        slam = stack.enter_context(get_backend(config, has_poses, clouds=clouds))
        tracker = pipeline.Tracker(config, slam)
        state = pipeline.run_state(tracker, config)
        assert state.noise is not None
        fusion = pipeline.Fusion.of(config, method)
        tracked = stack.enter_context(closing(pipeline.tracked_frames(path, rec, tracker, limit)))  # reader first
        for d in pipeline.detect(_after_each(tracked, truth), tracker, fusion, state.noise, limit):
            pipeline.tally(state, d, config)
            if truth is not None:
                truth.detection(d)
        state.frames = tracker.frames
        if state.frames == 0:
            raise DatasetError(path, no_frames_reason(rec.report))
        committed = pipeline.commit_site(state.sites.sites, pipeline.commit_radius_m(config))
        if opened is None:
            assert first is not None
            rec.report = PairingReport(paired=state.frames)
            info = RecordingInfo(FRAMES_SOURCE, "frames", (max(stamps) - min(stamps)) * 1e-9, (), (),
                                 first.intrinsics, "Frame.intrinsics", rec.report)
        key: dict[str, Any] = {"sha256": None, "method": method, "inputs": {}}
        return summarise(path, config, method, info, rec.report, state, tracker.slam_name,
                         tracker.poses_are_recorded, committed, truth, time.perf_counter() - t_start, key)


def _chain(first: Frame, rest: Iterator[Frame]) -> Iterator[Frame]:
    yield first
    yield from rest


def _after_each(tracked: Iterator[TrackedFrame], truth: Any) -> Iterator[TrackedFrame]:
    """The tracked frames; the ground truth (if any) told of each frame once its detection went through."""
    for item in tracked:
        yield item
        if truth is not None:
            truth.frame(item[0].stamp_ns)
