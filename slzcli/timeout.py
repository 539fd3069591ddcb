"""``--timeout``: bound each stage of a run in wall time, so a stuck or slow stage ends the run.

A stage is one step of the per-frame loop (reading the next frame, SLAM, detection, writing)
or of the run around it (opening the recording, the final write). When one overruns,
``StageTimeout`` is raised inside it and unwinds through the run folder's ``output_dir.build``, so
the recording fails with nothing partial left, and a batch goes on with the next one:

- in the main thread (``slz detect`` on one recording, a local pool worker) by SIGALRM from
  ``setitimer``: a blocking read or wait is interrupted too (the handler raises, so PEP 475
  does not retry the call);
- in any other thread (a Dask worker runs tasks in threads), or where there is no SIGALRM
  (Windows), by an asynchronous exception that a timer thread sets
  (``PyThreadState_SetAsyncExc``). It lands at the next Python bytecode: a stage stuck inside
  one native call is stopped when that call returns. The ORB-SLAM3 worker is a separate
  process bounded by ``slam.orbslam3.frame_timeout_s`` as well.

Stages do not nest: a stage opened inside another is covered by the outer one's bound.
"""

from __future__ import annotations

import ctypes
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from slzcli.errors import StageTimeout


class _Overrun(StageTimeout):
    """What the timer thread raises in a worker thread (an exception class, created without arguments)."""


class StageLimit:
    """``with limit.stage("SLAM on frame 12"):`` raises ``StageTimeout`` after ``limit_s`` seconds.

    ``limit_s`` None or 0: no bound, and the stages cost nothing.
    """

    def __init__(self, limit_s: float | None, where: str) -> None:
        self.limit_s = limit_s or None
        self.where = where
        self._active = False

    @contextmanager
    def stage(self, what: str) -> Iterator[None]:
        limit_s = self.limit_s
        if limit_s is None or self._active:
            yield
            return
        self._active = True
        try:
            if threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer"):
                with self._alarm(what, limit_s):
                    yield
            else:
                with self._async_exc(what, limit_s):
                    yield
        finally:
            self._active = False

    def _error(self, what: str) -> StageTimeout:
        return StageTimeout(self.where, what, self.limit_s)

    @contextmanager
    def _alarm(self, what: str, limit_s: float) -> Iterator[None]:
        def on_alarm(signum: int, frame: object) -> None:
            raise self._error(what)

        previous = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, limit_s)
        try:
            yield
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)

    @contextmanager
    def _async_exc(self, what: str, limit_s: float) -> Iterator[None]:
        target = threading.get_ident()
        lock = threading.Lock()
        state = {"open": True}

        def fire() -> None:
            with lock:
                if state["open"]:
                    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(target), ctypes.py_object(_Overrun))

        timer = threading.Timer(limit_s, fire)
        timer.daemon = True
        timer.start()
        try:
            yield
        except _Overrun:
            raise self._error(what) from None
        finally:
            with lock:
                state["open"] = False
            timer.cancel()
