"""``--timeout``: a stuck or slow stage ends its recording with a named stage and no output (issue 10).

No test here depends on how fast the machine is. The unit tests of ``StageLimit`` bound stages
that do nothing or that block for good. The CLI tests bound only the stage they make stuck
(``bound_only``): every real stage of the run (reading, SLAM, maps, writing) runs unbounded, so
a slow machine cannot trip the bound. On a 2-core EPYC, writing one detection frame took 0.6-1.3 s,
over the 0.5 s bound these tests used to put on every stage.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from conftest import GAUSSIAN

from slzcli.cli import main
from slzcli.errors import StageTimeout
from slzcli.pipeline import run as run_module
from slzcli.pipeline import source as source_module
from slzcli.pipeline import step as step_module
from slzcli.timeout import StageLimit

STUCK_S = 20.0  # how long a "stuck" stage blocks if the bound failed: the test then fails, it does not hang


def stuck() -> None:
    """A stage that waits on a lock nobody releases (a hung read, a deadlocked call)."""
    threading.Event().wait(STUCK_S)


# ----------------------------------------------------------------------------- StageLimit
def test_a_blocking_wait_in_the_main_thread_is_interrupted() -> None:
    limit = StageLimit(0.2, "flight.mcap")
    with pytest.raises(StageTimeout) as err, limit.stage("reading frame 7"):
        stuck()
    assert str(err.value).startswith("flight.mcap: reading frame 7 took longer than --timeout 0.2 s")


def test_a_python_loop_in_a_worker_thread_is_interrupted() -> None:
    """Dask runs tasks in threads: there the bound arrives as an asynchronous exception."""
    caught: list[BaseException] = []

    def task() -> None:
        limit = StageLimit(0.2, "flight.mcap")
        try:
            with limit.stage("SLAM on frame 3"):
                end = time.monotonic() + STUCK_S
                while time.monotonic() < end:
                    sum(range(1000))
        except StageTimeout as e:
            caught.append(e)

    t = threading.Thread(target=task)
    t.start()
    t.join(STUCK_S + 5)
    assert len(caught) == 1
    assert "SLAM on frame 3 took longer than --timeout 0.2 s" in str(caught[0])


@pytest.mark.parametrize("in_thread", [False, True])
def test_a_stage_that_finishes_in_time_leaves_no_alarm_behind(in_thread: bool) -> None:
    errors: list[BaseException] = []

    def body() -> None:
        limit = StageLimit(0.3, "flight.mcap")
        try:
            for i in range(3):
                with limit.stage(f"stage {i}"):
                    pass  # an empty stage: no machine is slow enough to spend 0.3 s here
            time.sleep(0.6)  # past the bound, outside any stage
        except BaseException as e:
            errors.append(e)

    if in_thread:
        t = threading.Thread(target=body)
        t.start()
        t.join()
    else:
        body()
    assert errors == []


def test_no_limit_costs_nothing_and_bounds_nothing() -> None:
    limit = StageLimit(None, "flight.mcap")
    with limit.stage("anything"):
        time.sleep(0.05)


def test_stages_do_not_nest() -> None:
    limit = StageLimit(0.2, "flight.mcap")
    with pytest.raises(StageTimeout, match="outer"), limit.stage("outer"), limit.stage("inner"):
        stuck()


# ----------------------------------------------------------------------------- slz detect --timeout
@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> dict[str, Path]:
    from click.testing import CliRunner

    folder = tmp_path_factory.mktemp("timeout")
    calm = folder / "calm.mcap"
    res = CliRunner().invoke(main, ["synth", "parking_lot", "-o", str(calm), "--frames", "4", *GAUSSIAN])
    assert res.exit_code == 0, res.output
    # the same flight under a second name (with its ground-truth sidecars): rendered once
    for f in list(folder.iterdir()):
        shutil.copy(f, folder / f.name.replace("calm.mcap", "stuck.mcap"))
    return {"calm": calm, "stuck": folder / "stuck.mcap"}


def bound_only(monkeypatch, stage_name: str, recording: str = "") -> None:
    """Let ``--timeout`` bound only the stage ``stage_name`` (of ``recording``, when given); the others run free.

    The stage that a test makes stuck is the one under test; a real stage (writing a frame, SLAM)
    must never reach the test's short bound, however slow the machine.
    """
    real = StageLimit.stage

    @contextmanager
    def stage(self: StageLimit, what: str) -> Iterator[None]:
        if what == stage_name and recording in self.where:
            with real(self, what):
                yield
        else:
            yield

    monkeypatch.setattr(StageLimit, "stage", stage)


def _stuck_detection(monkeypatch, only: str = "") -> None:
    real = run_module.step

    def detect(tracked, *args):
        if not only or only in tracked.frame.source:
            stuck()
        return real(tracked, *args)

    monkeypatch.setattr(run_module, "step", detect)


def test_detect_stops_a_stuck_stage_names_it_and_leaves_nothing(runner, flights, tmp_path, monkeypatch) -> None:
    _stuck_detection(monkeypatch)
    bound_only(monkeypatch, "detection on frame 0")
    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(flights["calm"]), "-o", str(out), "--timeout", "0.5"])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr
    assert "calm.mcap" in lines[0] and "detection on frame 0 took longer than --timeout 0.5 s" in lines[0]
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_a_stuck_read_is_bounded_too(runner, flights, tmp_path, monkeypatch) -> None:
    """A recording whose third frame never arrives (a hung network filesystem)."""
    real = source_module.open_recording

    class Hanging:
        def __init__(self, rec) -> None:
            self.rec = rec

        def __getattr__(self, name: str):
            return getattr(self.rec, name)

        def frames(self):
            for frame in self.rec.frames():
                if frame.index == 2:
                    stuck()
                yield frame

    class Opener:
        def __init__(self, path, config) -> None:
            self.cm = real(path, config)

        def __enter__(self):
            return Hanging(self.cm.__enter__())

        def __exit__(self, *exc):
            return self.cm.__exit__(*exc)

    monkeypatch.setattr(source_module, "open_recording", Opener)
    bound_only(monkeypatch, "reading frame 2")
    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(flights["calm"]), "-o", str(out), "--timeout", "0.5"])
    assert res.exit_code == 1
    assert "reading frame 2 took longer than --timeout 0.5 s" in res.stderr
    assert not out.exists()


def test_a_batch_goes_on_past_a_recording_that_timed_out(runner, flights, tmp_path, monkeypatch) -> None:
    _stuck_detection(monkeypatch, only="stuck.mcap")
    bound_only(monkeypatch, "detection on frame 0", recording="stuck.mcap")
    out = tmp_path / "runs"
    res = runner.invoke(main, ["detect", str(flights["calm"]), str(flights["stuck"]), "-o", str(out),
                               "--workers", "1", "--timeout", "1", "--json"])
    assert res.exit_code == 1, res.output
    summary = json.loads((out / "summary.json").read_text())
    rows = {Path(r["recording"]).name: r for r in summary["recordings"]}
    assert rows["calm.mcap"]["status"] == "site"
    assert rows["stuck.mcap"]["status"] == "failed"
    assert "took longer than --timeout 1 s" in rows["stuck.mcap"]["error"]
    assert (out / "calm" / "landing.json").is_file() and not (out / "stuck").exists()
    assert summary["batch"]["timeout_s"] == 1.0


def test_a_generous_timeout_changes_nothing(runner, flights, tmp_path) -> None:
    a = runner.invoke(main, ["detect", str(flights["calm"]), "-o", str(tmp_path / "a"), "--json"])
    b = runner.invoke(main, ["detect", str(flights["calm"]), "-o", str(tmp_path / "b"), "--json", "--timeout", "600"])
    assert a.exit_code == b.exit_code == 0, a.output + b.output
    la = json.loads((tmp_path / "a" / "landing.json").read_text())
    lb = json.loads((tmp_path / "b" / "landing.json").read_text())
    assert la["site"]["center_world"] == lb["site"]["center_world"]


def test_timeout_must_be_positive(runner, flights, tmp_path) -> None:
    res = runner.invoke(main, ["detect", str(flights["calm"]), "-o", str(tmp_path / "r"), "--timeout", "0"])
    assert res.exit_code == 2 and "--timeout" in res.output + res.stderr


def test_compare_takes_the_same_bound(runner, flights, tmp_path, monkeypatch) -> None:
    real = step_module.posed_maps

    def slow_maps(*args, **kwargs):
        stuck()
        return real(*args, **kwargs)

    monkeypatch.setattr(step_module, "posed_maps", slow_maps)
    bound_only(monkeypatch, "detection on frame 0")
    out = tmp_path / "cmp"
    res = runner.invoke(main, ["compare", str(flights["calm"]), "-o", str(out), "--timeout", "0.5"])
    assert res.exit_code == 1
    assert "calm.mcap: detection on frame 0 took longer than --timeout 0.5 s" in res.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []
