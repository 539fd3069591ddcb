"""Many recordings: one task per recording, on a local process pool (default) or a Dask cluster.

The per-recording work is ``pipeline.detect_recording``: frames streamed from the file, the
run folder built under a temporary name and renamed at the end, skipped when it was done
before for the same config hash and input. This module plans the run folders, hands the
tasks to an engine, counts progress and collects one row per recording:

- ``inline``: in this process (one worker, or one recording);
- ``local``: ``concurrent.futures.ProcessPoolExecutor`` with the spawn start method (fresh
  interpreters, as on a Dask worker; no fork of a process that holds threads);
- ``dask``: ``distributed.Client(address).submit`` per recording. The workers must see the
  same paths (a shared filesystem) and have slz installed; frame counts reach the progress
  bar as worker events.

Safety. Each task holds its run folder's lock (waiting while another batch writes that run, then
skipping it as done) and first removes the ``.RUN.*.partial`` folders a killed process left
(``outputs/run_lock.py``). A run folder is written only where ``outputs/output_dir.py`` allows
(missing, empty, or a ``slz detect`` run folder; never a recording or a folder holding one).
Ctrl-C or SIGTERM stop the batch: the local workers' running recordings are interrupted and
remove their temporary folders, queued ones are cancelled, the summary records what was done,
then ``KeyboardInterrupt`` goes on to the caller. Pool workers watch their parent: if it is killed outright
they stop too.
A task already running on a Dask worker cannot be interrupted; it finishes its (atomic) run.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import functools
import glob
import logging
import multiprocessing as mp
import os
import queue
import signal
import socket
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from slzcli.config import Config
from slzcli.errors import ConfigError, DatasetError, SlzError
from slzcli.interrupt import sigterm_interrupts
from slzcli.pipeline import RunOptions
from slzcli.records import BatchRow, BatchSettings, BatchTotals
from slzcli.sources.formats import run_suffixes

if TYPE_CHECKING:
    from multiprocessing.sharedctypes import SynchronizedArray

    from distributed import Client, Future

log = logging.getLogger(__name__)

# Process housekeeping, not tuning: how often the parent refreshes progress and workers check
# that their parent lives; how long interrupted workers get to remove their temporary folders.
POLL_S = 0.25
STOP_GRACE_S = 10.0
CONNECT_TIMEOUT_S = 10.0
GLOB_CHARS = frozenset("*?[")


# ----------------------------------------------------------------------------- planning
@dataclass(frozen=True)
class Task:
    """One recording and the run folder it goes to (both absolute: workers may have another cwd)."""

    recording: Path
    run_dir: Path


def is_pattern(arg: str | Path) -> bool:
    """A glob pattern: it has ``*?[`` and no file or folder has exactly that name (``flight[1].mcap`` is a name)."""
    return any(c in GLOB_CHARS for c in str(arg)) and not os.path.lexists(os.path.expanduser(str(arg)))


def expand(args: Sequence[str | Path]) -> list[Path]:
    """Paths and glob patterns -> recordings, in the order given (a pattern's matches sorted), no repeats.

    An argument naming an existing file or folder is that path, even with glob characters in it.
    """
    found: list[Path] = []
    for arg in args:
        if is_pattern(arg):
            matches = _glob(os.path.expanduser(str(arg)))
            if not matches:
                raise DatasetError(arg, "no recording matches this pattern")
            found.extend(Path(m) for m in matches)
        else:
            found.append(Path(arg))
    seen: set[Path] = set()
    unique = []
    for p in found:
        key = p.absolute()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def _glob(pattern: str) -> list[str]:
    """``glob.glob(pattern, recursive=True)``, sorted, except that ``**`` does not descend through links to
    folders: a link loop (``a/up -> ..``) made ``glob`` recurse until the path was too long, and several
    such links multiplied it past any wait. A link named by a non-``**`` part is still followed."""
    if "**" not in pattern:
        return sorted(glob.glob(pattern))
    parts = Path(pattern).parts
    fixed = next(i for i, part in enumerate(parts) if any(c in GLOB_CHARS for c in part))
    root = Path(*parts[:fixed]) if fixed else Path(".")
    rest = parts[fixed:]
    hidden_ok = any(part.startswith(".") for part in rest)
    found = []
    for p in root.glob(str(Path(*rest))):  # pathlib's ** does not follow links to folders
        if hidden_ok or not any(q.startswith(".") for q in p.relative_to(root).parts):
            found.append(str(p) if fixed else os.path.normpath(str(p)))
    return sorted(found)


def run_name(recording: Path) -> str:
    name = Path(recording).name or "run"
    for suffix in run_suffixes():
        name = name.removesuffix(suffix)
    return name


def plan(recordings: Sequence[Path], output: Path | None, *, batch: bool) -> list[Task]:
    """Run folders: ``output`` itself for one recording named alone, else ``output/<name>`` each.

    ``output`` defaults to ``runs``. Two recordings with the same name get their parent folder's
    name in front; recordings that still collide are a usage error. A run folder that would be, or
    hold, one of the recordings is refused (OutputError) before anything runs, as is a batch folder
    whose summary.json / summary.csv slz did not write.
    """
    from slzcli.outputs import batch_summary, output_dir

    if not batch:
        if len(recordings) != 1:
            raise ConfigError("recordings", "one recording expected outside a batch")
        rec = recordings[0]
        task = Task(rec.absolute(), (output or Path("runs") / run_name(rec)).absolute())
        output_dir.refuse_inputs(task.run_dir, [task.recording])
        return [task]
    base = (output or Path("runs")).absolute()
    names = [run_name(p) for p in recordings]
    clash = {n for n in names if names.count(n) > 1}
    names = [f"{p.absolute().parent.name}_{n}" if n in clash else n for p, n in zip(recordings, names, strict=True)]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError("recordings", f"several recordings would share the run folder {base / twice[0]}; "
                                        "run them into different -o folders")
    tasks = [Task(p.absolute(), base / n) for p, n in zip(recordings, names, strict=True)]
    for t in tasks:
        output_dir.refuse_inputs(t.run_dir, [r.recording for r in tasks])
    batch_summary.check_folder(base)
    return tasks


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# ----------------------------------------------------------------------------- one task
class FrameTick:
    """``detect_recording``'s progress(done, total) -> increments of frames done and of frames expected
    (the recording's total, once known) for a sink (picklable state only)."""

    def __init__(self, sink: Callable[[int, int], None]) -> None:
        self.sink = sink
        self.done = 0
        self.total = 0

    def __call__(self, done: int, total: int | None) -> None:
        more = max(0, (total or 0) - self.total)
        if done > self.done or more:
            self.sink(max(0, done - self.done), more)
            self.done, self.total = max(done, self.done), self.total + more


def error_detail(err: SlzError) -> dict[str, str]:
    """The failed row's error as ``--json`` names it: the error's class and the file or key it concerns."""
    detail = {"kind": type(err).__name__}
    path, key = getattr(err, "path", None), getattr(err, "key", None)
    if isinstance(path, str):
        detail["file"] = path
    if isinstance(key, str) and key:
        detail["key"] = key
    return detail


def run_task(task: Task, config: Config, options: RunOptions,
             progress: Callable[[int, int | None], None] | None = None) -> BatchRow:
    """One recording -> its row: ``detect_recording`` under the run folder's lock; errors become rows."""
    from slzcli.outputs import run_lock
    from slzcli.pipeline import detect_recording

    t0 = time.perf_counter()
    row = BatchRow(str(task.recording), str(task.run_dir), "failed", worker=_worker_id())
    try:
        with run_lock.claim(task.run_dir, wait=True):  # another batch on this run: wait, then find it done
            summary = detect_recording(task.recording, config, task.run_dir, options, progress)
    except SlzError as err:
        return replace(row, error=" ".join(str(err).split()), error_detail=error_detail(err),
                       wall_s=round(time.perf_counter() - t0, 3), peak_rss_mb=_peak_rss_mb())
    except Exception as err:  # a bug: reported in the row, the batch goes on
        log.debug("internal error on %s", task.recording, exc_info=True)
        return replace(row, error=f"internal error ({type(err).__name__}: {err})",
                       wall_s=round(time.perf_counter() - t0, 3), peak_rss_mb=_peak_rss_mb())
    wall = time.perf_counter() - t0
    skipped = summary.skipped
    return replace(row, status=summary.status, skipped=skipped, wall_s=round(wall, 3),
                   frames_per_s=None if skipped or wall <= 0 else round(summary.frames / wall, 3),
                   peak_rss_mb=_peak_rss_mb(), peak_child_rss_mb=_peak_rss_mb("children"), summary=summary)


def _worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _peak_rss_mb(who: str = "self") -> float | None:
    """Peak resident memory, MiB, of this process (the worker) or of its largest finished child
    (``children``: the ORB-SLAM3 worker); None where ``resource`` is missing."""
    try:
        import resource
    except ImportError:
        return None
    kib = resource.getrusage(resource.RUSAGE_SELF if who == "self" else resource.RUSAGE_CHILDREN).ru_maxrss
    return round(kib / 1024.0, 1)  # Linux reports KiB


# ----------------------------------------------------------------------------- the batch
@dataclass(frozen=True)
class BatchProgress:
    """What the progress display needs: recordings done, frames processed, and the row just finished."""

    done: int
    total: int
    frames: int
    elapsed_s: float
    row: BatchRow | None = None
    frames_expected: int = 0  # the frame totals of the recordings started so far

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass(frozen=True)
class BatchResult:
    rows: list[BatchRow]
    engine: str
    workers: int
    wall_s: float
    interrupted: bool = False
    summary_files: tuple[Path, ...] = field(default_factory=tuple)

    def totals(self) -> BatchTotals:
        """Batch-level numbers for summary.json and the CLI."""
        ran = [r for r in self.rows if r.finished and not r.skipped]
        frames = sum(r.frames or 0 for r in ran)

        def count(status: str) -> int:
            return sum(r.status == status for r in self.rows)

        return BatchTotals(
            engine=self.engine, workers=self.workers, recordings=len(self.rows), site=count("site"),
            no_safe_site=count("no_safe_site"), failed=count("failed"), interrupted=count("interrupted"),
            skipped=sum(r.skipped for r in self.rows), processed=len(ran), frames=frames,
            wall_s=round(self.wall_s, 3),
            frames_per_s=round(frames / self.wall_s, 3) if self.wall_s > 0 else None,
            recordings_per_min=round(60.0 * len(ran) / self.wall_s, 3) if self.wall_s > 0 else None,
            batch_interrupted=self.interrupted)


DEFAULT_OPTIONS = RunOptions()  # frozen: one instance serves every call


def run_batch(tasks: Sequence[Task], config: Config, *, workers: int = 1, scheduler: str | None = None,
              options: RunOptions = DEFAULT_OPTIONS, summary_dir: Path | None = None,
              on_progress: Callable[[BatchProgress], None] | None = None) -> BatchResult:
    """Run every task; rows come back in task order. With ``summary_dir``, writes summary.json/csv there.

    Interrupted (Ctrl-C, SIGTERM): stops the workers, writes the summary, re-raises KeyboardInterrupt.
    """
    if scheduler:
        engine: _Engine = _DaskEngine(scheduler)
    elif workers <= 1 or len(tasks) <= 1:
        engine = _InlineEngine()
    else:
        engine = _LocalEngine(min(workers, len(tasks)))
    t0 = time.perf_counter()
    rows: list[BatchRow | None] = [None] * len(tasks)
    emit = on_progress or (lambda p: None)
    interrupted = False
    with sigterm_interrupts():
        try:
            engine.start()
            emit(BatchProgress(0, len(tasks), 0, 0.0))
            _collect(engine, tasks, config, options, rows, t0, emit)
        except KeyboardInterrupt:
            interrupted = True
            log.warning("interrupted: stopping the workers")
            engine.stop()  # again, harmless: the interrupt may have come before _collect's own stop
        finally:
            engine.close()
    filled = [r if r is not None else BatchRow(str(t.recording), str(t.run_dir), "interrupted",
                                               error="the batch was stopped")
              for r, t in zip(rows, tasks, strict=True)]
    result = BatchResult(filled, engine.name, engine.workers, time.perf_counter() - t0, interrupted)
    if summary_dir is not None:
        from slzcli.outputs.batch_summary import write_summary

        settings = BatchSettings(scheduler, config.hash(), options.force, options.timeout_s)
        written = write_summary(summary_dir, result.totals(), settings, filled)
        result = replace(result, summary_files=written)
    if interrupted:
        raise KeyboardInterrupt
    return result


def _collect(engine: _Engine, tasks: Sequence[Task], config: Config, options: RunOptions,
             rows: list[BatchRow | None], t0: float, emit: Callable[[BatchProgress], None]) -> None:
    """Submit everything, then record rows as tasks finish (in this thread) and refresh the frame count."""
    def progress(row: BatchRow | None = None) -> BatchProgress:
        return BatchProgress(sum(r is not None for r in rows), len(tasks), engine.frames(),
                             time.perf_counter() - t0, row, engine.expected())

    def finish(i: int, outcome: Outcome) -> None:
        rows[i] = _row_of(tasks[i], outcome)
        emit(progress(rows[i]))

    done_q: queue.Queue[tuple[int, Outcome]] = queue.Queue()
    if engine.threaded:  # done callbacks run in the engine's threads: hand them over to this one
        engine.submit_all(tasks, config, options, lambda i, outcome: done_q.put((i, outcome)), lambda: None)
    else:
        engine.submit_all(tasks, config, options, finish, lambda: emit(progress()))
    shown = -1
    try:
        while any(r is None for r in rows):
            try:
                finish(*done_q.get(timeout=POLL_S))
            except queue.Empty:
                if engine.frames() != shown:
                    shown = engine.frames()
                    emit(progress())
    except KeyboardInterrupt:
        engine.stop()
        while not done_q.empty():  # recordings that finished meanwhile are done: keep their rows
            i, outcome = done_q.get_nowait()
            row = _row_of(tasks[i], outcome)
            if row.finished:
                rows[i] = row
        raise


def _row_of(task: Task, outcome: Outcome) -> BatchRow:
    """A finished future (or an inline row) -> the row; a failure of the engine itself becomes a failed row."""
    if isinstance(outcome, BatchRow):
        return outcome
    recording, run = str(task.recording), str(task.run_dir)
    try:
        row = outcome.result()
    except KeyboardInterrupt:
        return BatchRow(recording, run, "interrupted", error="the worker was interrupted")
    except cf.CancelledError:
        return BatchRow(recording, run, "interrupted", error="cancelled")
    except Exception as err:  # e.g. a worker process died (BrokenProcessPool), a lost Dask worker
        return BatchRow(recording, run, "failed", error=f"{type(err).__name__}: {err}")
    if not isinstance(row, BatchRow):
        raise TypeError(f"a batch worker returned {type(row).__name__}, not a BatchRow")
    return row


# ----------------------------------------------------------------------------- engines
class Pending(Protocol):
    """A task's future (concurrent.futures or Dask): its row, or the error that ended it."""

    def result(self) -> object: ...


Outcome = BatchRow | Pending  # an inline engine hands the row itself
Done = Callable[[int, Outcome], None]


class _Engine:
    name = "?"
    workers = 1
    threaded = True  # tasks finish in other threads or processes (else: inside submit_all)

    def start(self) -> None:
        return None

    def submit_all(self, tasks: Sequence[Task], config: Config, options: RunOptions, done: Done,
                   tick: Callable[[], None]) -> None:
        raise NotImplementedError

    def frames(self) -> int:
        return 0

    def expected(self) -> int:
        return 0

    def stop(self) -> None:
        return None

    def close(self) -> None:
        return None


class _InlineEngine(_Engine):
    """In this process, one recording after the other: progress on every frame."""

    name = "inline"
    threaded = False

    def __init__(self) -> None:
        self._frames = 0
        self._expected = 0

    def submit_all(self, tasks: Sequence[Task], config: Config, options: RunOptions, done: Done,
                   tick: Callable[[], None]) -> None:
        def count(n: int, more: int) -> None:
            self._frames += n
            self._expected += more
            tick()

        for i, task in enumerate(tasks):
            done(i, run_task(task, config, options, FrameTick(count)))

    def frames(self) -> int:
        return self._frames

    def expected(self) -> int:
        return self._expected


_FRAMES: SynchronizedArray[int] | None = None  # in a pool worker: frames done and expected (set by _init_worker)
_RUNNING = False     # in a pool worker: a task is running
_STOPPING = False    # in a pool worker: told to stop once; later signals must not break the clean-up


def _init_worker(counter: SynchronizedArray[int], parent_pid: int) -> None:
    """Pool worker start: the frame counter, what Ctrl-C and SIGTERM do, and the parent watch."""
    global _FRAMES
    _FRAMES = counter
    # SIGTERM too: when one worker leaves, the executor calls the pool broken and terminates the rest.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_stop_signal)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="slz-parent-watch", daemon=True).start()


def _on_stop_signal(signum: int, frame: object) -> None:
    """Stop: a running task is interrupted (it removes its temporary folder, then the worker
    leaves); an idle worker leaves at once, so that it takes no further task. Once only."""
    global _STOPPING
    if _STOPPING:
        return
    _STOPPING = True
    if _RUNNING:
        raise KeyboardInterrupt
    os._exit(128 + signum)


def _watch_parent(parent_pid: int) -> None:
    """If the parent dies (SIGKILL, crash), interrupt the running task (it cleans up), then leave."""
    while os.getppid() == parent_pid:
        time.sleep(POLL_S)
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(STOP_GRACE_S)
    os._exit(1)


def _count_frames(n: int, more: int) -> None:
    if _FRAMES is None:  # not in a pool worker: nobody counts
        return
    with _FRAMES.get_lock():
        _FRAMES[0] += n
        _FRAMES[1] += more


def _pool_task(task: Task, config: Config, options: RunOptions) -> BatchRow:
    global _RUNNING
    _RUNNING = True
    try:
        return run_task(task, config, options, FrameTick(_count_frames))
    except KeyboardInterrupt:
        os._exit(128 + signal.SIGINT)  # cleaned up on the way here; leaving takes no further task
    finally:
        _RUNNING = False


class _LocalEngine(_Engine):
    """A process pool on this machine; the parent polls a shared frame counter."""

    name = "local"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        ctx = mp.get_context("spawn")
        self._counter = ctx.Array(ctypes.c_longlong, 2)  # frames done, frames expected ("q")
        self._pool = cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                                            initargs=(self._counter, os.getpid()))

    def submit_all(self, tasks: Sequence[Task], config: Config, options: RunOptions, done: Done,
                   tick: Callable[[], None]) -> None:
        for i, task in enumerate(tasks):
            fut = self._pool.submit(_pool_task, task, config, options)
            fut.add_done_callback(functools.partial(done, i))

    def frames(self) -> int:
        return int(self._counter[0])

    def expected(self) -> int:
        return int(self._counter[1])

    def stop(self) -> None:
        """Interrupt running tasks (SIGINT: they remove their temporary folders), cancel the rest."""
        # No public way before Python 3.14 (terminate_workers) to reach the worker processes.
        procs = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.pid, signal.SIGINT)
        deadline = time.monotonic() + STOP_GRACE_S
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


def _dask_task(task: Task, config: Config, options: RunOptions, topic: str) -> BatchRow:
    from distributed import get_worker

    worker = get_worker()
    return run_task(task, config, options, FrameTick(lambda n, more: worker.log_event(topic, (n, more))))


class _DaskEngine(_Engine):
    """Tasks on an existing Dask distributed cluster; frame counts come back as worker events."""

    name = "dask"

    def __init__(self, address: str) -> None:
        self.address = address
        self.client: Client | None = None
        self.futures: list[Future[BatchRow]] = []
        self.topic = f"slz-frames-{uuid.uuid4().hex[:12]}"
        self._frames = 0
        self._expected = 0
        self._lock = threading.Lock()

    def start(self) -> None:
        try:
            from distributed import Client
        except ImportError as err:
            raise ConfigError("--scheduler", "needs dask.distributed: pip install 'slz[dask]'") from err
        try:
            self.client = Client(self.address, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as err:
            raise ConfigError("--scheduler", f"cannot connect to the Dask scheduler at {self.address} ({err})") from err
        info = self.client.scheduler_info()
        self.workers = sum(int(w.get("nthreads", 1)) for w in info.get("workers", {}).values())
        self.client.subscribe_topic(self.topic, self._on_frames)

    def _on_frames(self, event: tuple[object, tuple[int, int]]) -> None:
        _, (n, more) = event
        with self._lock:
            self._frames += int(n)
            self._expected += int(more)

    def submit_all(self, tasks: Sequence[Task], config: Config, options: RunOptions, done: Done,
                   tick: Callable[[], None]) -> None:
        if self.client is None:
            raise RuntimeError("the Dask engine was not started")
        token = uuid.uuid4().hex[:8]
        for i, task in enumerate(tasks):
            fut = self.client.submit(_dask_task, task, config, options, self.topic, pure=False,
                                     key=f"slz-detect-{task.run_dir.name}-{token}-{i}")
            fut.add_done_callback(lambda f, i=i: done(i, f))
            self.futures.append(fut)

    def frames(self) -> int:
        with self._lock:
            return self._frames

    def expected(self) -> int:
        with self._lock:
            return self._expected

    def stop(self) -> None:
        if self.client is not None and self.futures:
            self.client.cancel(self.futures)

    def close(self) -> None:
        if self.client is not None:
            try:
                self.client.unsubscribe_topic(self.topic)
            finally:
                self.client.close()
