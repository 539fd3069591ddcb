"""Long native computations that still let Ctrl-C, SIGTERM and ``--timeout`` through.

Python runs a signal handler only between bytecodes of the main thread. One OpenCV or numpy
call on a large frame can last many seconds (measured on a 4096 x 4096 frame: the mask's
Gaussian blur is one 20 s ``cv2.GaussianBlur``), and the handler waits for it: SIGTERM took
12 s to act, and on the 108 MP frame that the pixel bound now refuses, minutes.

``call_interruptibly`` runs such a computation in a daemon thread while the main thread waits
on it; OpenCV and numpy release the GIL, and the wait (``Thread.join``) is interrupted by
signals, so the handler's exception (``KeyboardInterrupt``, ``StageTimeout``) is raised at once
in the main thread and unwinds the run (temporary folders removed). The abandoned computation
ends on its own or with the process. Only pure computations go here: nothing that writes files
(an abandoned writer could recreate a folder being removed) or talks to another process.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import ParamSpec, TypeVar

T = TypeVar("T")
P = ParamSpec("P")
_running: set[threading.Event] = set()   # computations started and not yet finished


def call_interruptibly(fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
    """``fn(*args, **kwargs)``, waited for so that signals reach the main thread while it runs.

    Off the main thread (a Dask worker's task thread) signals cannot arrive anyway: a plain call.
    """
    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)
    value: list[T] = []                 # what fn returned, once it has
    error: list[BaseException] = []
    done = threading.Event()

    def work() -> None:
        try:
            value.append(fn(*args, **kwargs))
        except BaseException as err:  # handed to the caller's thread as it is
            error.append(err)
        finally:
            done.set()
            _running.discard(done)

    _running.add(done)
    worker = threading.Thread(target=work, name=f"slz-{getattr(fn, '__name__', 'work')}", daemon=True)
    worker.start()
    # Event.wait, not Thread.join: an interrupted join marks a still-running thread as stopped
    # (CPython's bpo-45274 clean-up), which would hide it from ``abandoned``.
    done.wait()
    if error:
        raise error[0]
    return value[0]


def abandoned() -> bool:
    """Whether a computation left behind by an interruption is still running (see ``exit_now``)."""
    return bool(_running)


def exit_now(code: int) -> None:
    """Leave at once after an interruption that left a computation running.

    The run has unwound (temporary folders gone); interpreter finalization would now contend
    with the abandoned thread for the GIL and memory (measured 1.4-2 s more on a 4096 x 4096
    frame). atexit handlers and the standard streams are run and flushed first.
    """
    import atexit
    import contextlib
    import os
    import sys

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM stops the work the way Ctrl-C does: the exception unwinds through the atomic writers
    (temporary files and folders are removed) and slz exits with 130. Off the main thread (slz called
    from a thread) signals cannot arrive there: nothing is changed."""
    def stop(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
