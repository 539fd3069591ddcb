"""Figures of ``slz compare`` (matplotlib, Agg): the paper's Figure 6 layout, PR curves, timing, variants.

Colours (``palette``): scores in viridis as ``images.heatmap_bgr`` (1 = good = light yellow);
SLAM map points white when the mask rejects them, sky blue when kept; the Eq. 10 square of the
site is white outlined in black; masks in the verdict colours (bluish green safe, vermillion
unsafe). Every function writes one PNG atomically and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes

from slzcli.compare_records import Curve, FigureFrame, MethodView, VariantMethod, VariantRow
from slzcli.outputs import palette
from slzcli.outputs.files import atomic_path

METHOD_COLOURS = {"fuzzy": "tab:red", "bayes": "tab:blue", "px4slp": "tab:green"}
MAP_COLOURS = {"depth_variance": "tab:olive", "flatness": "tab:green", "inclination": "tab:purple",
               "steepness": "tab:brown"}
STAGE_COLOURS = {"slam": "tab:gray", "maps": "tab:green", "score": "tab:orange", "mask": "tab:purple",
                 "select": "tab:cyan", "frame": "black"}
DPI = 90
MASK_SAFE_RGB = np.array(palette.rgba01(palette.SAFE)[:3])
MASK_UNSAFE_RGB = np.array(palette.rgba01(palette.UNSAFE)[:3])
KEPT_COLOUR = palette.hex_of(palette.KEPT)


def _colour(method: str) -> str:
    return METHOD_COLOURS.get(method, "tab:orange")


def _save(fig: plt.Figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def figure6(path: Path, frame: FigureFrame, title: str) -> Path:
    """Per method a row: colour image with the mask, the score map, the mask with SLAM points and the site."""
    methods = list(frame.per_method)
    fig, axes = plt.subplots(len(methods), 3, figsize=(12, 3.4 * len(methods)), squeeze=False)
    for row, m in zip(axes, methods, strict=True):
        v = frame.per_method[m]
        mask = v.mask
        tint = np.where(mask[..., None], np.array(palette.SAFE), np.array(palette.UNSAFE))
        row[0].imshow((0.55 * frame.rgb + 0.45 * tint).astype(np.uint8))
        row[0].set_title(f"{m}: mask over the image ({100 * mask.mean():.0f} % safe)", fontsize=9)
        im = row[1].imshow(v.score.astype(np.float32), cmap=palette.COLORMAP, vmin=0.0, vmax=1.0)
        row[1].set_title(f"{m}: score map", fontsize=9)
        fig.colorbar(im, ax=row[1], fraction=0.035, pad=0.02)
        row[2].imshow(np.where(mask[..., None], MASK_SAFE_RGB, MASK_UNSAFE_RGB))
        row[2].set_title(f"{m}: mask, SLAM points, site", fontsize=9)
        for ax in (row[1], row[2]):
            _points(ax, v, mask.shape)
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"{title} - frame {frame.index}", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def _points(ax: Axes, v: MethodView, shape: tuple[int, int]) -> None:
    px = v.projected
    if px is not None and v.kept is not None and len(px):
        h, w = shape
        inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        kept = v.kept & inside
        ax.scatter(px[inside & ~kept, 0], px[inside & ~kept, 1], s=3, c=palette.hex_of(palette.POINT),
                   edgecolors="0.3", linewidths=0.2)
        ax.scatter(px[kept, 0], px[kept, 1], s=5, c=KEPT_COLOUR, linewidths=0)
    corners = v.corners_px
    if corners is not None:
        c = np.asarray(corners)[[0, 1, 3, 2, 0]]  # corners are (+,+), (+,-), (-,+), (-,-): walk the square
        ax.plot(c[:, 0], c[:, 1], "-", color="black", lw=3.2)
        ax.plot(c[:, 0], c[:, 1], "-", color="white", lw=1.6)
    ax.set_xlim(0, shape[1])
    ax.set_ylim(shape[0], 0)


def pr_curves(path: Path, curves: Mapping[str, Curve], aucs: Mapping[str, float | None], title: str) -> Path:
    """Precision against recall of ``score > tau`` (steps, as the area is computed): fused scores bold, maps dashed."""
    fig, ax = plt.subplots(figsize=(6.0, 4.6))
    for name, (precision, recall) in curves.items():
        order = np.lexsort((-precision, recall))
        auc = aucs.get(name)
        label = f"{name.removeprefix('map:')} (AUC {auc:.3f})" if auc is not None else name
        if name.startswith("map:"):
            ax.step(recall[order], precision[order], "--", where="pre", lw=1, color=MAP_COLOURS.get(name[4:], "0.5"),
                    label=label)
        else:
            ax.step(recall[order], precision[order], "-", where="pre", lw=2.2, color=_colour(name), label=label)
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall of truly safe pixels")
    ax.set_ylabel("precision (share of predicted safe that is safe)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    return _save(fig, path)


def timing_bars(path: Path, timings: Mapping[str, Mapping[str, list[float]]], title: str) -> Path:
    """Median time per stage and method, p90 as a whisker, ms per detection frame ("frame" = all stages)."""
    methods = list(timings)
    stages = [s for s in STAGE_COLOURS if any(timings[m].get(s) for m in methods)]
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    width = 0.8 / max(len(methods), 1)
    x = np.arange(len(stages))
    for i, m in enumerate(methods):
        med = [float(np.median(timings[m][s])) if timings[m].get(s) else 0.0 for s in stages]
        p90 = [float(np.percentile(timings[m][s], 90)) if timings[m].get(s) else 0.0 for s in stages]
        err = np.maximum(np.asarray(p90) - np.asarray(med), 0.0)
        ax.bar(x + (i - (len(methods) - 1) / 2) * width, med, width, yerr=[np.zeros_like(err), err],
               color=_colour(m), alpha=0.85, label=m, capsize=3)
    ax.set_xticks(x, stages)
    ax.set_ylabel("ms per detection frame (median, whisker p90)")
    ax.set_title(title, fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def variants_chart(path: Path, rows: Sequence[VariantRow], title: str) -> Path:
    """Per variant: each method's mask precision, recall and PR AUC, and each terrain map's PR AUC."""
    labels = [r.variant for r in rows]
    methods = list(rows[0].methods) if rows else []
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    x = np.arange(len(labels))
    metrics = ("precision", "recall", "pr_auc")
    width = 0.8 / max(len(methods) * len(metrics), 1)
    k = 0
    for m in methods:
        for j, metric in enumerate(metrics):
            vals = [np.nan if (v := _metric(r.methods[m], metric)) is None else v for r in rows]
            axes[0].bar(x + (k - (len(methods) * len(metrics) - 1) / 2) * width, vals, width,
                        color=_colour(m), alpha=(1.0, 0.65, 0.35)[j], label=f"{m} {metric}")
            k += 1
    axes[0].set_xticks(x, labels, rotation=20)
    axes[0].set_ylim(0, 1.05)
    axes[0].set_title("methods: mask precision / recall, score PR AUC", fontsize=10)
    axes[0].legend(fontsize=7, ncol=2)
    maps = list(rows[0].maps) if rows else []
    width = 0.8 / max(len(maps), 1)
    for i, n in enumerate(maps):
        vals = [np.nan if (v := r.maps[n]) is None else v for r in rows]
        axes[1].bar(x + (i - (len(maps) - 1) / 2) * width, vals, width, color=MAP_COLOURS.get(n, "0.5"), label=n)
    axes[1].set_xticks(x, labels, rotation=20)
    axes[1].set_ylim(0, 1.05)
    axes[1].set_title("terrain maps alone: PR AUC against ground truth", fontsize=10)
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def _metric(m: VariantMethod, name: str) -> float | None:
    return {"precision": m.precision, "recall": m.recall, "pr_auc": m.pr_auc}[name]
