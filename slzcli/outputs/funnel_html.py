"""report.html's funnel section: per detection frame, what each filter between the depth and a site left.

Read from run.json's ``funnel`` (``slzcli.funnel.FunnelLog.as_dict``): one row per detection frame (the first
``MAX_ROWS``; all of them are in run.json), the sums over the run first.
"""

from __future__ import annotations

import html
from collections.abc import Mapping

MAX_ROWS = 200  # display only: a long recording's rows stay in run.json
COLUMNS = ("frame", "px with depth", "above threshold", "footprint clear", "column in view", "noise limits (mask)",
           "emptied by", "map points: keyframe / in view / on mask", "clusters (failed test)", "site")


def _obj(value: object) -> Mapping[str, object]:
    """A JSON object of the funnel ({} for a missing one)."""
    return value if isinstance(value, Mapping) else {}


def _objs(value: object) -> list[Mapping[str, object]]:
    """The JSON objects of a list of the funnel ([] for a missing one)."""
    return [v for v in value if isinstance(v, Mapping)] if isinstance(value, list) else []


def funnel_section(funnel: Mapping[str, object] | None) -> str:
    """The section's HTML ("" without a funnel: a run folder of an older slz)."""
    if not funnel:
        return ""
    frames = _objs(funnel.get("frames"))
    head = "<h2 id=funnel>Funnel: what each filter left</h2>"
    if not frames:
        return head + "<p class=note>No detection frame.</p>"
    mp = _obj(funnel.get("map_points"))
    failed = _obj(funnel.get("clusters_failed"))
    total = ["all", *(str(v) for v in _obj(funnel.get("mask_px")).values()),
             ", ".join(f"{k} {v}" for k, v in _obj(funnel.get("frames_emptied_by")).items() if v) or "-",
             f"{mp.get('keyframe', 0)} / {mp.get('in_view', 0)} / {mp.get('on_mask', 0)}",
             f"{funnel.get('clusters', 0)}" + (f" ({', '.join(f'{k} {v}' for k, v in failed.items())})" if failed
                                                else ""), ""]
    rows = [_row(total, " style=font-weight:600")] + [_row(_cells(f)) for f in frames[:MAX_ROWS]]
    more = f" The first {MAX_ROWS} of {len(frames)} frames are shown; run.json has every one." \
        if len(frames) > MAX_ROWS else ""
    th = "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS)
    return (head + "<p class=note>Pixels of each detection frame left after each step of the landing mask, in "
            "order (the score threshold, the footprint square's clearance, the final descent's column in view, "
            "the depth noise limits), then the SLAM map points on the mask, the k-means clusters and the first "
            "test each failed, and the site's acceptance test (docs/DESIGN.md, run.json funnel). The first row "
            f"sums the run.{more}</p><table><tr>{th}</tr>{''.join(rows)}</table>" + _verdict_cells(frames))


def _verdict_cells(frames: list[Mapping[str, object]]) -> str:
    """A method with a verdict per cell (fused): the cells in view each of its tests left, per detection frame
    ("" when no frame has them)."""
    with_cells = [(f["frame"], _obj(f.get("cells"))) for f in frames[:MAX_ROWS] if f.get("cells")]
    if not with_cells:
        return ""
    steps = list(with_cells[0][1])
    th = "".join(f"<th>{html.escape(c)}</th>" for c in ("frame", *steps))
    rows = "".join(_row([str(v) for v in (frame, *(c.get(s, "-") for s in steps))], left_from=len(steps) + 1)
                   for frame, c in with_cells)
    return ("<p class=note>The fused verdict's cells in view each test left, in the order a cell must pass them "
            "(seen, its landing square's score above the threshold, decided by the noise, within the step and slope "
            "tolerances, its descent column seen, off a refused raised surface: safe; docs/METHOD.md 2.3.6). "
            f"Frames without a pose have none.</p><table><tr>{th}</tr>{rows}</table>")


def _cells(f: Mapping[str, object]) -> list[str]:
    px = _obj(f.get("mask_px"))
    mask = [str(v) for v in px.values()] if px else ["-"] * 5
    mp = f.get("map_points")
    points = str(f.get("note", "-")) if not isinstance(mp, Mapping) else \
        f"{mp['keyframe']} / {mp['in_view']} / {mp['on_mask']}"
    clusters = _objs(f.get("clusters"))
    tests = [str(c["failed"]) for c in clusters if c["failed"]]
    cl = f"{len(clusters)}" + (f" ({', '.join(tests)})" if tests else "")
    site = f.get("site")
    what = "-" if not isinstance(site, Mapping) else \
        ("accepted" if site["accepted"] else f"not accepted: {site['reason']}")
    return [str(f["frame"]), *mask, str(f.get("emptied_by") or "-"), points, cl, what]


def _row(cells: list[str], cls: str = "", left_from: int = 6) -> str:
    """A table row; the cells from ``left_from`` on are text (left-aligned), the ones before it numbers."""
    tds = "".join(f"<td{' class=l' if i >= left_from else ''}>{html.escape(c)}</td>" for i, c in enumerate(cells))
    return f"<tr{cls}>{tds}</tr>"
