"""Figures of `slz land simulate` (matplotlib, Agg): paper Figs. 7-8 style, 3-D path, Monte Carlo histograms."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from slzcli.outputs.files import atomic_path
from slzcli.types import SimResult, Target

COLOURS = ("tab:red", "tab:green", "tab:blue", "tab:orange")


def _save(fig: plt.Figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def image_plane(path: Path, result: SimResult, width: int, height: int, cx: float, cy: float, i: int = 0) -> Path:
    """Fig. 7 style: virtual-image corner traces during IBVS, start circles, goal stars (the last IBVS point)."""
    log = result.log or {}
    ibvs = log["phase"][:, i] == 0
    uv = log["virtual_uv"][ibvs, i] + np.array([cx, cy])
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    if not len(uv):  # the landing ended before its IBVS phase (e.g. a timeout in the approach)
        ax.text(width / 2, height / 2, "no IBVS phase in this landing", ha="center", va="center")
    for k in range(uv.shape[1] if len(uv) else 0):
        ax.plot(uv[:, k, 0], uv[:, k, 1], color=COLOURS[k], lw=1.2, label=f"corner {k}")
        ax.plot(uv[0, k, 0], uv[0, k, 1], "o", mfc="none", color=COLOURS[k], ms=9)
        ax.plot(uv[-1, k, 0], uv[-1, k, 1], "*", color=COLOURS[k], ms=12)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title("Virtual image: corners (o start, * end of IBVS)")
    if len(uv):
        ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def feature_error(path: Path, result: SimResult, i: int = 0) -> Path:
    """Fig. 8 style: e_q components (estimated) and the true pixel-equivalent error vs time."""
    log = result.log or {}
    t = log["t"][:, i]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for k, name in enumerate(("e_qx", "e_qy", "e_qz")):
        ax1.plot(t, log["e_q"][:, i, k], label=name)
    ax1.plot(t, np.degrees(log["yaw_err_true"][:, i]) / 100, label="e_psi (deg/100)", ls="--")
    ax1.set_ylabel("feature error")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ibvs = log["phase"][:, i] == 0   # after the switch the goal moves down: the hover error no longer applies
    ax2.semilogy(t[ibvs], np.maximum(log["e_px_true"][ibvs, i], 1e-3), label="IBVS phase")
    ax2.axhline(1.0, color="k", ls=":", lw=1)
    sw = result.switch_time_s[i]
    for ax in (ax1, ax2):
        if np.isfinite(sw):
            ax.axvline(sw, color="grey", ls="--", lw=1)
    ax2.set_ylabel("true feature error (px)")
    ax2.set_xlabel("t (s)")
    ax2.grid(alpha=0.3)
    return _save(fig, path)


def trajectory_3d(path: Path, result: SimResult, target: Target, i: int = 0) -> Path:
    """The flown path in the world frame with the landing square."""
    log = result.log or {}
    p = log["p_world"][:, i]
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=1.5)
    ax.scatter(*p[0], marker="o", s=40, label="start")
    ax.scatter(*p[-1], marker="v", s=40, label="end")
    c = target.corners_world[[0, 1, 3, 2, 0]]
    ax.plot(c[:, 0], c[:, 1], c[:, 2], "k-", lw=1.5, label="landing square")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def montecarlo_histograms(path: Path, result: SimResult) -> Path:
    """Histograms of landing time, feature error at the hover -> touch-down switch and touch-down error."""
    fields = (("landing_time_s", "landing time (s)"), ("final_feature_error_px", "feature error at the switch (px)"),
              ("touchdown_error_m", "touch-down error (m)"))
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (name, label) in zip(axes, fields, strict=True):
        vals = getattr(result, name)
        vals = vals[np.isfinite(vals)]
        if vals.size:
            ax.hist(vals, bins=30, color="tab:blue", alpha=0.8)
        ax.set_xlabel(label)
        ax.set_title(f"n = {vals.size} of {len(result.reason)}", fontsize=9)
    axes[0].set_ylabel("runs")
    return _save(fig, path)
