"""Progress on stderr: plain lines off a terminal (at once, then at most every every_s, always the last)."""

from __future__ import annotations

import pytest

from slzcli import progress
from slzcli.progress import Bar, duration, progress_line


def test_duration_reads_as_a_person_says_it() -> None:
    assert [duration(s) for s in (0.4, 8, 59.6, 125, 3600 + 3 * 60 + 9)] == ["0 s", "8 s", "1 min 00 s",
                                                                           "2 min 05 s", "1 h 03 min"]


def test_progress_line_has_count_rate_and_time_left() -> None:
    line = progress_line("synth parking_lot", 10, 40, "frames", 5.0)
    assert line == "slz: synth parking_lot: 10 of 40 frames (25 %) in 5.0 s, 2.0 frames/s, about 15 s left"
    assert progress_line("detect", 3, None, "frames", 1.5) == "slz: detect: 3 frames in 1.5 s, 2.0 frames/s"
    assert "in 40.0 s, 0.03 frames/s, about" in progress_line("synth s", 1, 20, "frames", 40.0)  # slow, not 0.0
    done = progress_line("monte carlo", 5, 5, "runs", 2.0, note="4 landed")
    assert done == "slz: monte carlo: 5 of 5 runs (100 %) in 2.0 s, 2.5 runs/s; 4 landed"  # no time left at the end


def test_time_left_uses_the_rate_after_start_up(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
                                                ) -> None:
    clock = iter([0.0, 0.0, 10.0, 11.0, 12.0])  # made, entered; first frame after a 10 s start-up; then 1 frame/s
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    with Bar("detect", "frames", every_s=0.0, lines=True) as bar:
        bar.update(1, 10)
        bar.update(2, 10)
        bar.update(3, 10)
    lines = capsys.readouterr().err.splitlines()
    assert "about" not in lines[0]  # one point gives no rate
    assert lines[1].endswith("about 8 s left") and lines[2].endswith("about 7 s left"), lines


def test_lines_are_rate_limited_and_the_last_is_always_shown(monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    t = [0.0]
    monkeypatch.setattr(progress.time, "perf_counter", lambda: t[0])
    with Bar("synth s", "frames", every_s=5.0, lines=True) as bar:
        for i in range(1, 13):
            t[0] = float(i)
            bar.update(i, None)
    counts = [int(ln.split()[3]) for ln in capsys.readouterr().err.splitlines()]
    assert counts == [1, 6, 11, 12]  # the first at once, then every 5 s, then the last one held back


def test_a_finished_total_is_shown_at_once_and_not_twice(capsys: pytest.CaptureFixture[str]) -> None:
    with Bar("compare", "frames", every_s=1e9, lines=True) as bar:
        bar.update(1, 2)
        bar.update(2, 2)
    lines = capsys.readouterr().err.splitlines()
    assert [ln.split()[2] for ln in lines] == ["1", "2"]


def test_on_a_terminal_the_bar_prints_no_lines(monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    with Bar("detect", "frames", lines=False) as bar:
        assert bar.rich is not None
        bar.update(1, 4)
        bar.update(4, 4)
    assert "slz: detect:" not in capsys.readouterr().err


def test_an_estimated_total_that_is_passed_is_dropped_not_shown_over_100_percent(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A run's total is estimated from the recording's index by log time; more frames may pair."""
    with Bar("detect", "frames", every_s=0.0, lines=True) as bar:
        bar.update(2, 2)
        bar.update(3, 2)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("slz: detect: 2 of 2 frames (100 %)") and lines[1].startswith("slz: detect: 3 frames in")
