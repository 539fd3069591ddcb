"""Maps as pictures: heat-map PNGs and overlays on the colour image.

Convention: maps are in [0, 1] with 1 = good for landing; the heat map (viridis, ``palette``) shows
good as light yellow and bad as dark blue by default. ``reverse=True`` runs the scale the other way
(the paper's figures' convention). NaN / invalid pixels are drawn black. Verdict colours (safe,
unsafe, no depth) are ``palette``'s, the same in every picture.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from slzcli.errors import OutputError
from slzcli.outputs import palette
from slzcli.outputs.files import atomic_path

SAFE_BGR = np.array(palette.bgr(palette.SAFE), np.uint8)
UNSAFE_BGR = np.array(palette.bgr(palette.UNSAFE), np.uint8)
UNDECIDED_BGR = np.array(palette.bgr(palette.UNDECIDED), np.uint8)


def heatmap_bgr(values: np.ndarray, *, reverse: bool = False, valid: np.ndarray | None = None) -> np.ndarray:
    """A float map in [0, 1] -> BGR uint8 through the viridis colour map (NaN as 0 before ``reverse``).

    In place on one float32 buffer: fmax/fmin clip and turn NaN into 0 in two passes (with nan_to_num, then
    clip, and a boolean index for the black pixels a heat map took ~2x as long, the same bytes)."""
    with np.errstate(invalid="ignore"):
        v = np.fmax(np.asarray(values), np.float32(0.0), dtype=np.float32)
        np.fmin(v, np.float32(1.0), out=v)
        if reverse:
            np.subtract(np.float32(1.0), v, out=v)
        v *= np.float32(255.0)
        v += np.float32(0.5)
    img = cv2.applyColorMap(v.astype(np.uint8), palette.CV2_COLORMAP)
    bad = ~np.isfinite(values) if valid is None else ~valid
    img.reshape(-1, 3)[np.flatnonzero(bad)] = 0  # ~3x faster than img[bad] = 0 (a (h, w) boolean index)
    return img


# The colour bar beside a per-frame heat map (frames/NNNNNN/<map>.png at --outputs all): display only, no result
# depends on these. Width in px, the gradient column inside it, text scale of cv2.FONT_HERSHEY_SIMPLEX.
BAR_WIDTH_PX = 64
BAR_GRADIENT_PX = 16
BAR_MARGIN_PX = 6
BAR_TEXT_SCALE = 0.4
LEGEND_WIDTH_PX = 88


def _label(img: np.ndarray, text: str, x: int, y: int) -> None:
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, BAR_TEXT_SCALE, (255, 255, 255), 1, cv2.LINE_AA)


def with_colour_bar(img: np.ndarray, *, reverse: bool = False, low: str = "0 bad", high: str = "1 good") -> np.ndarray:
    """A heat map (``heatmap_bgr``) with its colour bar to the right: the viridis scale from 0 (bottom) to 1 (top),
    labelled; ``reverse`` as in ``heatmap_bgr`` (the bar shows the colours the map was drawn with)."""
    h = img.shape[0]
    strip = np.zeros((h, BAR_WIDTH_PX, 3), np.uint8)
    top, bottom = BAR_MARGIN_PX + 8, h - BAR_MARGIN_PX - 8
    values = np.linspace(1.0, 0.0, max(bottom - top, 2), dtype=np.float32)[:, None]  # top = 1
    column = heatmap_bgr(np.repeat(values, BAR_GRADIENT_PX, axis=1), reverse=reverse)
    strip[top:top + len(values), BAR_MARGIN_PX:BAR_MARGIN_PX + BAR_GRADIENT_PX] = column
    x = BAR_MARGIN_PX + BAR_GRADIENT_PX + 3
    _label(strip, high.split()[0], x, top + 4)
    _label(strip, " ".join(high.split()[1:]), x, top + 16)
    _label(strip, low.split()[0], x, bottom)
    _label(strip, " ".join(low.split()[1:]), x, bottom - 12)
    return np.hstack([img, strip])


def with_mask_legend(mask_img: np.ndarray) -> np.ndarray:
    """mask.png (255 safe, 0 unsafe) with a legend strip to the right, still one grey channel."""
    h = mask_img.shape[0]
    strip = np.full((h, LEGEND_WIDTH_PX), 64, np.uint8)
    for row, (value, text) in enumerate(((255, "safe"), (0, "unsafe"))):
        y = BAR_MARGIN_PX + 20 * row
        strip[y:y + 12, BAR_MARGIN_PX:BAR_MARGIN_PX + 12] = value
        cv2.rectangle(strip, (BAR_MARGIN_PX, y), (BAR_MARGIN_PX + 11, y + 11), 160, 1)
        cv2.putText(strip, text, (BAR_MARGIN_PX + 18, y + 10), cv2.FONT_HERSHEY_SIMPLEX, BAR_TEXT_SCALE, 255, 1,
                    cv2.LINE_AA)
    return np.hstack([mask_img, strip])


def verdict_bgr(mask: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The mask in the verdict colours (safe, unsafe, no depth) with their legend to the right."""
    img = np.empty((*mask.shape, 3), np.uint8)
    img[...] = UNSAFE_BGR
    img[mask] = SAFE_BGR
    img[~valid] = UNDECIDED_BGR
    h = img.shape[0]
    strip = np.full((h, LEGEND_WIDTH_PX, 3), 64, np.uint8)
    for row, (text, rgb) in enumerate(palette.VERDICTS):
        y = BAR_MARGIN_PX + 20 * row
        cv2.rectangle(strip, (BAR_MARGIN_PX, y), (BAR_MARGIN_PX + 11, y + 11), palette.bgr(rgb), -1)
        _label(strip, text, BAR_MARGIN_PX + 18, y + 10)
    return np.hstack([img, strip])


def overlay_bgr(rgb: np.ndarray, mask: np.ndarray, alpha: float = 0.45,
                undecided: np.ndarray | None = None) -> np.ndarray:
    """The colour image tinted by verdict: safe, unsafe, and undecided (``undecided``: pixels without
    depth or beyond the depth the frame's noise lets it vouch for), in ``palette``'s colours (blended in
    uint8, rounded). Undecided wins: a mask value there is not a verdict slz stands by."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    # One plane per channel then merged: the same uint8 tint as np.where(mask[..., None], SAFE, UNSAFE) in
    # ~1 ms instead of ~10 (a (h, w, 3) where broadcasts to int64 first).
    planes = [np.where(mask, safe, unsafe) for safe, unsafe in zip(SAFE_BGR, UNSAFE_BGR, strict=True)]
    if undecided is not None:
        planes = [np.where(undecided, grey, p) for grey, p in zip(UNDECIDED_BGR, planes, strict=True)]
    return cv2.addWeighted(bgr, 1.0 - alpha, cv2.merge(planes), alpha, 0.0)


def mask_png(mask: np.ndarray) -> np.ndarray:
    return mask.astype(np.uint8) * 255


# zlib level of every PNG slz writes: 1 encodes a 640x480 heat map in ~9 ms against ~13 ms at OpenCV's default 3,
# for ~20% more bytes (benchmarks/writes.py); PNG is lossless at every level, the pixels are the same.
PNG_LEVEL = 1
# The heat maps and the mask (--outputs all): run-length matching after the UP row filter encodes the five heat maps
# of a 640x480 frame in 45-60 ms against 90-120 ms with zlib's default matching and PNG's adaptive filters, and in
# ~3 % fewer bytes (smooth colour maps: a row is mostly the one above it; benchmarks/writes.py).
DEFAULT_PNG = (cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
               cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP)
# Photo-like images (the overlay: a tinted camera image) are written uncompressed (zlib level 0, no row filter):
# ~1.4 ms for a 640x480 overlay against ~23 ms at level 1 with run-length matching (the writer before) and ~14 ms
# at level 1 with the SUB filter, for 0.92 MB against 0.60 MB on a clear_field frame (benchmarks/writes.py) and
# against 0.36 MB on the real RealSense frames of the test data (an indoor floor, less noise): +5-9 % of a frame
# folder (maps.npz holds ~5.5 MB), for ~20 ms of the ~50 a detection frame may take to write at 10 frames/s.
# A valid PNG like any other, lossless, every reader opens it.
PHOTO_PNG = (cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE)


def write_png(path: Path, image: np.ndarray, params: tuple[int, ...] | None = None) -> None:
    """Encode in memory (``params``: ``DEFAULT_PNG`` when None, or ``PHOTO_PNG``), then write atomically
    (cv2.imwrite cannot target a temp name safely)."""
    ok, buf = cv2.imencode(".png", image, list(DEFAULT_PNG if params is None else params))
    if not ok:
        raise OutputError(path, "PNG encoding failed")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def site_overlay_bgr(rgb: np.ndarray, mask: np.ndarray, projected: np.ndarray | None = None,
                     kept: np.ndarray | None = None, chosen: np.ndarray | None = None,
                     corners_px: np.ndarray | None = None, undecided: np.ndarray | None = None,
                     label: str | None = None, px_per_m: float | None = None) -> np.ndarray:
    """The paper's Figure 6 in one picture: verdict tint, every SLAM point (white), the ones under
    the mask (sky blue), the chosen cluster (yellow) and the Eq. 10 square (an outline: the verdict
    under it stays visible). With ``label``: the frame label, the legend and (``px_per_m``, pixels
    per metre on the ground) a scale bar, drawn in the corners."""
    img = overlay_bgr(rgb, mask, undecided=undecided)
    h, w = mask.shape
    if projected is not None and len(projected):
        ok = np.all(np.isfinite(projected), axis=1) & (projected[:, 0] >= 0) & (projected[:, 0] < w) \
            & (projected[:, 1] >= 0) & (projected[:, 1] < h)
        layers = [(ok, palette.bgr(palette.POINT), 1)]
        if kept is not None:
            layers.append((ok & kept, palette.bgr(palette.KEPT), 2))
        if chosen is not None:
            layers.append((ok & chosen, palette.bgr(palette.CHOSEN), 3))
        for sel, colour, radius in layers:
            dots = np.zeros((h, w), np.uint8)
            pts = np.round(projected[sel]).astype(np.int64)
            dots[np.clip(pts[:, 1], 0, h - 1), np.clip(pts[:, 0], 0, w - 1)] = 1
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
            img.reshape(-1, 3)[np.flatnonzero(cv2.dilate(dots, disc))] = colour  # ~2x a boolean (h, w) index
    if corners_px is not None and np.all(np.isfinite(corners_px)):
        quad = np.round(corners_px[[0, 1, 3, 2]]).astype(np.int32)  # ++, +-, --, -+ around the square
        cv2.polylines(img, [quad], True, palette.bgr(palette.HALO), 3, lineType=cv2.LINE_AA)
        cv2.polylines(img, [quad], True, palette.bgr(palette.SITE), 1, lineType=cv2.LINE_AA)
    if label is not None:
        annotate(img, label, px_per_m)
    return img


# The overlay's annotations (display only): text scale and line, box padding, the scale bar's share of the width.
NOTE_SCALE = 0.42
NOTE_LINE_PX = 15
NOTE_PAD_PX = 5
SCALE_BAR_FRACTION = 0.2


def _box(img: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> None:
    """A dark backing box for text (half-transparent: what is under it still shows)."""
    h, w = img.shape[:2]
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 > x0 and y1 > y0:
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] // 2


def _text(img: np.ndarray, text: str, x: int, y: int) -> None:
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, NOTE_SCALE, (255, 255, 255), 1, cv2.LINE_AA)


def nice_length_m(raw: float) -> float:
    """1, 2 or 5 times a power of ten, at most ``raw`` (a scale bar's length)."""
    p = 10.0 ** np.floor(np.log10(max(raw, 1e-9)))
    return float(max(k * p for k in (1, 2, 5) if k * p <= raw))


def annotate(img: np.ndarray, label: str, px_per_m: float | None) -> None:
    """Frame label (top left), legend of the verdict colours and marks (bottom left), scale bar (bottom right)."""
    h, w = img.shape[:2]
    (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, NOTE_SCALE, 1)
    _box(img, 0, 0, tw + 2 * NOTE_PAD_PX, NOTE_LINE_PX + NOTE_PAD_PX)
    _text(img, label, NOTE_PAD_PX, NOTE_LINE_PX)
    entries = [*palette.VERDICTS, ("SLAM point", palette.POINT), ("under mask", palette.KEPT),
               ("chosen cluster", palette.CHOSEN), ("site square", palette.SITE)]
    top = h - NOTE_LINE_PX * len(entries) - NOTE_PAD_PX
    _box(img, 0, top - NOTE_PAD_PX, 118, h)
    for i, (name, rgb) in enumerate(entries):
        y = top + i * NOTE_LINE_PX
        if name == "site square":
            cv2.rectangle(img, (NOTE_PAD_PX, y + 1), (NOTE_PAD_PX + 10, y + 11), palette.bgr(palette.SITE), 1)
        else:
            cv2.rectangle(img, (NOTE_PAD_PX, y + 1), (NOTE_PAD_PX + 10, y + 11), palette.bgr(rgb), -1)
        _text(img, name, NOTE_PAD_PX + 16, y + 11)
    if px_per_m is None or not np.isfinite(px_per_m) or px_per_m <= 0:
        return
    metres = nice_length_m(SCALE_BAR_FRACTION * w / px_per_m)
    length = round(metres * px_per_m)
    x1, y = w - NOTE_PAD_PX - 4, h - NOTE_PAD_PX - 6
    text = f"{metres:g} m at the median depth"
    (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, NOTE_SCALE, 1)
    _box(img, min(x1 - length, x1 - tw) - 2 * NOTE_PAD_PX, y - NOTE_LINE_PX - 2 * NOTE_PAD_PX, w, h)
    cv2.line(img, (x1 - length, y), (x1, y), (255, 255, 255), 2)
    for x in (x1 - length, x1):
        cv2.line(img, (x, y - 3), (x, y + 3), (255, 255, 255), 2)
    _text(img, text, x1 - tw, y - 10)
