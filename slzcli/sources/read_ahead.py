"""Decode ahead: a recording's next frames are read and decoded in a thread while the current one is used.

Reading a frame (chunk decompression, JPEG / PNG / compressedDepth decoding, depth to metres) is
work the detection of the frame before does not need; in a thread it overlaps that detection
(zstd, OpenCV and numpy release the GIL). ``sources.read_ahead_frames`` frames are held at
most (each ~3 MB at 640x480): memory stays bounded whatever the recording's length. 0 reads in
the caller, as before.

The frames come out in the recording's order, and an error the reader meets (a damaged chunk,
an undecodable frame the source refuses) is raised in the caller where the frame would have come
out, as without the thread. The caller waits in short slices, so ``--timeout`` (a signal in the
main thread, an asynchronous exception in a Dask worker's thread) still reaches it while it waits
for a stuck read. When the caller stops early (an error, an interruption, the end of a
``--max-frames``), the reader is told to stop and is waited for a short grace: it may be inside
one read of a file that is then closed, which it ends with an error nobody reads.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Generator, Iterable
from typing import Literal, TypeVar

T = TypeVar("T")
# Housekeeping, not tuning: the slice the caller waits in (so signals and async exceptions land between
# slices) and how long a stopped reader is waited for before it is left to end with the process.
WAIT_SLICE_S = 0.05
STOP_GRACE_S = 5.0


# What the reader thread hands over: an item, the end, or what it raised.
_Slot = tuple[Literal["item"], T] | tuple[Literal["end"], None] | tuple[Literal["error"], BaseException]


def read_ahead(items: Iterable[T], depth: int, name: str = "slz-reader") -> Generator[T, None, None]:
    """``items`` in order, produced by a thread up to ``depth`` ahead of the caller (0: no thread)."""
    if depth <= 0:
        yield from items
        return
    slots: queue.Queue[_Slot[T]] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(entry: _Slot[T]) -> bool:
        while not stop.is_set():
            try:
                slots.put(entry, timeout=WAIT_SLICE_S)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for item in items:
                if not put(("item", item)):
                    return
            put(("end", None))
        except BaseException as err:  # handed to the caller where the next frame would have come out
            put(("error", err))

    thread = threading.Thread(target=work, name=name, daemon=True)
    thread.start()
    try:
        while True:
            try:
                entry = slots.get(timeout=WAIT_SLICE_S)
            except queue.Empty:
                continue
            if entry[0] == "end":
                return
            if entry[0] == "error":
                raise entry[1]
            yield entry[1]
    finally:
        stop.set()
        thread.join(STOP_GRACE_S)
