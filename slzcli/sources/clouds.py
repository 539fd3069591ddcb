"""Recorded map clouds (``slam.points_topic``) waiting for the frame they belong to.

The reader decodes each PointCloud2 as it streams past, in the same pass as the images
(the recording used to be opened a second time for its clouds). A cloud goes to the
posed frame nearest in stamp within ``sources.pose_tolerance_ms``, at most one frame per
cloud; frames come in stamp order, so clouds older than the current frame by more than
the tolerance can never be taken and are dropped. The reader also drops those older
than any frame still to come, so memory holds the clouds near the frames in flight,
however long the recording. As for poses, a cloud must be logged within
``sources.reorder_window_ms`` of the images of its time: one logged later (e.g. appended
after all the images) finds its frames gone; it is counted as ``late``, not kept.
"""

from __future__ import annotations

import bisect

from slzcli.types import MapCloud


class CloudBuffer:
    """Decoded clouds by stamp; ``take`` hands the nearest one to a frame and forgets it."""

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self._clouds: list[MapCloud] = []  # sorted by stamp
        self._floor: int | None = None  # no frame still to come can take a cloud older than this
        self.late = 0

    def __len__(self) -> int:
        return len(self._clouds)

    def add(self, cloud: MapCloud) -> None:
        if self._floor is not None and cloud.stamp_ns < self._floor:
            self.late += 1
            return
        i = bisect.bisect_right(self._clouds, cloud.stamp_ns, key=lambda c: c.stamp_ns)
        self._clouds.insert(i, cloud)

    def take(self, stamp_ns: int) -> MapCloud | None:
        """The cloud nearest to ``stamp_ns`` within the tolerance, taken out; older clouds dropped."""
        self.prune(stamp_ns - self.tolerance_ns)
        if not self._clouds:
            return None
        best = min(range(len(self._clouds)), key=lambda j: abs(self._clouds[j].stamp_ns - stamp_ns))
        if abs(self._clouds[best].stamp_ns - stamp_ns) > self.tolerance_ns:
            return None
        return self._clouds.pop(best)

    def prune(self, before_ns: int) -> None:
        """Forget clouds with a stamp before ``before_ns`` (no frame still to come can take them)."""
        self._floor = before_ns if self._floor is None else max(self._floor, before_ns)
        del self._clouds[: bisect.bisect_left(self._clouds, self._floor, key=lambda c: c.stamp_ns)]
