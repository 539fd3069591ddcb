"""Maps as pictures: heat-map PNGs and overlays on the colour image.

Convention: maps are in [0, 1] with 1 = good for landing; the heat map shows good as
warm (red/yellow) by default. ``reverse=True`` gives the paper's figures' convention,
where the colour scale runs the other way. NaN / invalid pixels are drawn black.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from slzcli.errors import OutputError
from slzcli.outputs.files import atomic_path

SAFE_BGR = np.array([60, 200, 60], np.uint8)
UNSAFE_BGR = np.array([40, 40, 220], np.uint8)


def heatmap_bgr(values: np.ndarray, *, reverse: bool = False, valid: np.ndarray | None = None) -> np.ndarray:
    """A float map in [0, 1] -> BGR uint8 through the JET colour map."""
    v = np.nan_to_num(values.astype(np.float32), nan=0.0)
    v = np.clip(1.0 - v if reverse else v, 0.0, 1.0)
    img = cv2.applyColorMap((v * 255.0 + 0.5).astype(np.uint8), cv2.COLORMAP_JET)
    bad = ~np.isfinite(values) if valid is None else ~valid
    img[bad] = 0
    return img


def overlay_bgr(rgb: np.ndarray, mask: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    """The colour image with safe pixels tinted green and the rest red (blended in uint8, rounded)."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    tint = np.where(mask[..., None], SAFE_BGR, UNSAFE_BGR)
    return cv2.addWeighted(bgr, 1.0 - alpha, tint, alpha, 0.0)


def mask_png(mask: np.ndarray) -> np.ndarray:
    return mask.astype(np.uint8) * 255


# zlib level of every PNG slz writes: 1 encodes a 640x480 heat map in ~9 ms against ~13 ms at OpenCV's default 3,
# for ~20% more bytes (benchmarks/writes.py); PNG is lossless at every level, the pixels are the same.
PNG_LEVEL = 1
# zlib strategy for photo-like images (the overlay: a tinted camera image): run-length matching only encodes a
# 640x480 overlay in ~0.6x the time of the default strategy at the same level, for ~1% fewer bytes
# (benchmarks/writes.py); lossless like every PNG.
PHOTO_STRATEGY = cv2.IMWRITE_PNG_STRATEGY_RLE
DEFAULT_STRATEGY = cv2.IMWRITE_PNG_STRATEGY_DEFAULT


def write_png(path: Path, image: np.ndarray, strategy: int = DEFAULT_STRATEGY) -> None:
    """Encode in memory, then write atomically (cv2.imwrite cannot target a temp name safely)."""
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL, cv2.IMWRITE_PNG_STRATEGY, strategy])
    if not ok:
        raise OutputError(path, "PNG encoding failed")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def site_overlay_bgr(rgb: np.ndarray, mask: np.ndarray, projected: np.ndarray | None = None,
                     kept: np.ndarray | None = None, chosen: np.ndarray | None = None,
                     corners_px: np.ndarray | None = None) -> np.ndarray:
    """The paper's Figure 6 in one picture: mask tint, every SLAM point (white), the ones under
    the mask (blue), the chosen cluster (green) and the Eq. 10 square (red)."""
    img = overlay_bgr(rgb, mask)
    h, w = mask.shape
    if projected is not None and len(projected):
        ok = np.all(np.isfinite(projected), axis=1) & (projected[:, 0] >= 0) & (projected[:, 0] < w) \
            & (projected[:, 1] >= 0) & (projected[:, 1] < h)
        layers = [(ok, (255, 255, 255), 1)]
        if kept is not None:
            layers.append((ok & kept, (255, 120, 30), 2))
        if chosen is not None:
            layers.append((ok & chosen, (40, 220, 40), 3))
        for sel, colour, radius in layers:
            dots = np.zeros((h, w), np.uint8)
            pts = np.round(projected[sel]).astype(np.int64)
            dots[np.clip(pts[:, 1], 0, h - 1), np.clip(pts[:, 0], 0, w - 1)] = 1
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
            img[cv2.dilate(dots, disc).astype(bool)] = colour
    if corners_px is not None and np.all(np.isfinite(corners_px)):
        quad = np.round(corners_px[[0, 1, 3, 2]]).astype(np.int32)  # ++, +-, --, -+ around the square
        cv2.polylines(img, [quad], True, (0, 0, 255), 2, lineType=cv2.LINE_AA)
    return img
