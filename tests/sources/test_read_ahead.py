"""Decode ahead (sources/read_ahead.py): order kept, memory bounded, errors where the frame would be, clean stop."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from slzcli.errors import DatasetError
from slzcli.sources.read_ahead import read_ahead


def test_items_come_out_in_order_from_another_thread() -> None:
    where: list[str] = []

    def items() -> Iterator[int]:
        for i in range(100):
            where.append(threading.current_thread().name)
            yield i

    assert list(read_ahead(items(), 3)) == list(range(100))
    assert set(where) == {"slz-reader"}


def test_depth_zero_reads_in_the_caller() -> None:
    me = threading.current_thread().name
    seen: list[str] = []

    def items() -> Iterator[int]:
        for i in range(3):
            seen.append(threading.current_thread().name)
            yield i

    assert list(read_ahead(items(), 0)) == [0, 1, 2] and set(seen) == {me}


def test_the_reader_stays_at_most_depth_ahead() -> None:
    produced: list[int] = []
    gate = threading.Event()

    def items() -> Iterator[int]:
        for i in range(50):
            produced.append(i)
            yield i

    it = read_ahead(items(), 2)
    assert next(it) == 0
    while len(produced) < 4:  # 0 taken, 1 and 2 queued, 3 made and waiting for a slot
        gate.wait(0.01)
    gate.wait(0.2)  # however long we wait, nothing more is read while the caller holds back
    assert produced == [0, 1, 2, 3]
    it.close()


def test_an_error_is_raised_where_its_frame_would_have_come_out(tmp_path) -> None:
    def items() -> Iterator[int]:
        yield 0
        yield 1
        raise DatasetError(tmp_path / "flight.mcap", "chunk 3 is damaged")

    got = []
    with pytest.raises(DatasetError, match="chunk 3 is damaged"):
        for i in read_ahead(items(), 4):
            got.append(i)
    assert got == [0, 1]


def test_stopping_early_stops_the_reader() -> None:
    produced: list[int] = []

    def items() -> Iterator[int]:
        for i in range(10_000):
            produced.append(i)
            yield i

    it = read_ahead(items(), 2)
    assert [next(it) for _ in range(3)] == [0, 1, 2]
    it.close()  # tells the reader to stop and joins it
    n = len(produced)
    threading.Event().wait(0.1)
    assert n <= 6 and len(produced) == n  # nothing read after the close
