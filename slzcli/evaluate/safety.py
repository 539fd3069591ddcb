"""Mask quality against ground truth: precision, recall and IoU of the "safe" class.

Precision is the number that matters for landing (a pixel we call safe that is not is a
crash risk); recall says how much of the truly safe ground we find. Counts are kept so
that per-frame results add up to an exact overall figure (micro-average), not an average
of ratios.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from slzcli.geometry import transform_points
from slzcli.synth.groundtruth import SafetyRaster


@dataclass(frozen=True)
class MaskCounts:
    tp: int
    fp: int
    fn: int
    tn: int

    def __add__(self, other: MaskCounts) -> MaskCounts:
        return MaskCounts(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    @property
    def precision(self) -> float | None:
        """None when nothing was predicted safe (undefined, not perfect)."""
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else None

    @property
    def recall(self) -> float | None:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else None

    @property
    def iou(self) -> float | None:
        union = self.tp + self.fp + self.fn
        return self.tp / union if union else None

    def as_dict(self) -> dict[str, float | int | None]:
        return {"precision": self.precision, "recall": self.recall, "iou": self.iou,
                "tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn}


def mask_counts(predicted: np.ndarray, truth: np.ndarray, known: np.ndarray | None = None) -> MaskCounts:
    """Confusion counts of ``predicted`` vs ``truth`` (bool HxW), over ``known`` pixels only."""
    if predicted.shape != truth.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {truth.shape}")
    p, t = predicted.astype(bool), truth.astype(bool)
    if known is not None:
        p, t = p[known], t[known]
    tp = int(np.count_nonzero(p & t))
    fp = int(np.count_nonzero(p & ~t))
    fn = int(np.count_nonzero(~p & t))
    return MaskCounts(tp, fp, fn, int(p.size) - tp - fp - fn)


def total(counts: Iterable[MaskCounts]) -> MaskCounts:
    out = MaskCounts(0, 0, 0, 0)
    for c in counts:
        out = out + c
    return out


def precision_recall_curve(score: np.ndarray, truth: np.ndarray, thresholds: np.ndarray,
                           known: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Precision and recall of ``score > tau`` for every tau, vectorised via a histogram of scores."""
    s, t = score.astype(np.float64), truth.astype(bool)
    if known is not None:
        s, t = s[known], t[known]
    order = np.sort(thresholds)
    pos = np.sort(s[t])
    neg = np.sort(s[~t])
    tp = pos.size - np.searchsorted(pos, order, side="right")
    fp = neg.size - np.searchsorted(neg, order, side="right")
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = np.where(tp + fp > 0, tp / np.maximum(tp + fp, 1), 1.0)
        recall = tp / max(pos.size, 1)
    inv = np.argsort(np.argsort(thresholds))
    return precision[inv], recall[inv]


@dataclass(frozen=True)
class SiteTruth:
    """A chosen site checked against the ground-truth world raster."""

    safe: bool                       # the site's cell is one where the UAV footprint plus margin is clear
    clearance_m: float               # distance from the site to the nearest hazard (non-usable) cell
    to_best_centre_m: float          # distance to the centre of the largest truly safe area in view
    true_xy: tuple[float, float]     # the site in the ground-truth world

    def as_dict(self) -> dict[str, object]:
        return {"safe": self.safe, "clearance_m": self.clearance_m, "to_best_centre_m": self.to_best_centre_m,
                "true_xy": list(self.true_xy)}


def site_truth(raster: SafetyRaster, xy: tuple[float, float], visible: np.ndarray | None = None) -> SiteTruth:
    """Check a world-XY site against a SafetyRaster (``slzcli.synth.groundtruth``).

    The "centre" of the largest safe area is its point farthest from the area's boundary
    (the distance-transform maximum), a centre that is inside the area whatever its shape.
    ``visible`` (bool, raster shape) limits that area to what the camera saw: a larger safe
    area out of view is no fair target for a detector.
    """
    import cv2

    x, y = float(xy[0]), float(xy[1])
    safe = bool(raster.safe_at(np.array([x]), np.array([y]))[0])
    res = raster.resolution_m
    hazard_dist = cv2.distanceTransform(raster.usable.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
    r, c, inside = raster.cells(np.array([x]), np.array([y]))
    clearance = float(hazard_dist[r[0], c[0]]) if inside[0] else 0.0
    candidates = raster.safe if visible is None else raster.safe & visible
    n, labels = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
    best = float("nan")
    if n > 1:
        sizes = np.bincount(labels.ravel())[1:]
        largest = labels == 1 + int(np.argmax(sizes))
        inner = cv2.distanceTransform(largest.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        br, bc = np.unravel_index(int(np.argmax(inner)), inner.shape)
        cx = raster.origin_xy[0] + (bc + 0.5) * res
        cy = raster.origin_xy[1] + (br + 0.5) * res
        best = float(np.hypot(x - cx, y - cy))
    return SiteTruth(safe, clearance, best, (x, y))


def visible_cells(raster: SafetyRaster, T_world_camera: np.ndarray, K: np.ndarray,
                  shape: tuple[int, int]) -> np.ndarray:
    """Raster cells whose surface point projects into the image of a camera at ``T_world_camera``."""
    rows, cols = raster.safe.shape
    res = raster.resolution_m
    x = raster.origin_xy[0] + (np.arange(cols) + 0.5) * res
    y = raster.origin_xy[1] + (np.arange(rows) + 0.5) * res
    xx, yy = np.meshgrid(x, y)
    zz = np.nan_to_num(raster.height_m, nan=0.0)
    p = transform_points(np.linalg.inv(T_world_camera), np.stack([xx, yy, zz], axis=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * p[..., 0] / p[..., 2] + K[0, 2]
        v = K[1, 1] * p[..., 1] / p[..., 2] + K[1, 2]
    h, w = shape
    return (p[..., 2] > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)

