"""SLAM map segments: after a map reset a backend's poses are in a new world frame.

ORB-SLAM3 (Atlas) begins a new map at the identity when it cannot relocalise; the built-in
odometry starts one after ``slam.odometry.reinit_after_frames`` lost frames. Each map is a
*segment* (``TrackResult.segment``: 0, 1, ...). Poses, map points and sites of different
segments are in world frames whose relation is unknown, so nothing is compared across
segments: the pipeline gravity-aligns each segment from its own first pose, a site is
confirmed only by detections of its own segment, the ATE is aligned per segment.

The run's world frame (landing.json, trajectory.tum, points.ply) is one segment's, the
*primary* segment: the committed site's; without a site, the segment with the most tracked
frames (the earlier one on a tie).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    """One map of a run: how many frames it tracked, its first and last tracked frame, its keyframes."""

    segment: int
    frames_tracked: int
    first_frame: int
    last_frame: int
    keyframes: int


def segment_table(segments: np.ndarray, has_pose: np.ndarray, keyframes: Mapping[int, int]) -> list[Segment]:
    """The segments that have a pose, in order; ``segments``/``has_pose`` per frame (frame index = row)."""
    idx = np.flatnonzero(has_pose)
    seg = np.asarray(segments)[idx]
    ids, first, counts = np.unique(seg, return_index=True, return_counts=True)
    last = len(seg) - 1 - np.unique(seg[::-1], return_index=True)[1]
    return [Segment(int(k), int(n), int(idx[f]), int(idx[e]), int(keyframes.get(int(k), 0)))
            for k, f, e, n in zip(ids, first, last, counts, strict=True)]


def primary_segment(table: list[Segment], committed_segment: int | None) -> int | None:
    """The segment that is the run's world frame (module docstring); None when nothing was tracked."""
    if committed_segment is not None:
        return committed_segment
    if not table:
        return None
    return max(table, key=lambda s: (s.frames_tracked, -s.segment)).segment
