"""Pairing by stamp (sync.py): closest first, each message once, order-independent, bounded memory."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slzcli.sources.sync import PoseTrack, Stream, StreamPairer, pair_stamps

MS = 1_000_000
TOL = 20 * MS
WINDOW = 500 * MS
Tag = tuple[Stream, int]  # (stream, stamp): the payload the tests pair
Items = list[Tag]  # in arrival order


def stream(pairer: StreamPairer[Tag], items: Items) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for s, t in items:
        out += [(p.stamp_ns, p.depth_stamp_ns) for p in pairer.push(s, t, (s, t))]
    out += [(p.stamp_ns, p.depth_stamp_ns) for p in pairer.flush()]
    return out


def test_nearest_within_tolerance_each_used_once() -> None:
    color = [0, 33 * MS, 66 * MS, 100 * MS]
    depth = [5 * MS, 30 * MS, 36 * MS, 150 * MS]  # 150 ms has no colour within 20 ms
    pairs = pair_stamps(color, depth, TOL)
    # 33 ms is 3 ms from both 30 and 36: a tie goes to the earlier depth; 66, 100 and 150 stay unpaired.
    assert pairs == [(0, 0), (1, 1)]


def test_greedy_prefers_the_closest_candidate() -> None:
    # colour 10 is 2 from depth 12 and 4 from depth 6: 10-12 first, then 0-6.
    assert pair_stamps([0, 10 * MS], [6 * MS, 12 * MS], TOL) == [(0, 0), (1, 1)]
    # Only one depth: it goes to the nearer colour; the other colour stays unpaired.
    assert pair_stamps([0, 10 * MS], [8 * MS], TOL) == [(1, 0)]


def test_tolerance_is_inclusive_and_respected() -> None:
    assert pair_stamps([0], [TOL], TOL) == [(0, 0)]
    assert pair_stamps([0], [TOL + 1], TOL) == []
    assert pair_stamps([], [1], TOL) == [] and pair_stamps([1], [], TOL) == []


def test_stream_pairer_counts_missing_and_unpaired() -> None:
    items: Items = []
    for k in range(100):
        t = k * 33 * MS
        if k % 10 != 3:
            items.append(("color", t))
        if k % 7 != 2:
            items.append(("depth", t + 4 * MS))
    p = StreamPairer[Tag](TOL, WINDOW)
    out = stream(p, items)
    n_color = sum(1 for s, _ in items if s == "color")
    n_depth = len(items) - n_color
    assert p.paired == len(out)
    assert p.paired + p.unpaired["color"] == n_color and p.paired + p.unpaired["depth"] == n_depth
    both = [k for k in range(100) if k % 10 != 3 and k % 7 != 2]
    assert [c for c, _ in out] == [k * 33 * MS for k in both]
    assert p.late == 0


def test_stream_pairer_shuffled_within_window_equals_sorted() -> None:
    items: Items = [("color", k * 33 * MS) for k in range(60)] + [("depth", k * 33 * MS + 7 * MS) for k in range(60)]
    rng = random.Random(1)
    # Shuffle inside blocks of 8 messages (~130 ms of data, inside the 500 ms window).
    items.sort(key=lambda it: it[1])
    shuffled: Items = []
    for i in range(0, len(items), 8):
        block = items[i:i + 8]
        rng.shuffle(block)
        shuffled += block
    a = stream(StreamPairer[Tag](TOL, WINDOW), items)
    p = StreamPairer[Tag](TOL, WINDOW)
    b = stream(p, shuffled)
    assert a == b and len(a) == 60 and p.late == 0


def test_message_later_than_window_is_counted_late_not_lost() -> None:
    p = StreamPairer[Tag](TOL, 100 * MS)
    items: Items = [("color", k * 33 * MS) for k in range(30)] + [("depth", k * 33 * MS) for k in range(30)]
    items.sort(key=lambda it: it[1])
    items.remove(("depth", 0))
    items.append(("depth", 0))  # arrives ~1 s late
    out = stream(p, items)
    assert len(out) == 29 and p.late == 1
    assert p.unpaired == {"color": 1, "depth": 1}


def test_buffer_stays_bounded_for_long_overlapping_chains() -> None:
    # 60 Hz depth against 30 Hz colour with a 20 ms tolerance: every message overlaps its neighbours.
    p = StreamPairer[Tag](TOL, WINDOW)
    peak = 0
    n = 0
    for k in range(3000):
        t = k * 16_666_667
        if k % 2 == 0:
            n += len(p.push("color", t, ("color", t)))
        n += len(p.push("depth", t + MS, ("depth", t + MS)))
        peak = max(peak, p.pending)
    n += len(p.flush())
    assert peak < 200  # about 2 windows of messages, not 4500
    assert n == 1500 and p.unpaired["color"] == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 2000), max_size=40), st.lists(st.integers(0, 2000), max_size=40),
       st.randoms(use_true_random=False))
def test_incremental_equals_batch_for_any_stamps_and_order(c_ms, d_ms, rnd) -> None:
    color = sorted(set(c_ms))
    depth = sorted(set(d_ms))
    want = sorted((color[i] * MS, depth[j] * MS) for i, j in pair_stamps(
        [c * MS for c in color], [d * MS for d in depth], TOL))
    items: Items = [("color", c * MS) for c in color] + [("depth", d * MS) for d in depth]
    rnd.shuffle(items)
    p = StreamPairer[Tag](TOL, 10_000 * MS)  # window longer than the data: any order is in time
    got = sorted(stream(p, items))
    assert got == want
    assert p.paired + p.unpaired["color"] == len(color) and p.paired + p.unpaired["depth"] == len(depth)


def test_pose_track_interpolates_and_respects_tolerance() -> None:
    tr = PoseTrack(50 * MS)
    A = np.eye(4)
    B = np.eye(4)
    B[:3, 3] = (2.0, 0.0, 0.0)
    c, s = np.cos(np.pi / 2), np.sin(np.pi / 2)
    B[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    tr.add(0, A)
    tr.add(40 * MS, B)
    mid = tr.at(20 * MS)
    assert mid is not None
    np.testing.assert_allclose(mid[:3, 3], (1.0, 0.0, 0.0))
    ang = np.degrees(np.arctan2(mid[1, 0], mid[0, 0]))
    assert ang == pytest.approx(45.0)
    np.testing.assert_array_equal(tr.at(40 * MS), B)
    np.testing.assert_array_equal(tr.at(85 * MS), B)  # nearest within tolerance
    assert tr.at(91 * MS) is None and tr.at(-51 * MS) is None
    tr.prune(40 * MS)
    assert len(tr) == 2  # keeps one pose before the cut for interpolation
