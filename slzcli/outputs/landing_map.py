"""The landing map as a picture (landing_map.png, report.html) and read back from ``landing_map.npz``.

One drawing for both: the verdict of every cell in the project's colours (``palette``: Okabe-Ito bluish
green safe, vermillion unsafe, grey undecided, dark grey unseen), +y up and +x right as in the map frame,
a legend with each verdict's area, a scale bar in metres and, when given, the committed site's square as
the overlays draw it (a white outline on a black halo, so the verdict under it stays visible).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from slzcli.outputs import palette
from slzcli.types import LandingGrid

CELL_RGB: dict[str, palette.RGB] = {**dict(palette.VERDICTS), "unseen": palette.UNSEEN}
LEGEND_ORDER = ("safe", "undecided", "unsafe", "unseen")
# Display only (no result depends on these): pixels per cell (3 keeps the 40 m window, 488 cells, within
# ~1500 px; small maps are enlarged to ~MIN_MAP_PX), the legend band, the scale bar's candidate lengths.
PX_PER_CELL = 3
MAX_PX_PER_CELL = 12
MIN_MAP_PX = 480
LEGEND_BAND_PX = 64
MIN_WIDTH_PX = 560
SCALE_BARS_M = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
FONT = cv2.FONT_HERSHEY_SIMPLEX
TEXT_BGR = (0, 0, 0)


def verdict_lut(names: tuple[str, ...]) -> np.ndarray:
    """(len(names), 3) uint8 RGB of each verdict code (``names[code]``)."""
    return np.array([CELL_RGB[n] for n in names], np.uint8)


def px_per_cell(grid: LandingGrid) -> int:
    return int(np.clip(MIN_MAP_PX // max(grid.shape), PX_PER_CELL, MAX_PX_PER_CELL))


def landing_map_bgr(grid: LandingGrid, site_xy: np.ndarray | None = None) -> np.ndarray:
    """The map (BGR, +y up) with its legend and scale bar below; ``site_xy``: (4, 2) corners of a square to
    outline (world x, y in the grid's frame), e.g. the committed site's."""
    ny, nx = grid.shape
    k = px_per_cell(grid)
    rgb = verdict_lut(grid.verdict_names)[np.flipud(grid.verdict)]
    img = cv2.resize(np.ascontiguousarray(rgb[..., ::-1]), (nx * k, ny * k), interpolation=cv2.INTER_NEAREST)
    canvas = np.full((img.shape[0] + LEGEND_BAND_PX, max(img.shape[1], MIN_WIDTH_PX), 3), 255, np.uint8)
    canvas[: img.shape[0], : img.shape[1]] = img
    if site_xy is not None:
        _outline(canvas, _to_px(grid, np.asarray(site_xy, np.float64)[:, :2], k))
    cell_area = grid.resolution_m ** 2
    y, x = img.shape[0] + 20, 8
    for name in LEGEND_ORDER:
        if name not in grid.verdict_names:
            continue
        code = grid.verdict_names.index(name)
        area = cell_area * int(np.count_nonzero(grid.verdict == code))
        cv2.rectangle(canvas, (x, y - 11), (x + 13, y + 2), palette.bgr(CELL_RGB[name]), -1)
        cv2.rectangle(canvas, (x, y - 11), (x + 13, y + 2), TEXT_BGR, 1)
        label = f"{name} {area:.0f} m2"
        cv2.putText(canvas, label, (x + 18, y), FONT, 0.45, TEXT_BGR, 1, cv2.LINE_AA)
        x += 18 + cv2.getTextSize(label, FONT, 0.45, 1)[0][0] + 16
    if site_xy is not None:
        cv2.rectangle(canvas, (x, y - 11), (x + 13, y + 2), palette.bgr(palette.HALO), 3)
        cv2.rectangle(canvas, (x, y - 11), (x + 13, y + 2), palette.bgr(palette.SITE), 1)
        cv2.putText(canvas, "site", (x + 18, y), FONT, 0.45, TEXT_BGR, 1, cv2.LINE_AA)
    px_per_m = k / grid.resolution_m
    bar_m = max((m for m in SCALE_BARS_M if m * px_per_m <= 0.4 * canvas.shape[1]), default=SCALE_BARS_M[0])
    y2, bar = y + 28, round(bar_m * px_per_m)
    cv2.line(canvas, (8, y2), (8 + bar, y2), TEXT_BGR, 2)
    for end in (8, 8 + bar):
        cv2.line(canvas, (end, y2 - 5), (end, y2 + 5), TEXT_BGR, 2)
    cv2.putText(canvas, f"{bar_m:g} m   (x right, y up; cell {grid.resolution_m * 100:.1f} cm)",
                (16 + bar, y2 + 5), FONT, 0.45, TEXT_BGR, 1, cv2.LINE_AA)
    return canvas


def read_landing_map(path: Path) -> LandingGrid:
    """``landing_map.npz`` as the grid it was written from (``fusion/output.py``)."""
    with np.load(path) as z:
        a = {k: z[k] for k in z.files}
    return LandingGrid(origin_xy=(float(a["origin_xy"][0]), float(a["origin_xy"][1])),
                       resolution_m=float(a["resolution_m"]), segment=int(a["segment"]),
                       frame_index=int(a["frame_index"]), stamp_ns=int(a.get("stamp_ns", 0)),
                       verdict=a["verdict"], verdict_names=tuple(str(n) for n in a["verdict_names"]),
                       score=a["score"], height_m=a["height_m"], variance_m2=a["variance_m2"], looks=a["looks"])


def _to_px(grid: LandingGrid, xy: np.ndarray, k: int) -> np.ndarray:
    """World (x, y) -> picture pixels (column, row) of a map drawn ``k`` px a cell, +y up."""
    ox, oy = grid.origin_xy
    col = (xy[:, 0] - ox) / grid.resolution_m * k
    row = (grid.shape[0] - (xy[:, 1] - oy) / grid.resolution_m) * k
    return np.stack([col, row], axis=1)


def _outline(canvas: np.ndarray, corners_px: np.ndarray) -> None:
    """A square's outline, white on a black halo (the overlays' site square), corners in any order."""
    c = corners_px.mean(axis=0)
    order = np.argsort(np.arctan2(corners_px[:, 1] - c[1], corners_px[:, 0] - c[0]))
    pts = np.round(corners_px[order]).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(canvas, [pts], True, palette.bgr(palette.HALO), 4, cv2.LINE_8)
    cv2.polylines(canvas, [pts], True, palette.bgr(palette.SITE), 2, cv2.LINE_8)
