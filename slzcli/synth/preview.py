"""Contact sheet of a synthetic frame: colour, depth, object ids, ground-truth safe mask (+ raster).

Pure: returns an RGB uint8 image; the caller writes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

_LABEL_SCALE = 0.6      # cv2 font scale of the panel captions
_SAFE_TINT = np.array([40, 200, 60], dtype=np.float64)      # RGB of "safe" in the overlay
_UNSAFE_TINT = np.array([220, 40, 40], dtype=np.float64)    # RGB of "unsafe"


@dataclass(frozen=True)
class SheetRow:
    """One frame of the sheet."""

    rgb: np.ndarray          # uint8 HxWx3
    depth_m: np.ndarray      # float32 HxW, NaN = hole
    object_id: np.ndarray    # HxW
    safe: np.ndarray         # bool HxW
    title: str = "colour"


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = np.ascontiguousarray(img)
    cv2.putText(out, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, _LABEL_SCALE, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, _LABEL_SCALE, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def depth_panel(depth_m: np.ndarray) -> np.ndarray:
    """Depth as a turbo colour map over its own valid range; holes black."""
    valid = np.isfinite(depth_m)
    if not valid.any():
        return np.zeros((*depth_m.shape, 3), np.uint8)
    lo, hi = float(np.nanmin(depth_m)), float(np.nanmax(depth_m))
    g = np.zeros(depth_m.shape, np.uint8)
    g[valid] = np.clip((depth_m[valid] - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.uint8)
    col = cv2.cvtColor(cv2.applyColorMap(g, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    col[~valid] = 0
    return _label(col, f"depth {lo:.2f}-{hi:.2f} m (black = hole)")


def ids_panel(object_id: np.ndarray) -> np.ndarray:
    """Object ids in stable pseudo-random colours (id * golden ratio hue); 0 black."""
    ids = object_id.astype(np.int64)
    hue = ((ids * 0.618034) % 1.0 * 179).astype(np.uint8)
    hsv = np.stack([hue, np.full_like(hue, 200), np.where(ids > 0, 230, 0).astype(np.uint8)], -1)
    return _label(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), f"object ids ({len(np.unique(ids[ids > 0]))} objects)")


def safe_panel(rgb: np.ndarray, safe: np.ndarray) -> np.ndarray:
    """The colour image tinted green where safe, red where not."""
    tint = np.where(safe[..., None], _SAFE_TINT, _UNSAFE_TINT)
    out = (0.5 * rgb.astype(np.float64) + 0.5 * tint).astype(np.uint8)
    return _label(out, f"ground-truth safe ({100.0 * safe.mean():.1f} %)")


def raster_panel(raster_safe: np.ndarray, raster_usable: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """World-XY raster, north up: safe green, usable-but-too-close grey, unusable dark red."""
    img: np.ndarray = np.zeros((*raster_safe.shape, 3), np.uint8)
    img[raster_usable] = (150, 150, 150)
    img[~raster_usable] = (90, 20, 20)
    img[raster_safe] = (40, 200, 60)
    img = np.flipud(img)
    h, w = shape
    scale = min(h / img.shape[0], w / img.shape[1])
    small = cv2.resize(img, (max(1, int(img.shape[1] * scale)), max(1, int(img.shape[0] * scale))),
                       interpolation=cv2.INTER_NEAREST)
    out = np.zeros((h, w, 3), np.uint8)
    out[:small.shape[0], :small.shape[1]] = small
    return _label(out, "world safe raster (north up)")


def contact_sheet(rows: Sequence[SheetRow], raster_safe: np.ndarray | None = None,
                  raster_usable: np.ndarray | None = None) -> np.ndarray:
    """One row per frame; an optional raster panel at the end."""
    out_rows = []
    for r in rows:
        panels = [_label(r.rgb, r.title), depth_panel(r.depth_m), ids_panel(r.object_id), safe_panel(r.rgb, r.safe)]
        out_rows.append(np.concatenate(panels, axis=1))
    sheet = np.concatenate(out_rows, axis=0)
    if raster_safe is not None and raster_usable is not None:
        h = rows[0].rgb.shape[0]
        panel = raster_panel(raster_safe, raster_usable, (h * len(rows), h * len(rows)))
        sheet = np.concatenate([sheet, panel], axis=1)
    return sheet
