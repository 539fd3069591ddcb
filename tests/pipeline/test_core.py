"""The detection core: the one frame loop (``pipeline.run``) over tracked frames, stateless map methods,
ground truth as a sink.

The loop is run here with no run folder and must give what ``slz detect`` writes.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest
from conftest import GAUSSIAN, synth_recording

from slzcli.cli import main
from slzcli.config import Config, load_config
from slzcli.evaluate.safety import total
from slzcli.evaluate.truth import TruthEvaluator, ground_truth_of
from slzcli.methods.base import Method
from slzcli.pipeline import run as run_module
from slzcli.pipeline.commit import commit
from slzcli.pipeline.run import Sink, TruthSink, method_run, run
from slzcli.pipeline.source import open_source
from slzcli.pipeline.tracking import Tracker, open_slam
from slzcli.slam import get_backend
from slzcli.summary import RunState
from slzcli.timeout import StageLimit
from slzcli.types import Detection, TrackedFrame

FRAMES = 4


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("flights") / "parking_lot.mcap", "parking_lot", FRAMES, *GAUSSIAN)


class Kept(Sink):
    """The detections of a run, kept."""

    def __init__(self) -> None:
        self.detections: list[Detection] = []

    def detected(self, t: TrackedFrame, maps, detections) -> None:
        self.detections.extend(detections)


def run_core(path: Path, config: Config,
             method: str) -> tuple[list[Detection], RunState, TruthEvaluator, Method]:
    """open / track / the frame loop with the ground truth and a sink that keeps the detections."""
    gt = ground_truth_of(path, config.synth.ground_truth)
    assert gt is not None
    truth = TruthEvaluator(gt)
    limit = StageLimit(None, str(path))
    kept = Kept()
    with ExitStack() as stack:
        source, config = open_source(path, config, stack)
        tracker = Tracker(config, open_slam(source, config.slam, stack))
        mr = method_run(config, method, tracker)
        assert mr.state.noise is not None
        run(source, tracker, [mr], mr.state.noise, limit, [TruthSink(truth), kept])
    return kept.detections, mr.state, truth, mr.method


def test_the_core_gives_what_slz_detect_writes(runner, recording, tmp_path) -> None:
    config = load_config()
    dets, state, truth, _ = run_core(recording, config, config.scoring.method)
    assert dets, "no detection frame: the test would compare nothing"
    res = runner.invoke(main, ["detect", str(recording), "-o", str(tmp_path / "run"), "--json"])
    assert res.exit_code == 0, res.output + res.stderr
    landing = json.loads((tmp_path / "run" / "landing.json").read_text())
    summary = json.loads((tmp_path / "run" / "run.json").read_text())["summary"]
    assert summary["detections"] == len(dets) == state.detections
    assert total(truth.masks).as_dict() == summary["ground_truth"]["mask"]
    committed = commit(state.sites, config.landing, config.uav)
    assert (committed is None) == (landing["status"] != "site")
    if committed is not None:
        assert landing["frame"]["index"] == committed.frame.index
        assert np.allclose(landing["site"]["center_world"], committed.site.center_world, atol=1e-6)


@pytest.mark.parametrize("method", ["fuzzy", "bayes"])
def test_map_methods_keep_no_state(recording, method) -> None:
    """The same inputs give the same mask and site, after any number of other frames."""
    config = load_config()
    dets, _, _, m = run_core(recording, config, method)
    for d in reversed(dets):  # the other order: nothing carried over from the previous frame
        again = m.detect(TrackedFrame(d.frame, d.T_world_camera, d.segment, d.points, True, 0.0), d.maps, 0.0)
        assert np.array_equal(again.score.mask, d.score.mask)
        assert np.array_equal(again.score.score, d.score.score, equal_nan=True)
        assert (again.selection is None) == (d.selection is None)
        if d.selection is not None and again.selection is not None:
            assert again.selection.site == d.selection.site


def _tree(run: Path) -> dict[str, bytes]:
    """The files of a run folder that do not hold timings (run.json, landing.json, results.mcap and report.html
    carry them)."""
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*"))
            if p.is_file() and p.name not in {"run.json", "landing.json", "results.mcap", "report.html"}}


def test_overlapping_the_stages_changes_no_result(runner, recording, tmp_path) -> None:
    """SLAM one frame ahead and the background writer change when work is done, never what is written."""
    runs = {}
    for name, sets in {"overlapped": (), "sequential": ("slam.track_ahead=false", "output.write_queue=0")}.items():
        out = tmp_path / name
        args = ["detect", str(recording), "-o", str(out), "--set", "slam.backend=odometry",
                "--set", "landing.detect_on=every_nth", "--set", "landing.every_nth_frame=1"]
        for s in sets:
            args += ["--set", s]
        res = runner.invoke(main, args)
        assert res.exit_code == 0, res.output + res.stderr
        landing = json.loads((out / "landing.json").read_text())
        landing.pop("timings_ms")
        summary = json.loads((out / "run.json").read_text())["summary"]
        runs[name] = (landing, summary["detections"], summary["ground_truth"], _tree(out))
    a, b = runs["overlapped"], runs["sequential"]
    assert a[1] == b[1] == FRAMES  # every frame a detection: every write went through the writer
    assert a[0] == b[0] and a[2] == b[2]
    assert a[3].keys() == b[3].keys() and any(k.endswith("maps.npz") for k in a[3])
    assert a[3] == b[3]


def test_slam_is_handed_the_next_frame_before_this_frames_detection(recording, monkeypatch) -> None:
    """track_ahead: frame n+1 goes to the backend (a worker process starts on it) before frame n is detected."""
    events: list[str] = []
    real_step = run_module.step

    def step(tracked, *args):
        events.append(f"detect {tracked.frame.index}")
        return real_step(tracked, *args)

    monkeypatch.setattr(run_module, "step", step)
    config = load_config(None, ["slam.backend=odometry", "landing.detect_on=every_nth", "landing.every_nth_frame=1"])
    limit = StageLimit(None, str(recording))
    with ExitStack() as stack:
        source, config = open_source(recording, config, stack)
        slam = stack.enter_context(get_backend(config.slam, False))
        real_submit, real_collect = slam.submit, slam.collect
        def submit(frame):
            events.append(f"submit {frame.index}")
            real_submit(frame)

        def collect():
            events.append("collect")
            return real_collect()

        monkeypatch.setattr(slam, "submit", submit)
        monkeypatch.setattr(slam, "collect", collect)
        tracker = Tracker(config, slam)
        mr = method_run(config, "fuzzy", tracker)
        assert mr.state.noise is not None
        run(source, tracker, [mr], mr.state.noise, limit)
    want = ["submit 0", "collect"]
    for i in range(FRAMES):
        want += [f"submit {i + 1}"] if i + 1 < FRAMES else []
        want += [f"detect {i}"] + (["collect"] if i + 1 < FRAMES else [])
    assert events == want


def test_a_backend_taking_two_frames_gets_the_next_two_and_answers_each_frame_in_order(recording, monkeypatch) -> None:
    """A backend whose worker takes a frame while it tracks another (``in_flight`` 2, ORB-SLAM3's): frames n+1 and
    n+2 are in its hands while frame n is detected, each detection gets its own frame's pose, and the poses are
    those of one frame at a time."""
    from collections import deque

    real_step = run_module.step

    def tracked_run(in_flight: int) -> tuple[list[str], list[tuple[int, np.ndarray | None]]]:
        events: list[str] = []
        poses: list[tuple[int, np.ndarray | None]] = []

        def step(tracked, *args):
            events.append(f"detect {tracked.frame.index}")
            poses.append((tracked.frame.index, tracked.T_world_camera))
            return real_step(tracked, *args)

        monkeypatch.setattr(run_module, "step", step)
        config = load_config(None, ["slam.backend=odometry", "landing.detect_on=every_nth",
                                    "landing.every_nth_frame=1"])
        with ExitStack() as stack:
            source, config = open_source(recording, config, stack)
            slam = stack.enter_context(get_backend(config.slam, False))
            queue: deque = deque()

            def submit(frame):   # a worker's queue: frames wait until collected in order
                assert len(queue) < in_flight
                events.append(f"submit {frame.index}")
                queue.append(frame)

            def collect():
                events.append("collect")
                return slam.track(queue.popleft())

            monkeypatch.setattr(slam, "in_flight", in_flight)
            monkeypatch.setattr(slam, "submit", submit)
            monkeypatch.setattr(slam, "collect", collect)
            tracker = Tracker(config, slam)
            mr = method_run(config, "fuzzy", tracker)
            assert mr.state.noise is not None
            run(source, tracker, [mr], mr.state.noise, StageLimit(None, str(recording)))
        return events, poses

    events, poses = tracked_run(2)
    want = ["submit 0", "submit 1"]
    for i in range(FRAMES):
        want += ["collect"] + ([f"submit {i + 2}"] if i + 2 < FRAMES else []) + [f"detect {i}"]
    assert events == want
    _, one_at_a_time = tracked_run(1)
    assert [i for i, _ in poses] == [i for i, _ in one_at_a_time] == list(range(FRAMES))
    pairs = zip(poses, one_at_a_time, strict=True)
    assert all(a is not None and b is not None and np.array_equal(a, b) for (_, a), (_, b) in pairs)
