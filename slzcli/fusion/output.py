"""The flight-wide landing map: ``landing_map.npz`` (the fused cells and their verdict) and a PNG of it.

Arrays are row j = world y (row 0 the southern edge: ``origin_xy`` is the south-west corner of cell (0, 0)),
column i = world x, in the map frame of the run's last map segment. The PNG shows north up, the verdict
coloured, a legend and a scale bar.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from slzcli.fusion.verdict import SAFE, UNDECIDED, UNSAFE, UNSEEN, VERDICT_NAMES, FusedMaps
from slzcli.outputs import files, palette

# The verdict colours of every slz picture (outputs/palette.py); unseen cells darker than undecided ones.
COLOURS_BGR = {UNSEEN: (60, 60, 60), UNSAFE: palette.bgr(palette.UNSAFE), UNDECIDED: palette.bgr(palette.UNDECIDED),
               SAFE: palette.bgr(palette.SAFE)}
_PX_PER_CELL = 3           # PNG pixels per cell
_SCALE_BAR_M = (1.0, 2.0, 5.0, 10.0, 20.0)


def landing_map_arrays(fm: FusedMaps, segment: int, frame_index: int) -> dict[str, np.ndarray]:
    """What ``landing_map.npz`` holds (float32 maps, NaN where unseen)."""
    reg = fm.region
    seen = reg.seen

    def f(a: np.ndarray) -> np.ndarray:
        return np.where(seen, a, np.nan).astype(np.float32)

    return {
        "height_m": f(reg.h), "variance_m2": f(reg.var), "looks": f(reg.looks), "frames": reg.frames.astype(np.int32),
        "depth_variance": f(fm.depth_variance), "flatness": f(fm.flatness), "inclination": f(fm.inclination),
        "steepness": f(fm.steepness), "score": f(fm.score), "step_min_m": f(fm.step_min_m),
        "slope_min_deg": f(fm.slope_min_deg), "column_seen": reg.column.astype(bool),
        "verdict": fm.verdict.astype(np.uint8),
        "verdict_names": np.array([VERDICT_NAMES[k] for k in sorted(VERDICT_NAMES)]),
        "origin_xy": np.array(reg.origin_m, np.float64), "resolution_m": np.float64(reg.cell_m),
        "segment": np.int64(segment), "frame_index": np.int64(frame_index),
    }


def landing_map_png(fm: FusedMaps) -> np.ndarray:
    """BGR image of the verdict, north up, with a legend and a scale bar."""
    v = np.flipud(fm.verdict)
    img = np.zeros((*v.shape, 3), np.uint8)
    for code, bgr in COLOURS_BGR.items():
        img[v == code] = bgr
    img = cv2.resize(img, (v.shape[1] * _PX_PER_CELL, v.shape[0] * _PX_PER_CELL), interpolation=cv2.INTER_NEAREST)
    legend_h = 60
    canvas = np.full((img.shape[0] + legend_h, max(img.shape[1], 420), 3), 255, np.uint8)
    canvas[: img.shape[0], : img.shape[1]] = img
    y = img.shape[0] + 20
    x = 8
    for code in (SAFE, UNDECIDED, UNSAFE, UNSEEN):
        cv2.rectangle(canvas, (x, y - 10), (x + 12, y + 2), COLOURS_BGR[code], -1)
        cv2.putText(canvas, VERDICT_NAMES[code], (x + 16, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += 100
    px_per_m = _PX_PER_CELL / fm.region.cell_m
    bar_m = max((m for m in _SCALE_BAR_M if m * px_per_m <= 0.4 * canvas.shape[1]), default=_SCALE_BAR_M[0])
    y2 = y + 25
    cv2.line(canvas, (8, y2), (8 + int(bar_m * px_per_m), y2), (0, 0, 0), 2)
    cv2.putText(canvas, f"{bar_m:g} m   (north up; cell {fm.region.cell_m * 100:.1f} cm)",
                (14 + int(bar_m * px_per_m), y2 + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def write_landing_map(folder: Path, fm: FusedMaps, segment: int, frame_index: int) -> None:
    """``landing_map.npz`` and ``landing_map.png`` in ``folder``."""
    files.write_npz_streamed(folder / "landing_map.npz", dict(landing_map_arrays(fm, segment, frame_index)))
    ok, data = cv2.imencode(".png", landing_map_png(fm))
    if ok:
        files.write_bytes(folder / "landing_map.png", data.tobytes())
