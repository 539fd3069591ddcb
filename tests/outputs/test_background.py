"""The background writer: order kept, memory bounded, errors reach the main thread, abort drops the queue."""

from __future__ import annotations

import threading

import pytest

from slzcli.errors import OutputError
from slzcli.outputs.background import BackgroundWriter


def test_tasks_run_in_order_in_one_other_thread() -> None:
    done: list[tuple[int, str]] = []
    with BackgroundWriter(2) as w:
        for i in range(50):
            w.submit(f"task {i}", lambda i=i: done.append((i, threading.current_thread().name)))
    assert [i for i, _ in done] == list(range(50))
    assert {name for _, name in done} == {"slz-writer"}


def test_the_queue_is_bounded_the_main_loop_waits() -> None:
    """With the writer held, submit returns only for ``depth`` queued tasks (plus the one being written)."""
    gate, started = threading.Event(), threading.Event()
    submitted: list[int] = []
    w = BackgroundWriter(2)

    def hold() -> None:
        started.set()
        gate.wait()

    def feed() -> None:
        for i in range(6):
            w.submit(f"task {i}", hold)
            submitted.append(i)

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    assert started.wait(60)  # a hang guard, not a speed bound
    while len(submitted) < 3 and feeder.is_alive():
        feeder.join(0.01)
    feeder.join(0.2)  # however long we wait, the 4th submit cannot return while the writer is held
    assert feeder.is_alive() and len(submitted) == 3  # 1 being written + 2 queued; the 4th waits
    assert w.busy_with() == "task 0"
    gate.set()
    feeder.join()
    w.close()
    assert submitted == list(range(6)) and w.busy_with() is None


def test_a_write_error_is_raised_in_the_main_thread_and_later_tasks_are_dropped(tmp_path) -> None:
    written: list[int] = []

    def fail() -> None:
        raise OutputError(tmp_path / "frames" / "000001" / "maps.npz", "cannot write (No space left on device)")

    w = BackgroundWriter(4)
    w.submit("frame 0", written.append, 0)
    w.submit("frame 1", fail)
    w.submit("frame 2", written.append, 2)
    with pytest.raises(OutputError, match=r"maps\.npz: cannot write"):
        w.close()
    assert written == [0]


def test_an_error_surfaces_at_the_next_submit() -> None:
    w = BackgroundWriter(1)
    w.submit("bad", lambda: 1 / 0)
    while w._error is None:  # the writer has failed on "bad" (kept, not yet raised)
        w._thread.join(0.01)
    with pytest.raises(ZeroDivisionError):
        w.submit("next", lambda: None)
    w.abort()


def test_abort_drops_what_is_queued_and_waits_for_the_task_in_hand() -> None:
    gate, started = threading.Event(), threading.Event()
    written: list[int] = []

    def slow() -> None:
        started.set()
        gate.wait()
        written.append(0)

    w = BackgroundWriter(4)
    w.submit("frame 0", slow)
    for i in range(1, 4):
        w.submit(f"frame {i}", written.append, i)
    started.wait()
    threading.Timer(0.2, gate.set).start()
    w.abort()  # returns once frame 0 is written; frames 1-3 never are
    assert written == [0] and not w._thread.is_alive()


def test_abort_gives_up_on_a_stuck_task_after_its_grace() -> None:
    gate, started = threading.Event(), threading.Event()
    w = BackgroundWriter(1, grace_s=0.05)
    def stuck() -> None:
        started.set()
        gate.wait()

    w.submit("stuck", stuck)
    assert started.wait(60)  # a hang guard, not a speed bound
    w.abort()  # does not hang: the stuck task is left to the daemon thread
    assert w._thread.is_alive()
    gate.set()
    w._thread.join()


def test_depth_zero_writes_in_the_caller() -> None:
    done: list[str] = []
    with BackgroundWriter(0) as w:
        w.submit("here", lambda: done.append(threading.current_thread().name))
        assert done == [threading.current_thread().name]
    with pytest.raises(ValueError):
        BackgroundWriter(-1)
