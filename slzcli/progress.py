"""Progress of long commands on stderr, one look for all of them (detect, compare, synth, land simulate).

On a terminal: a rich bar with the count, the rate and the time left. Anywhere else (a log, a pipe,
CI): a plain line at once, then at most every ``every_s`` seconds (``output.progress_every_s``),
and always the last one, so that a long step is never silent:

    slz: synth parking_lot: 12 of 40 frames (30 %) in 9.8 s, 1.2 frames/s, about 23 s left

The library reports ``progress(done, total)`` calls and knows nothing of this module.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from rich.progress import Progress, TaskID

    from slzcli.batch import BatchProgress

DEFAULT_EVERY_S = 5.0  # output.progress_every_s's default, for callers without a config


def on_terminal(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (stderr) is a terminal a bar can redraw on."""
    s = stream or sys.stderr
    return bool(getattr(s, "isatty", lambda: False)())


def duration(seconds: float) -> str:
    """A time span as a person reads it: ``8 s``, ``2 min 05 s``, ``1 h 03 min``."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def _rate(per_s: float) -> str:
    """A rate with one decimal, two below 1 (a slow render reads 0.25 frames/s, not 0.0)."""
    return f"{per_s:.1f}" if per_s >= 1 else f"{per_s:.2f}"


def progress_line(label: str, done: int, total: int | None, unit: str, elapsed_s: float, note: str = "",
                  rate: float | None = None) -> str:
    """The plain progress line; the count is the third word (scripts and tests read it).

    ``rate``: units per second for the time left (None: from ``done`` and ``elapsed_s``)."""
    mean = done / elapsed_s if elapsed_s > 0 else 0.0
    rate = mean if rate is None else rate
    if total:
        count = f"{done} of {total} {unit} ({100 * done / total:.0f} %)"
    else:
        count = f"{done} {unit}"
    text = f"slz: {label}: {count} in {elapsed_s:.1f} s, {_rate(mean)} {unit}/s"
    if total and 0 < done < total and rate > 0:
        text += f", about {duration((total - done) / rate)} left"
    return text + (f"; {note}" if note else "")


class Bar:
    """One step's progress: ``with Bar("synth", "frames") as bar: bar.update(done, total)``.

    ``lines`` forces the plain lines (None: a bar when stderr is a terminal).
    """

    def __init__(self, label: str, unit: str, every_s: float = DEFAULT_EVERY_S, lines: bool | None = None) -> None:
        self.label, self.unit, self.every_s = label, unit, every_s
        self.plain = (not on_terminal()) if lines is None else lines
        self.t0 = time.perf_counter()
        self.shown_s: float | None = None
        self.pending: tuple[int, int | None, str] | None = None  # the last update not printed yet
        self.last_done = -1
        self.rich: Progress | None = None  # the bar on a terminal (rich), and its task
        self.task: TaskID | None = None
        self.first: tuple[float, int] | None = None  # (elapsed, done) of the first update: start-up is not rate

    def __enter__(self) -> Bar:
        self.t0 = time.perf_counter()
        if not self.plain:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.rich = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn(self.unit), TextColumn("{task.fields[rate]}"),
                                 TimeElapsedColumn(), TextColumn("elapsed,"), TimeRemainingColumn(),
                                 TextColumn("left {task.fields[note]}"),
                                 console=Console(stderr=True), transient=True)
            self.rich.start()
            self.task = self.rich.add_task(self.label, total=None, rate="", note="")
        return self

    def update(self, done: int, total: int | None = None, note: str = "") -> None:
        """``done`` of ``total`` units (None: not known yet); ``note``: a short addition to the line. A total
        that was an estimate and is passed (a run's frames counted from the index by log time) is dropped."""
        total = None if total is not None and done > total else total
        elapsed = time.perf_counter() - self.t0
        if self.rich is not None and self.task is not None:
            rate = f"{_rate(done / elapsed)} {self.unit}/s" if elapsed > 0 and done else ""
            self.rich.update(self.task, completed=done, total=total, rate=rate, note=note)
            return
        if done == self.last_done and self.pending is None:
            return
        self.last_done = done
        if self.first is None:
            self.first = (elapsed, done)
        if self.shown_s is None or elapsed - self.shown_s >= self.every_s or (total is not None and done >= total):
            self.shown_s, self.pending = elapsed, None
            print(self._line(done, total, elapsed, note), file=sys.stderr, flush=True)
        else:
            self.pending = (done, total, note)

    def _line(self, done: int, total: int | None, elapsed: float, note: str) -> str:
        t1, d1 = self.first or (0.0, 0)
        rate = (done - d1) / (elapsed - t1) if done > d1 and elapsed > t1 else 0.0
        return progress_line(self.label, done, total, self.unit, elapsed, note, rate)

    def tick(self, done: int, total: int | None) -> None:
        """``update`` in the shape the library's ``progress(done, total)`` callbacks have."""
        self.update(done, total)

    def say(self, text: str) -> None:
        """A line of its own (a finished recording of a batch), above the bar on a terminal."""
        if self.rich is not None:
            self.rich.console.print(text, markup=False, highlight=False)
        else:
            print(text, file=sys.stderr, flush=True)

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self.rich is not None:
            self.rich.stop()
        elif self.pending is not None and exc_type is None:  # the last count is always shown
            done, total, note = self.pending
            print(self._line(done, total, time.perf_counter() - self.t0, note), file=sys.stderr, flush=True)


class BatchDisplay:
    """``slz detect``'s progress: one recording as a frame bar (frames of the recording's total), a
    batch as a recording bar with the frames and frames/s beside it, plus a line per finished recording."""

    def __init__(self, lines: bool, every_s: float = DEFAULT_EVERY_S) -> None:
        self.lines = lines
        self.bar = Bar("detect", "frames", every_s)

    def __enter__(self) -> Callable[[BatchProgress], None]:
        self.bar.__enter__()
        return self.show

    def show(self, p: BatchProgress) -> None:
        """One batch progress report: the bar, and a line per finished recording."""
        expected = p.frames_expected or None
        if p.total <= 1:
            if p.row is None and p.frames:
                self.bar.update(p.frames, expected)
        elif p.row is None and p.frames:
            self.bar.update(p.frames, expected if p.done == p.total else None,
                            note=f"{p.done} of {p.total} recordings done")
        if self.lines and p.row is not None:
            r = p.row
            what = r.status + (" (skipped: done before)" if r.skipped else "")
            if r.status == "failed":
                what += f": {r.error}"
            elif not r.skipped and r.frames is not None:
                what += f", {r.frames} frames in {r.wall_s or 0.0:.1f} s"
            self.bar.say(f"slz: [{p.done}/{p.total}] {Path(r.run).name}: {what}; "
                         f"{p.frames_per_s:.1f} frames/s overall")

    def __exit__(self, *exc: object) -> None:
        self.bar.__exit__(*exc)


class RunsDisplay:
    """Monte Carlo progress: ``tick(done, total, successes)`` after each chunk of runs."""

    def __init__(self, runs: int, chunk: int, every_s: float = DEFAULT_EVERY_S) -> None:
        self.quiet = runs <= chunk  # one chunk: nothing to show between start and end
        self.bar = Bar("monte carlo", "runs", every_s)

    def __enter__(self) -> Callable[[int, int, int], None]:
        if not self.quiet:
            self.bar.__enter__()
        return self.tick

    def tick(self, done: int, total: int, successes: int) -> None:
        if not self.quiet:
            self.bar.update(done, total, note=f"{successes} landed")

    def __exit__(self, *exc: object) -> None:
        if not self.quiet:
            self.bar.__exit__(*exc)
