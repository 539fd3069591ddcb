"""The flight-wide landing map: ``landing_map.npz`` (the fused cells and their verdict) and a PNG of it.

Arrays are row j = world y (row 0 the southern edge: ``origin_xy`` is the south-west corner of cell (0, 0)),
column i = world x, in the map frame of the run's last map segment (``frame_id``: ``map``, ``map_K``, as in
results.mcap). The PNG (``outputs/landing_map.py``) shows +y up, the verdict coloured, a legend with each
verdict's area and a scale bar. ``landing_grid`` is the same map as the typed record results.mcap encodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from slzcli.fusion.verdict import VERDICT_NAMES, FusedMaps
from slzcli.outputs import files
from slzcli.outputs.landing_map import landing_map_bgr
from slzcli.outputs.results_mcap import map_frame_of
from slzcli.types import LandingGrid

NAMES = tuple(VERDICT_NAMES[k] for k in sorted(VERDICT_NAMES))   # name of each verdict code


@dataclass(frozen=True, eq=False)
class Judged:
    """The arrays of a region a landing grid is made of: what a detection keeps until a sink writes its grid
    (results.mcap, in the background writer), not the whole fused maps (~15-25 MB a detection at 7.5-10 m)."""

    x0: int
    y0: int
    cell_m: float
    seen: np.ndarray
    verdict: np.ndarray
    score: np.ndarray
    height_m: np.ndarray
    variance_m2: np.ndarray
    looks: np.ndarray

    @classmethod
    def of(cls, fm: FusedMaps) -> Judged:
        reg = fm.region
        return cls(reg.x0, reg.y0, reg.cell_m, reg.seen, fm.verdict, fm.score, reg.h, reg.var, reg.looks)


def landing_grid(cells: FusedMaps | Judged, segment: int, frame_index: int, stamp_ns: int,
                 crop: bool = False) -> LandingGrid:
    """The verdict, score, height, its variance and looks of a region (``crop``: only the bounding box of its
    seen cells, what a detection's message carries)."""
    c = cells if isinstance(cells, Judged) else Judged.of(cells)
    seen = c.seen
    sl: tuple[slice, slice] = (slice(None), slice(None))
    if crop and seen.any():
        rows, cols = np.flatnonzero(seen.any(axis=1)), np.flatnonzero(seen.any(axis=0))
        sl = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
    s = seen[sl]

    def f(a: np.ndarray) -> np.ndarray:
        return np.where(s, a[sl], np.nan).astype(np.float32)

    x0, y0 = c.x0 + sl[1].indices(seen.shape[1])[0], c.y0 + sl[0].indices(seen.shape[0])[0]
    return LandingGrid(origin_xy=(x0 * c.cell_m, y0 * c.cell_m),     # as ``Region.origin_m``
                       resolution_m=c.cell_m, segment=segment, frame_index=frame_index, stamp_ns=stamp_ns,
                       verdict=c.verdict[sl].astype(np.uint8), verdict_names=NAMES, score=f(c.score),
                       height_m=f(c.height_m), variance_m2=f(c.variance_m2), looks=f(c.looks))


def landing_map_arrays(fm: FusedMaps, grid: LandingGrid, frame_id: str) -> dict[str, np.ndarray]:
    """What ``landing_map.npz`` holds (float32 maps, NaN where unseen); ``grid``: ``landing_grid(fm, ...)``."""
    reg = fm.region
    seen = reg.seen

    def f(a: np.ndarray) -> np.ndarray:
        return np.where(seen, a, np.nan).astype(np.float32)

    return {
        "height_m": grid.height_m, "variance_m2": grid.variance_m2, "looks": grid.looks,
        "frames": reg.frames.astype(np.int32),
        "depth_variance": f(fm.depth_variance), "flatness": f(fm.flatness), "inclination": f(fm.inclination),
        "steepness": f(fm.steepness), "score": grid.score, "step_min_m": f(fm.step_min_m),
        "slope_min_deg": f(fm.slope_min_deg), "column_seen": reg.column.astype(bool),
        "verdict": grid.verdict, "verdict_names": np.array(grid.verdict_names),
        "origin_xy": np.array(grid.origin_xy, np.float64), "resolution_m": np.float64(grid.resolution_m),
        "frame_id": np.array(frame_id), "segment": np.int64(grid.segment), "frame_index": np.int64(grid.frame_index),
        "stamp_ns": np.int64(grid.stamp_ns),
    }


def write_landing_map(folder: Path, fm: FusedMaps, segment: int, frame_index: int, stamp_ns: int,
                      map_frame: str) -> LandingGrid:
    """``landing_map.npz`` and ``landing_map.png`` in ``folder``; the grid they hold (for results.mcap).
    ``map_frame``: ``output.map_frame`` (the frame id is its segment's, as results.mcap names it)."""
    grid = landing_grid(fm, segment, frame_index, stamp_ns)
    files.write_npz_streamed(folder / "landing_map.npz",
                             landing_map_arrays(fm, grid, map_frame_of(segment, map_frame)))
    ok, data = cv2.imencode(".png", landing_map_bgr(grid))
    if ok:
        files.write_bytes(folder / "landing_map.png", data.tobytes())
    return grid
