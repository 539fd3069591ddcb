"""report.html of a ``slz detect`` run folder: one static page to read a run without a viewer.

Sections: the result (site or why not), the landing map (when the method wrote one: ``landing_map.npz``,
drawn by ``outputs/landing_map.py`` with the committed site and what would decide the undecided ground),
the funnel (what each filter left: ``outputs/funnel_html.py``),
the paper's Figure 5 panel for one frame (the four terrain maps, the score and the mask, the slope and
the overlay, with colour bars and units), the trajectory from above with the sites (SVG), the table of
every site found, each detection's overlay, the stage times. Built at the end of the run from what the
run already holds or has written (the RunResult, the site log, the pose log, frames/NNNNNN/maps.npz and
overlay.png):
one panel is drawn (for the committed site's frame, or the last detection frame without a
site), with OpenCV from one maps.npz; overlays are linked, not copied. At
``--outputs summary`` there are no frame files: the page says so and shows the rest.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from slzcli.outputs import images, palette
from slzcli.outputs.files import write_text
from slzcli.outputs.funnel_html import funnel_section
from slzcli.outputs.landing_map import landing_map_bgr, read_landing_map
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import PoseLog
from slzcli.records import SITE_FROM_FUSED, DecideAdvice, LandingRecord, RunSummary
from slzcli.render import height_text
from slzcli.types import CommittedSite, RunResult

if TYPE_CHECKING:
    import jinja2

# Display only (no result depends on these): the Figure 5 tiles' width and title band, tiles per row, the
# trajectory drawing's size and margin (px). Drawn with OpenCV and SVG, not matplotlib: a matplotlib panel of
# eight images took 20-30 s on the shared 2-core machine (benchmarks/detect_report.py), longer than the run.
TILE_WIDTH_PX = 320
TITLE_BAND_PX = 24
TILES_PER_ROW = 4
SVG_WIDTH_PX, SVG_HEIGHT_PX, SVG_MARGIN_PX = 640, 480, 34
SAFE_HEX, UNSAFE_HEX = palette.hex_of(palette.SAFE), palette.hex_of(palette.UNSAFE)
SITE_HEX = palette.hex_of(palette.SITE)
# The panel is a picture (the values are in maps.npz): JPEG at this quality is ~1/4 of the PNG's bytes and encodes
# faster; project decision.
PANEL_JPEG_QUALITY = 85
MAP_TITLES = {"depth_variance": "depth variance", "flatness": "flatness", "inclination": "inclination",
              "steepness": "steepness"}
SECTIONS = ("result", "funnel", "figure5", "trajectory", "sites", "detections", "timings")
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
    panel_frame = committed.frame.index if committed is not None else \
        (detection_frames[-1] if detection_frames else None)
    from markupsafe import Markup

    output = result.run.config.get("output")
    reverse = bool(output.get("reverse_colormap", False)) if isinstance(output, Mapping) else False
    page = _template().render(
        name=Path(s.source).name, css=Markup(CSS),
        # the picture sections are drawn here (image panel, SVG); the rest is the template's
        result=Markup(_result(s, landing)), funnel=Markup(funnel_section(result.run.funnel)),
        landing_map=Markup(_landing_map(run_dir, committed, _advice_text(landing.advice))),
        figure5=Markup(_figure5(run_dir, panel_frame, committed is not None and
                                committed.frame.index == panel_frame, level, reverse)),
        trajectory=Markup(_trajectory(trajectory, sites, committed, result.primary_segment)),
        site_columns=SITE_COLUMNS, sites=_site_rows(sites, committed),
        detections=_detection_figures(detection_frames, sites, committed), level=level,
        timings=[(k, v) for k, v in s.timings_ms.items() if isinstance(v, int | float)])
    path = run_dir / "report.html"
    write_text(path, page)
    return path


def _template() -> jinja2.Template:
    """templates/detect_report.html (jinja2, HTML-escaped by default; the package carries it)."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("slzcli.outputs", "templates"), autoescape=True,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    return env.get_template("detect_report.html")


# ----------------------------------------------------------------------------- sections
def _result(s: RunSummary, landing: LandingRecord) -> str:
    site = landing.site
    if landing.status == "site" and site is not None:
        x, y, z = site.center_world
        sup, acc = site.support, site.acceptance
        height = f", {html.escape(height_text(site.height))}" if site.height else ""
        what = (f"<b>Landing site</b> at ({x:.2f}, {y:.2f}, {z:.2f}) m{height}, score {site.score:.2f}, "
                f"confirmed by "
                f"{sup.detections_agreeing} of {sup.detections_with_site} detections with a site; acceptance "
                f"test {'passed' if acc.passed else 'NOT passed: ' + html.escape(str(acc.reason))}, "
                f"tilt {acc.tilt_deg:.1f} deg.")
        if site.source == SITE_FROM_FUSED:
            what += (" Chosen by the fused terrain (its safest square): too few SLAM map points lay on it to form "
                     "a cluster.")
        gt = site.ground_truth
        if gt:
            what += f" Ground truth: {'safe' if gt.get('safe') else 'NOT safe'}."
        if landing.spread is not None:   # how far another run (ORB-SLAM3's threads) may commit from this one
            what += f" Stability: {html.escape(str(landing.spread.site_spread.note))}."
    else:
        what = f"<b>No safe site</b>: {html.escape(str(landing.reason))}"
    return (f"<h2 id=result>Result</h2><p>{what}</p><p class=note>{html.escape(s.source)}: {s.frames} frames, "
            f"{s.detections} detection frames, method {html.escape(s.method)}, SLAM "
            f"{html.escape(s.slam_backend)}, outputs {html.escape(str(s.outputs))}. Positions are in "
            f"{html.escape(landing.world_frame)} (metres, z up). Files: <a href=landing.json>landing.json</a>, "
            "<a href=run.json>run.json</a>, <a href=sites.csv>sites.csv</a>, <a href=points.ply>points.ply</a>, "
            "<a href=trajectory.tum>trajectory.tum</a>.</p>")


def _landing_map(run_dir: Path, committed: CommittedSite | None, advice: str | None) -> str:
    """The flight's landing map (``landing_map.npz``, written by a method that keeps one: fused), or nothing."""
    path = run_dir / "landing_map.npz"
    if not path.is_file():
        return ""
    grid = read_landing_map(path)
    with np.load(path) as z:
        frame_id = str(z["frame_id"]) if "frame_id" in z.files else "map"
    site = None
    where = "No site was committed."
    if committed is not None and committed.segment == grid.segment:
        site = np.asarray(committed.site.corners_world, np.float64)[:, :2]
        where = "The committed site's square is outlined (white on black)."
    elif committed is not None:
        where = (f"The committed site is in map segment {committed.segment}, not in this map's ({grid.segment}): "
                 "not drawn.")
    ok, buf = cv2.imencode(".png", landing_map_bgr(grid, site))
    if not ok:
        return "<h2 id=landing_map>Landing map</h2><p class=note>Not drawn: PNG encoding failed.</p>"
    decide = "" if not advice else f"<p><b>What would decide the undecided ground</b>: {html.escape(advice)}.</p>"
    ox, oy = grid.origin_xy
    return ("<h2 id=landing_map>Landing map (terrain fused over the flight)</h2>"
            "<p class=note>Every cell of the ground the flight saw, fused over all its frames up to frame "
            f"{grid.frame_index}, in frame {html.escape(frame_id)} (+x right, +y up; cells of "
            f"{grid.resolution_m * 100:.1f} cm from ({ox:.2f}, {oy:.2f}) m): safe (bluish green) where the fused "
            "terrain vouches for the whole landing square, unsafe (vermillion) where a defect is known, undecided "
            "(grey) where the noise still hides what the UAV cannot take, unseen (dark grey) where no frame "
            f"measured. {where} Values: <a href=landing_map.npz>landing_map.npz</a>, picture "
            "<a href=landing_map.png>landing_map.png</a>; in results.mcap: /slz/landing_map.</p>" + decide +
            f'<img alt="landing map" src="data:image/png;base64,{_b64(buf)}">')


def _advice_text(advice: DecideAdvice | None) -> str | None:
    """The landing record's advice text, if any."""
    return advice.text if advice is not None and advice.text else None


def _figure5(run_dir: Path, index: int | None, is_site: bool, level: str, reverse: bool) -> str:
    head = "<h2 id=figure5>Terrain maps, score and mask (the paper's Figure 5)</h2>"
    folder = None if index is None else run_dir / "frames" / f"{index:06d}"
    if folder is None or not (folder / "maps.npz").is_file():
        why = "no detection frame" if index is None else \
            f"frame folders are not written at --outputs {html.escape(level)}"
        return head + f"<p class=note>Not drawn: {why}.</p>"
    with np.load(folder / "maps.npz") as z:
        arrays = {k: z[k] for k in z.files}
    h, w = arrays["valid"].shape
    scale = min(1.0, TILE_WIDTH_PX / w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))

    def small(a: np.ndarray) -> np.ndarray:  # every array to the tile size first: 1/4 of the pixels to colour
        kind = np.uint8 if a.dtype == bool else np.float32
        return cv2.resize(np.asarray(a, kind), size, interpolation=cv2.INTER_NEAREST)

    valid = small(arrays["valid"]).astype(bool)

    def heat(values: np.ndarray) -> np.ndarray:
        return images.with_colour_bar(images.heatmap_bgr(small(values), reverse=reverse, valid=valid),
                                      reverse=reverse)

    tiles = [(MAP_TITLES[n], heat(arrays[n])) for n in MAP_TITLES]
    tiles.append(("fused score", heat(arrays["score"])))
    mask = small(arrays["mask"]).astype(bool)
    tiles.append((f"landing mask ({100 * float(np.mean(arrays['mask'])):.0f} % safe)",
                  images.verdict_bgr(mask, valid)))
    slope = small(arrays.get("slope_deg", np.full((h, w), np.nan)))
    finite = slope[np.isfinite(slope) & valid]
    top = max(float(np.percentile(finite, 99)), 1.0) if finite.size else 1.0
    tiles.append(("surface slope (deg from level)", images.with_colour_bar(
        images.heatmap_bgr(np.clip(slope / top, 0.0, 1.0), valid=valid & np.isfinite(slope)),
        low="0 deg", high=f"{top:.0f} deg")))
    overlay = cv2.imread(str(folder / "overlay.png"), cv2.IMREAD_COLOR) if (folder / "overlay.png").is_file() else None
    if overlay is not None:
        tiles.append(("mask, SLAM points, site", cv2.resize(overlay, size, interpolation=cv2.INTER_AREA)))
    panel = _mosaic(tiles, TILES_PER_ROW)
    ok, buf = cv2.imencode(".jpg", panel, [cv2.IMWRITE_JPEG_QUALITY, PANEL_JPEG_QUALITY])
    if not ok:
        return head + "<p class=note>Not drawn: JPEG encoding failed.</p>"
    which = "the committed site's frame" if is_site else "the last detection frame (no site was committed)"
    return (head + f"<p class=note>Frame {index}, {which}. Maps and score in [0, 1] (dimensionless), 1 = good for "
            "landing (METHOD.md 2.3), colour bar beside each; black = no depth. Slope in degrees from level. Values: "
            f"<a href='frames/{index:06d}/maps.npz'>maps.npz</a>.</p>"
            f'<img alt="Figure 5, frame {index}" src="data:image/jpeg;base64,{_b64(buf)}">')


def _b64(buf: np.ndarray) -> str:
    return base64.b64encode(buf.tobytes()).decode()


def _mosaic(tiles: list[tuple[str, np.ndarray]], per_row: int) -> np.ndarray:
    """Tiles (BGR) with a title band each, in rows of ``per_row``, padded to one size."""
    th = max(t.shape[0] for _, t in tiles)
    tw = max(t.shape[1] for _, t in tiles)
    cells = []
    for title, tile in tiles:
        cell = np.full((th + TITLE_BAND_PX, tw, 3), 255, np.uint8)
        cell[TITLE_BAND_PX:TITLE_BAND_PX + tile.shape[0], :tile.shape[1]] = tile
        cv2.putText(cell, title, (4, TITLE_BAND_PX - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        cells.append(cell)
    blank = np.full_like(cells[0], 255)
    rows = [np.hstack(cells[i:i + per_row] + [blank] * (per_row - len(cells[i:i + per_row])))
            for i in range(0, len(cells), per_row)]
    return np.vstack(rows)


def _trajectory(log: PoseLog, sites: SiteLog, committed: CommittedSite | None, segment: int | None) -> str:
    """The camera path, every site and the committed square from above, as inline SVG (no rendering cost)."""
    head = "<h2 id=trajectory>Trajectory from above</h2>"
    poses = [p for p, k in zip(log.poses(), log.segments(), strict=True)
             if p is not None and (segment is None or k == segment)]
    if not poses:
        return head + "<p class=note>No frame was tracked: no trajectory.</p>"
    path = np.array([p[:2, 3] for p in poses])
    found = [e for e in sites.sites if segment is None or e.segment == segment]
    centres = np.array([e.site.center_world[:2] for e in found]).reshape(-1, 2)
    accepted = np.array([e.site.accepted for e in found], bool)
    square = np.asarray(committed.site.corners_world)[[0, 1, 3, 2], :2] if committed is not None else \
        np.zeros((0, 2))
    everything = np.vstack([path, centres, square])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    span = max(float(np.max(hi - lo)), 1.0)
    lo, hi = lo - 0.08 * span, hi + 0.08 * span
    m = SVG_MARGIN_PX
    scale = min((SVG_WIDTH_PX - 2 * m) / (hi[0] - lo[0]), (SVG_HEIGHT_PX - 2 * m) / (hi[1] - lo[1]))

    def px(xy: np.ndarray) -> np.ndarray:  # metres -> SVG pixels, y up
        return np.stack([m + (xy[..., 0] - lo[0]) * scale, SVG_HEIGHT_PX - m - (xy[..., 1] - lo[1]) * scale], axis=-1)

    def pts(xy: np.ndarray) -> str:
        return " ".join(f"{x:.1f},{y:.1f}" for x, y in px(xy))

    step = _nice_step(span / 6)
    grid = []
    for axis in (0, 1):
        for v in np.arange(np.ceil(lo[axis] / step) * step, hi[axis], step):
            a = np.array([[v, lo[1]], [v, hi[1]]]) if axis == 0 else np.array([[lo[0], v], [hi[0], v]])
            (x1, y1), (x2, y2) = px(a)
            grid.append(f"<line x1='{x1:.1f}' y1='{y1:.1f}' x2='{x2:.1f}' y2='{y2:.1f}' stroke='#ddd'/>")
            tx, ty = (x1, SVG_HEIGHT_PX - m + 14) if axis == 0 else (4, y1 + 4)
            grid.append(f"<text x='{tx:.1f}' y='{ty:.1f}' font-size='11' fill='#555'>{v:g}</text>")
    parts = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{SVG_WIDTH_PX}' height='{SVG_HEIGHT_PX}' "
             "style='border:1px solid #ddd;background:#fff'>", *grid,
             f"<text x='{SVG_WIDTH_PX / 2:.0f}' y='{SVG_HEIGHT_PX - 4}' font-size='12'>x (m)</text>",
             "<text x='4' y='14' font-size='12'>y (m)</text>"]
    if len(square):
        parts.append(f"<polygon points='{pts(square)}' fill='none' stroke='#000' stroke-width='3'/>"
                     f"<polygon points='{pts(square)}' fill='none' stroke='{SITE_HEX}' stroke-width='1.2'/>")
    parts.append(f"<polyline points='{pts(path)}' fill='none' stroke='#444' stroke-width='1.5'/>")
    (x0, y0), = px(path[:1])
    parts.append(f"<circle cx='{x0:.1f}' cy='{y0:.1f}' r='5' fill='none' stroke='#444' stroke-width='2'/>")
    for (x, y), ok in zip(px(centres), accepted, strict=True):
        parts.append(f"<circle cx='{x:.1f}' cy='{y:.1f}' r='3.5' fill='{SAFE_HEX if ok else UNSAFE_HEX}'/>")
    parts.append("</svg>")
    note = f" (SLAM map segment {segment})" if segment is not None else ""
    return (head + f"<p class=note>Top view of the run's world frame{note}, metres: camera path (grey, ring = "
            "first frame), the site of each detection (green: passed the acceptance test, vermillion: not), the "
            "committed site's Eq. 10 square (outline).</p>" + "".join(parts))


def _nice_step(raw: float) -> float:
    """1, 2 or 5 times a power of ten, at least ``raw`` (grid lines in metres)."""
    p = 10.0 ** np.floor(np.log10(max(raw, 1e-9)))
    return float(next(k * p for k in (1, 2, 5, 10) if k * p >= raw))


SITE_COLUMNS = ("frame", "map", "x m", "y m", "z m", "score", "accepted", "reason", "tilt deg", "edge m",
                "normal var", "extent m", "points", "chosen by")


def _site_rows(sites: SiteLog, committed: CommittedSite | None) -> list[dict[str, object]]:
    """The site table's rows (``SITE_COLUMNS``), the committed site marked."""
    chosen = None if committed is None else committed.found.id
    rows = []
    for e in sites.sites:
        st = e.site
        x, y, z = st.center_world
        cells = [str(e.frame.index), str(e.segment), f"{x:.2f}", f"{y:.2f}", f"{z:.2f}", f"{st.score:.2f}",
                 "yes" if st.accepted else "no", st.acceptance_reason or "", f"{st.tilt_deg:.1f}",
                 "n/a" if st.edge_clearance_m is None else f"{st.edge_clearance_m:.2f}",
                 f"{st.normal_variance:.2e}", f"{st.extent_m[0]:.2f} x {st.extent_m[1]:.2f}", str(st.cluster_points),
                 st.source]
        rows.append({"cells": cells, "committed": e.id == chosen})
    return rows


def _detection_figures(frames: list[int], sites: SiteLog, committed: CommittedSite | None) -> list[dict[str, object]]:
    """One figure per detection frame folder: its overlay, whether it gave a site, whether that was committed."""
    by_frame = {e.frame.index: e.site for e in sites.sites}
    site_frame = None if committed is None else committed.frame.index
    out = []
    for i in frames:
        st = by_frame.get(i)
        what = "no site" if st is None else f"site {st.score:.2f}" + ("" if st.accepted else " (not accepted)")
        out.append({"index": i, "link": f"frames/{i:06d}/overlay.png", "what": what, "committed": i == site_frame})
    return out


# ----------------------------------------------------------------------------- helpers
def _detection_frames(run_dir: Path) -> list[int]:
    folder = run_dir / "frames"
    if not folder.is_dir():
        return []
    return sorted(int(p.name) for p in folder.iterdir() if p.is_dir() and p.name.isdigit())
