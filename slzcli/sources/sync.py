"""Pure pairing of streams by stamp: colour <-> depth, and a pose for each pair.

Rule (colour <-> depth): among all (colour, depth) candidates with |dt| <= tolerance,
accept the closest first (ties: earlier colour first); each message is used at most
once. The result depends only on the sets of stamps, not on arrival order, so shuffled
messages pair as sorted ones would. ``pair_stamps`` applies the rule to whole lists;
``StreamPairer`` applies it incrementally with bounded memory: it holds messages until
no later message can still be a candidate (newest stamp seen minus ``window_ns`` is
taken as a lower bound for any stamp still to come), then settles that group. A
message that arrives later than the window allows is counted as late and unpaired. A
second message of a stream with a stamp already held is dropped: counted as a duplicate
when its bytes are the same (recorded twice), as ``repeated`` when they differ. A
chain of overlapping candidates longer than two windows (e.g. 60 Hz depth against 30 Hz
colour) is settled one window at a time so memory stays bounded (only pairs straddling
such a cut can differ from ``pair_stamps`` on the whole lists).

Poses: ``PoseTrack.at`` interpolates (linear position, slerp rotation) between the
poses either side of the stamp when both are within ``tolerance_ns``; otherwise it
takes the nearest pose within tolerance; otherwise None (the frame has no pose).
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Generic, Literal, TypeVar

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

Stream = Literal["color", "depth"]
FIRST_KEPT = 64  # stamps of each stream kept to say how far apart two streams that never pair are; project


def pair_stamps(color_ns: Sequence[int], depth_ns: Sequence[int], tolerance_ns: int) -> list[tuple[int, int]]:
    """Index pairs (i_color, i_depth), closest first, each index at most once; sorted by colour stamp."""
    c = np.asarray(color_ns, dtype=np.int64)
    d = np.asarray(depth_ns, dtype=np.int64)
    if c.size == 0 or d.size == 0:
        return []
    d_order = np.argsort(d, kind="stable")
    d_sorted = d[d_order]
    # Candidates: for each colour, the depths within the tolerance window (searchsorted, no N x M matrix).
    lo = np.searchsorted(d_sorted, c - tolerance_ns, side="left")
    hi = np.searchsorted(d_sorted, c + tolerance_ns, side="right")
    counts = hi - lo
    ci = np.repeat(np.arange(c.size), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    dj = d_order[np.repeat(lo, counts) + offsets]
    if ci.size == 0:
        return []
    dt = np.abs(c[ci] - d[dj])
    order = np.lexsort((d[dj], c[ci], dt))
    used_c = np.zeros(c.size, dtype=bool)
    used_d = np.zeros(d.size, dtype=bool)
    pairs = []
    for k in order:  # over candidate edges of a group, not pixels; a handful per frame
        i, j = int(ci[k]), int(dj[k])
        if not used_c[i] and not used_d[j]:
            used_c[i] = used_d[j] = True
            pairs.append((i, j))
    pairs.sort(key=lambda p: (int(c[p[0]]), p[0]))
    return pairs


def stamp_offset_ns(frames_ns: np.ndarray, poses_ns: np.ndarray, tolerance_ns: int) -> float:
    """The offset d (other stamp - frame stamp) at which most frames have another message within ``tolerance_ns``.

    What a stream that never pairs is off by (poses against frames, depth against colour).

    Every (frame, pose) difference is binned at the tolerance; the bin holding the most distinct frames
    wins (ties: the smallest offset); its median difference is returned.
    """
    d = (poses_ns[None, :] - frames_ns[:, None]).astype(np.float64)  # frames x poses, both bounded
    b = np.floor(d / tolerance_ns).astype(np.int64)
    rows = np.broadcast_to(np.arange(len(frames_ns))[:, None], b.shape)
    pairs = np.unique(np.stack([b.ravel(), rows.ravel()], axis=1), axis=0)  # one count per frame and bin
    bins, counts = np.unique(pairs[:, 0], return_counts=True)
    best = bins[counts == counts.max()]
    pick = best[np.argmin(np.abs(best))]
    return float(np.median(d[b == pick]))


P = TypeVar("P")  # what the caller keeps of each message (the raw message, its bytes, or nothing)


@dataclass(frozen=True)
class Pair(Generic[P]):
    """A colour and a depth message paired; the frame takes the colour stamp."""

    stamp_ns: int
    depth_stamp_ns: int
    color: P
    depth: P


@dataclass(order=True)
class _Item(Generic[P]):
    stamp_ns: int
    seq: int
    stream: Stream = field(compare=False)
    payload: P = field(compare=False)


class StreamPairer(Generic[P]):
    """Incremental ``pair_stamps`` with bounded memory; counts what it cannot pair."""

    def __init__(self, tolerance_ns: int, window_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self.window_ns = int(window_ns)
        self._buf: list[_Item[P]] = []
        self._seq = itertools.count()
        self._newest: int | None = None
        self._settled_until: int | None = None
        self.paired = 0
        self.unpaired = {"color": 0, "depth": 0}
        self.late = 0
        self.duplicates = 0
        self.repeated = {"color": 0, "depth": 0}
        self.first: dict[str, list[int]] = {"color": [], "depth": []}  # the first FIRST_KEPT stamps of each

    def never_paired(self) -> str | None:
        """Why colour and depth never paired, with how far apart they are (None: some did, or a stream is empty)."""
        c, d = self.first["color"], self.first["depth"]
        if self.paired or not c or not d:
            return None
        off = stamp_offset_ns(np.asarray(c, np.int64), np.asarray(d, np.int64), max(1, self.tolerance_ns)) / 1e9
        return (f"colour and depth never pair within sources.sync_tolerance_ms {self.tolerance_ns / 1e6:g} ms: the "
                f"depth stamps are {abs(off):.6g} s {'after' if off > 0 else 'before'} the colour ones (the offset at "
                "which most colour frames would find a depth); fix the recording's clocks, or raise "
                "sources.sync_tolerance_ms if the two streams are stamped that far apart")

    def push(self, stream: Stream, stamp_ns: int, payload: P) -> list[Pair[P]]:
        """Add one message; returns the pairs that can no longer change, in stamp order."""
        if len(self.first[stream]) < FIRST_KEPT:
            self.first[stream].append(int(stamp_ns))
        if self._settled_until is not None and stamp_ns <= self._settled_until:
            self.late += 1
            self.unpaired[stream] += 1
            return []
        i = bisect.bisect_left(self._buf, int(stamp_ns), key=lambda it: it.stamp_ns)
        while i < len(self._buf) and self._buf[i].stamp_ns == stamp_ns:
            if self._buf[i].stream == stream:  # one frame per stamp and stream: the first message is kept
                if _same(self._buf[i].payload, payload):
                    self.duplicates += 1  # the same message recorded twice
                else:
                    self.repeated[stream] += 1  # another message under the same stamp: a stuck clock
                return []
            i += 1
        bisect.insort(self._buf, _Item(int(stamp_ns), next(self._seq), stream, payload))
        self._newest = stamp_ns if self._newest is None else max(self._newest, stamp_ns)
        return self._drain(final=False)

    def flush(self) -> list[Pair[P]]:
        """Settle everything still held (end of the recording)."""
        return self._drain(final=True)

    @property
    def pending(self) -> int:
        return len(self._buf)

    @property
    def oldest_ns(self) -> int | None:
        """Stamp of the oldest message still held (None when none is)."""
        return self._buf[0].stamp_ns if self._buf else None

    def _first_group_end(self) -> int:
        """Index of the last item of the first group of mutually reachable candidates."""
        tol = self.tolerance_ns
        last_c: int | None = None
        last_d: int | None = None
        stamps = [it.stamp_ns for it in self._buf]
        streams = [it.stream for it in self._buf]
        # Suffix minima of colour and depth stamps to test each cut in one pass.
        n = len(stamps)
        next_c: list[int | None] = [None] * (n + 1)
        next_d: list[int | None] = [None] * (n + 1)
        for i in range(n - 1, -1, -1):
            next_c[i] = stamps[i] if streams[i] == "color" else next_c[i + 1]
            next_d[i] = stamps[i] if streams[i] == "depth" else next_d[i + 1]
        for i in range(n):
            if streams[i] == "color":
                last_c = stamps[i]
            else:
                last_d = stamps[i]
            nd, nc = next_d[i + 1], next_c[i + 1]
            ok_c = last_c is None or nd is None or nd - last_c > tol
            ok_d = last_d is None or nc is None or nc - last_d > tol
            if ok_c and ok_d:
                return i
        return n - 1

    def _drain(self, final: bool) -> list[Pair[P]]:
        out: list[Pair] = []
        while self._buf:
            end = self._first_group_end()
            horizon = None if self._newest is None else self._newest - self.window_ns
            if not (final or (horizon is not None and horizon > self._buf[end].stamp_ns + self.tolerance_ns)):
                if horizon is None or self._buf[0].stamp_ns >= horizon - self.window_ns:
                    break
                # A chain longer than two windows: settle its older part (all but the last window)
                # so memory stays bounded; only pairs straddling the cut can come out different.
                end = max(i for i, it in enumerate(self._buf) if it.stamp_ns < horizon)
            group, self._buf = self._buf[: end + 1], self._buf[end + 1:]
            out.extend(self._settle(group))
            self._settled_until = group[-1].stamp_ns if self._settled_until is None else max(
                self._settled_until, group[-1].stamp_ns)
        return out

    def _settle(self, group: list[_Item]) -> list[Pair[P]]:
        colors = [it for it in group if it.stream == "color"]
        depths = [it for it in group if it.stream == "depth"]
        idx = pair_stamps([it.stamp_ns for it in colors], [it.stamp_ns for it in depths], self.tolerance_ns)
        self.paired += len(idx)
        self.unpaired["color"] += len(colors) - len(idx)
        self.unpaired["depth"] += len(depths) - len(idx)
        return [Pair(colors[i].stamp_ns, depths[j].stamp_ns, colors[i].payload, depths[j].payload) for i, j in idx]


_BUFFERS = (bytes, bytearray, memoryview, np.ndarray)


def _same(a: object, b: object) -> bool:
    """Whether two payloads hold the same bytes (None, when no payload is kept, counts as the same).

    A payload with a ``data`` attribute (a raw message) is compared by that.
    """
    a, b = getattr(a, "data", a), getattr(b, "data", b)
    if a is None or b is None or a is b:
        return True
    if isinstance(a, _BUFFERS) and isinstance(b, _BUFFERS):
        return bool(_view(a) == _view(b))
    return bool(a == b)


def _view(data: bytes | bytearray | memoryview | np.ndarray) -> memoryview:
    return data.data if isinstance(data, np.ndarray) else memoryview(data)  # an array's own buffer


class PoseTrack:
    """Timestamped poses (T_world_camera) with interpolation at a query stamp; prunable."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self._stamps: list[int] = []
        self._poses: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_ns(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def add(self, stamp_ns: int, T: np.ndarray) -> None:
        i = bisect.bisect_right(self._stamps, stamp_ns)
        if i > 0 and self._stamps[i - 1] == stamp_ns:
            self._poses[i - 1] = T  # a repeated stamp replaces the earlier pose
            return
        self._stamps.insert(i, int(stamp_ns))
        self._poses.insert(i, np.asarray(T, dtype=np.float64))

    def at(self, stamp_ns: int) -> np.ndarray | None:
        i = bisect.bisect_left(self._stamps, stamp_ns)
        tol = self.tolerance_ns
        after = i if i < len(self._stamps) else None
        before = i - 1 if i > 0 else None
        if after is not None and self._stamps[after] == stamp_ns:
            return self._poses[after].copy()
        if before is not None and after is not None and stamp_ns - self._stamps[before] <= tol \
                and self._stamps[after] - stamp_ns <= tol:
            return _interpolate(self._stamps[before], self._poses[before], self._stamps[after],
                                self._poses[after], stamp_ns)
        near = [k for k in (before, after) if k is not None and abs(self._stamps[k] - stamp_ns) <= tol]
        if not near:
            return None
        k = min(near, key=lambda k: abs(self._stamps[k] - stamp_ns))
        return self._poses[k].copy()

    def prune(self, before_ns: int) -> None:
        """Forget poses no longer needed, keeping one before ``before_ns`` for interpolation."""
        i = bisect.bisect_left(self._stamps, before_ns) - 1
        if i > 0:
            del self._stamps[:i]
            del self._poses[:i]


def _interpolate(ta: int, Ta: np.ndarray, tb: int, Tb: np.ndarray, t: int) -> np.ndarray:
    alpha = (t - ta) / (tb - ta)
    rot = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([Ta[:3, :3], Tb[:3, :3]])))([alpha])
    T = np.eye(4)
    T[:3, :3] = rot.as_matrix()[0]
    T[:3, 3] = (1 - alpha) * Ta[:3, 3] + alpha * Tb[:3, 3]
    return T
