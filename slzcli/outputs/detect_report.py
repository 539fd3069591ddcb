"""report.html of a ``slz detect`` run folder: one static page to read a run without a viewer.

Sections: the result (site or why not), the paper's Figure 5 panel for one frame (the four
terrain maps, the score and the mask, the slope and the overlay, with colour bars and units),
the trajectory from above with the sites, the table of every site found, each detection's
overlay, the stage times. Built at the end of the run from what the run already holds or has
written (the RunResult, the site log, the pose log, frames/NNNNNN/maps.npz and overlay.png):
only two figures are drawn (the panel for the committed site's frame, or the last detection
frame without a site, and the trajectory); overlays are linked, not copied. At
``--outputs summary`` there are no frame files: the page says so and shows the rest.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from slzcli.outputs.files import write_text
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import PoseLog
from slzcli.types import RunResult

DPI = 80   # figures are for a screen; the values are in maps.npz
MAP_TITLES = {"depth_variance": "depth variance", "flatness": "flatness", "inclination": "inclination",
              "steepness": "steepness"}
UNITLESS = "map value (dimensionless), 1 = good"
SECTIONS = ("result", "figure5", "trajectory", "sites", "detections", "timings")
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1200px;color:#222}
h1{font-size:22px;margin-bottom:4px} h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
p.note{color:#555;font-size:13px;max-width:950px}
table{border-collapse:collapse;font-size:12.5px;margin:8px 0}
td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}
th{background:#f1f1f1} tr.committed td{background:#e5f0ff;font-weight:600} td.l{text-align:left}
img{max-width:100%;border:1px solid #ddd} .grid{display:flex;flex-wrap:wrap;gap:8px}
.grid figure{margin:0;width:236px;font-size:12px} .grid img{width:236px}
"""


def write_detect_report(run_dir: Path, result: RunResult, sites: SiteLog, trajectory: PoseLog, level: str) -> Path:
    """report.html in ``run_dir`` (the temporary run folder: links are relative, so they hold after the rename)."""
    run_dir = Path(run_dir)
    s, landing, committed = result.summary, result.landing, result.committed
    detection_frames = _detection_frames(run_dir)
    panel_frame = committed["frame"].index if committed is not None else \
        (detection_frames[-1] if detection_frames else None)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>slz detect: "
             f"{html.escape(Path(s['source']).name)}</title><style>{CSS}</style></head><body>",
             f"<h1>slz detect: {html.escape(Path(s['source']).name)}</h1>",
             _result(s, landing),
             _figure5(run_dir, panel_frame, committed is not None and committed["frame"].index == panel_frame, level),
             _trajectory(trajectory, sites, committed, result.primary_segment),
             _site_table(sites, committed),
             _detections(run_dir, detection_frames, sites, committed, level),
             _timings(s),
             "</body></html>"]
    path = run_dir / "report.html"
    write_text(path, "\n".join(p for p in parts if p))
    return path


# ----------------------------------------------------------------------------- sections
def _result(s: dict[str, Any], landing: dict[str, Any]) -> str:
    if landing["status"] == "site":
        site = landing["site"]
        x, y, z = site["center_world"]
        sup = site["support"]
        acc = site["acceptance"]
        what = (f"<b>Landing site</b> at ({x:.2f}, {y:.2f}, {z:.2f}) m, score {site['score']:.2f}, confirmed by "
                f"{sup['detections_agreeing']} of {sup['detections_with_site']} detections with a site; acceptance "
                f"test {'passed' if acc['passed'] else 'NOT passed: ' + html.escape(str(acc['reason']))}, "
                f"tilt {acc['tilt_deg']:.1f} deg.")
        gt = site.get("ground_truth")
        if gt:
            what += f" Ground truth: {'safe' if gt.get('safe') else 'NOT safe'}."
    else:
        what = f"<b>No safe site</b>: {html.escape(str(landing.get('reason')))}"
    return (f"<h2 id=result>Result</h2><p>{what}</p><p class=note>{html.escape(s['source'])}: {s['frames']} frames, "
            f"{s['detections']} detection frames, method {html.escape(s['method'])}, SLAM "
            f"{html.escape(s['slam_backend'])}, outputs {html.escape(str(s.get('outputs')))}. Positions are in "
            f"{html.escape(landing['world_frame'])} (metres, z up). Files: <a href=landing.json>landing.json</a>, "
            "<a href=run.json>run.json</a>, <a href=sites.csv>sites.csv</a>, <a href=points.ply>points.ply</a>, "
            "<a href=trajectory.tum>trajectory.tum</a>.</p>")


def _figure5(run_dir: Path, index: int | None, is_site: bool, level: str) -> str:
    head = "<h2 id=figure5>Terrain maps, score and mask (the paper's Figure 5)</h2>"
    folder = None if index is None else run_dir / "frames" / f"{index:06d}"
    if folder is None or not (folder / "maps.npz").is_file():
        why = "no detection frame" if index is None else \
            f"frame folders are not written at --outputs {html.escape(level)}"
        return head + f"<p class=note>Not drawn: {why}.</p>"
    with np.load(folder / "maps.npz") as z:
        arrays = {k: np.asarray(z[k], np.float32) if z[k].dtype != bool else z[k] for k in z.files}
    overlay = _read_rgb(folder / "overlay.png")
    fig, axes = plt.subplots(2, 4, figsize=(16, 6.4))
    valid = arrays.get("valid")
    for ax, name in zip(axes[0], MAP_TITLES, strict=True):
        _heat(fig, ax, _hide(arrays[name], valid), MAP_TITLES[name], UNITLESS, 0.0, 1.0)
    _heat(fig, axes[1][0], _hide(arrays["score"], valid), "fused score", "score (dimensionless), 1 = safe", 0.0, 1.0)
    mask = arrays["mask"].astype(float)
    im = axes[1][1].imshow(mask, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    cb = fig.colorbar(im, ax=axes[1][1], fraction=0.035, pad=0.02, ticks=[0, 1])
    cb.ax.set_yticklabels(["unsafe", "safe"])
    axes[1][1].set_title(f"landing mask ({100 * float(np.mean(mask)):.0f} % safe)", fontsize=10)
    slope = arrays.get("slope_deg")
    if slope is not None:
        finite = slope[np.isfinite(slope)]
        top = float(np.percentile(finite, 99)) if finite.size else 1.0
        _heat(fig, axes[1][2], slope, "surface slope", "deg from level", 0.0, max(top, 1.0), cmap="viridis")
    if overlay is not None:
        axes[1][3].imshow(overlay)
        axes[1][3].set_title("mask, SLAM points, site (overlay.png)", fontsize=10)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
        if not ax.images:
            ax.set_axis_off()
    fig.suptitle(f"frame {index}" + (" (the committed site's)" if is_site else " (the last detection frame)"),
                 fontsize=12)
    fig.tight_layout()
    return (head + "<p class=note>Maps in [0, 1] with 1 = good for landing (METHOD.md 2.3); black = no depth. "
            f"Values: <a href='frames/{index:06d}/maps.npz'>maps.npz</a>.</p>" + _png(fig, f"Figure 5, frame {index}"))


def _trajectory(log: PoseLog, sites: SiteLog, committed: dict[str, Any] | None, segment: int | None) -> str:
    head = "<h2 id=trajectory>Trajectory from above</h2>"
    poses = [(p, k) for p, k in zip(log.poses(), log.segments(), strict=True) if p is not None]
    if segment is not None:
        poses = [(p, k) for p, k in poses if k == segment]
    if not poses:
        return head + "<p class=note>No frame was tracked: no trajectory.</p>"
    xyz = np.array([p[:3, 3] for p, _ in poses])
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    ax.plot(xyz[:, 0], xyz[:, 1], "-", color="0.3", lw=1.2, label="camera")
    ax.plot(xyz[0, 0], xyz[0, 1], "o", color="tab:green", label="first frame")
    found = [e for e in sites.sites if segment is None or e["segment"] == segment]
    if found:
        c = np.array([e["site"].center_world for e in found])
        ok = np.array([e["site"].accepted for e in found])
        ax.plot(c[ok, 0], c[ok, 1], ".", color="tab:blue", ms=7, label="site of a detection (accepted)")
        ax.plot(c[~ok, 0], c[~ok, 1], "x", color="tab:orange", ms=6, label="site of a detection (not accepted)")
    if committed is not None:
        sq = np.asarray(committed["site"].corners_world)[[0, 1, 3, 2, 0]]
        ax.fill(sq[:, 0], sq[:, 1], color="tab:red", alpha=0.35, label="committed site (Eq. 10 square)")
        ax.plot(sq[:, 0], sq[:, 1], "-", color="tab:red", lw=1.5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    note = f" (SLAM map segment {segment})" if segment is not None else ""
    return head + f"<p class=note>Camera positions and sites in the run's world frame{note}, top view.</p>" + \
        _png(fig, "trajectory")


def _site_table(sites: SiteLog, committed: dict[str, Any] | None) -> str:
    head = "<h2 id=sites>Sites found</h2>"
    if not sites.sites:
        return head + "<p class=note>No detection frame gave a site.</p>"
    cols = ("frame", "map", "x m", "y m", "z m", "score", "accepted", "reason", "tilt deg", "edge m",
            "normal var", "extent m", "points")
    chosen = None if committed is None else committed["id"]
    rows = []
    for e in sites.sites:
        st = e["site"]
        x, y, z = st.center_world
        cells = [str(e["frame"].index), str(e["segment"]), f"{x:.2f}", f"{y:.2f}", f"{z:.2f}", f"{st.score:.2f}",
                 "yes" if st.accepted else "no", st.acceptance_reason or "", f"{st.tilt_deg:.1f}",
                 "n/a" if st.edge_clearance_m is None else f"{st.edge_clearance_m:.2f}",
                 f"{st.normal_variance:.2e}", f"{st.extent_m[0]:.2f} x {st.extent_m[1]:.2f}", str(st.cluster_points)]
        tds = "".join(f"<td{' class=l' if i == 7 else ''}>{html.escape(c)}</td>" for i, c in enumerate(cells))
        rows.append(f"<tr{' class=committed' if e['id'] == chosen else ''}>{tds}</tr>")
    th = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    return (head + "<p class=note>One row per detection frame that gave a site; the committed site (landing.json) "
            "is highlighted. Every candidate cluster is in sites.csv.</p>"
            f"<table><tr>{th}</tr>{''.join(rows)}</table>")


def _detections(run_dir: Path, frames: list[int], sites: SiteLog, committed: dict[str, Any] | None,
                level: str) -> str:
    head = "<h2 id=detections>Detections</h2>"
    if not frames:
        return head + f"<p class=note>No frame folders at --outputs {html.escape(level)}.</p>"
    by_frame = {e["frame"].index: e["site"] for e in sites.sites}
    site_frame = None if committed is None else committed["frame"].index
    figs = []
    for i in frames:
        link = f"frames/{i:06d}/overlay.png"
        st = by_frame.get(i)
        what = "no site" if st is None else f"site {st.score:.2f}" + ("" if st.accepted else " (not accepted)")
        mark = " <b>committed</b>" if i == site_frame else ""
        figs.append(f"<figure><a href='{link}'><img loading=lazy src='{link}' alt='frame {i}'></a>"
                    f"<figcaption>frame {i}: {html.escape(what)}{mark}</figcaption></figure>")
    return (head + "<p class=note>Each detection frame's overlay (mask tint green/red, SLAM points white, under "
            "the mask blue, chosen cluster green, Eq. 10 square red); click for full size.</p>"
            f"<div class=grid>{''.join(figs)}</div>")


def _timings(s: dict[str, Any]) -> str:
    t = s.get("timings_ms") or {}
    rows = [(k, v) for k, v in t.items() if isinstance(v, int | float)]
    if not rows:
        return ""
    body = "".join(f"<tr><td class=l>{html.escape(k)}</td><td>{v:.1f}</td></tr>" for k, v in rows)
    return f"<h2 id=timings>Time per stage</h2><table><tr><th>stage</th><th>ms</th></tr>{body}</table>"


# ----------------------------------------------------------------------------- helpers
def _detection_frames(run_dir: Path) -> list[int]:
    folder = run_dir / "frames"
    if not folder.is_dir():
        return []
    return sorted(int(p.name) for p in folder.iterdir() if p.is_dir() and p.name.isdigit())


def _hide(values: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    """Pixels without depth as NaN (drawn black)."""
    v = np.asarray(values, np.float32)
    return v if valid is None else np.where(valid, v, np.nan)


def _heat(fig: Any, ax: Any, values: np.ndarray, title: str, unit: str, lo: float, hi: float,
          cmap: str = "jet") -> None:
    colours = plt.get_cmap(cmap).copy()
    colours.set_bad("black")
    im = ax.imshow(values, cmap=colours, vmin=lo, vmax=hi, interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, fraction=0.035, pad=0.02)
    cb.set_label(unit, fontsize=8)
    cb.ax.tick_params(labelsize=7)
    ax.set_title(title, fontsize=10)


def _read_rgb(path: Path) -> np.ndarray | None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _png(fig: Any, alt: str) -> str:
    """The figure inlined as a PNG (the page opens alone, without a server)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'
