"""A bounded background writer: a run's files are written in one thread, in order, off the compute path.

Writing a detection frame (maps.npz, overlay.png, its results.mcap messages) costs about as much
as computing it; done in the main loop it adds to every detection. Here the main loop hands each
write over as a task and goes on with the next frames while one thread writes, in the order the
tasks came (results.mcap stays in time order: poses and detections go through the same queue).
PNG, JPEG and LZ4 encoding, numpy casts and file writes release the GIL, so on two cores the writes
overlap the next frame's SLAM and maps.

The queue holds at most ``depth`` tasks (``output.write_queue``; 0 writes in the loop): a detection task keeps its
frame's arrays alive (~20 MB at 640x480), so memory stays bounded however far the writer falls
behind; when the queue is full the main loop waits, and that wait is what the run loses to
writing (``write_wait`` in run.json; ``write`` is the writer's own time per detection frame).

Errors: the first exception of a task (a full disk, a permission error) is kept, the tasks after
it are dropped, and it is raised in the main thread at the next ``submit`` or at ``close``.
``abort`` (after an error or an interruption in the main loop) drops what is queued and waits
for the task being written to end, so that the temporary run folder is not removed under it;
past ``grace_s`` it stops waiting (a writer stuck on a hung filesystem cannot hold the run).
"""

from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Callable
from types import TracebackType

# Housekeeping, not tuning: how long abort() waits for the task being written before it gives up.
ABORT_GRACE_S = 10.0
Task = tuple[str, Callable[..., object], tuple[object, ...]]  # (label, fn, args): fn(*args) in the thread


class BackgroundWriter:
    """One writer thread fed through a bounded queue; ``submit(label, fn, *args)`` runs ``fn(*args)`` there."""

    def __init__(self, depth: int, name: str = "slz-writer", grace_s: float = ABORT_GRACE_S) -> None:
        """``depth`` 0: no thread, every task is written in ``submit`` (the reference for benchmarks/writes.py)."""
        if depth < 0:
            raise ValueError("depth must be >= 0")
        self._queue: queue.Queue[Task | None] = queue.Queue(maxsize=max(depth, 1))  # None: stop
        self._error: BaseException | None = None
        self._cancel = threading.Event()
        self._busy: str | None = None
        self._grace_s = grace_s
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._inline = depth == 0
        if not self._inline:
            self._thread.start()

    # ------------------------------------------------------------------ main thread
    def submit(self, label: str, fn: Callable[..., object], *args: object) -> None:
        """Queue ``fn(*args)``; waits while the queue is full; raises the writer's first error, if any."""
        if self._inline:
            fn(*args)
            return
        self._raise()
        self._queue.put((label, fn, args))
        self._raise()

    def busy_with(self) -> str | None:
        """The label of the task being written now (None: idle), to name a stuck write."""
        return self._busy

    def close(self) -> None:
        """Write everything queued, stop the thread, raise the writer's first error, if any."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self._raise()

    def abort(self) -> None:
        """Drop what is queued and wait (at most ``grace_s``) for the task being written."""
        self._cancel.set()
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        if self._thread.is_alive():
            with contextlib.suppress(queue.Full):  # emptied just above; the thread only takes from it
                self._queue.put_nowait(None)
            self._thread.join(self._grace_s)

    def __enter__(self) -> BackgroundWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _raise(self) -> None:
        err = self._error
        if err is not None:
            self._error = None
            self._cancel.set()
            raise err

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        while True:
            task = self._queue.get()
            if task is None:
                return
            if self._cancel.is_set() or self._error is not None:
                continue  # after an error or an abort: drain without writing
            label, fn, args = task
            self._busy = label
            try:
                fn(*args)
            except BaseException as err:  # handed to the main thread as it is
                self._error = err
            finally:
                self._busy = None
