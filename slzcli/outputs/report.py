"""Outputs of ``slz compare``: compare.json, compare.csv, figures, the one-page report.html, the stdout table.

Folder layout::

    OUT/compare.json   every number (per recording, per method, per pair, per variant)
    OUT/compare.csv    one row per recording x method (variants included)
    OUT/report.html    one static page, images inlined (base64), opens without a server
    OUT/<recording>/figure6.png pr_curves.png timing.png
    OUT/variants.png   with --variants: how each method and each map changes
    OUT/variants/<recording>/*.mcap   the rendered variant recordings (+ ground truth)
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import astuple, dataclass, fields, replace
from pathlib import Path

from slzcli.compare_records import (
    Compared,
    Comparison,
    MapMeans,
    ProfileComparison,
    ProfileRow,
    RecordingComparison,
    VariantChange,
    VariantMethod,
    VariantRow,
)
from slzcli.config import Config
from slzcli.outputs import files, plots
from slzcli.outputs.records_json import to_json_object

CSV_COLUMNS = ("recording", "scene", "variant", "method", "frames", "detections", "status", "site_x", "site_y",
               "site_z", "site_safe", "clearance_m", "precision", "recall", "iou", "pr_auc", "mask_iou_vs_other",
               "site_distance_m", "frame_median_ms", "frame_p90_ms", "score_median_ms", "mask_median_ms",
               "select_median_ms", "maps_median_ms", "slam_median_ms")


def write_comparison(out: Path, config: Config, methods: tuple[str, ...], results: Sequence[Compared],
                     variants: Sequence[Compared]) -> Comparison:
    """Write everything into ``out`` (a temporary folder the caller renames); return the comparison."""
    figures: dict[str, dict[str, Path]] = {}
    for r in [*results, *variants]:
        figures[_key(r.record)] = _figures(out / _key(r.record), r)
    recs = tuple(r.record for r in results)
    var_recs = tuple(r.record for r in variants)
    variant_rows = variant_table(recs, var_recs)
    variants_png = None
    if variant_rows:
        by_base: dict[str, list[VariantRow]] = {}
        for row in variant_rows:
            by_base.setdefault(row.recording, []).append(row)
        variants_png = {base: plots.variants_chart(out / f"variants_{base}.png", rows, f"{base}: variants")
                        for base, rows in by_base.items()}
    summary = Comparison(methods, config.hash(), recs, var_recs, variant_rows)
    files.write_json(out / "compare.json", {**to_json_object(summary), "config": config.to_dict()})
    files.write_text(out / "compare.csv", csv_text([*recs, *var_recs]))
    files.write_text(out / "report.html", report_html(summary, figures, variants_png or {}))
    return summary


def write_profiles(out: Path, summary: ProfileComparison, configs: Mapping[str, Config]) -> None:
    """compare.json (with every profile's config) and compare.csv of ``slz compare --profiles`` into ``out``."""
    files.write_json(out / "compare.json",
                     {**to_json_object(summary), "configs": {n: c.to_dict() for n, c in configs.items()}})
    files.write_text(out / "compare.csv", profile_csv(summary.rows))


def _key(r: RecordingComparison) -> str:
    return r.name if r.variant_of is None else f"variants/{r.variant_of}/{r.name}"


def _figures(folder: Path, c: Compared) -> dict[str, Path]:
    r, arrays = c.record, c.figures
    out: dict[str, Path] = {}
    if arrays.figure_frame is not None:
        out["figure6"] = plots.figure6(folder / "figure6.png", arrays.figure_frame, r.name)
    if arrays.curves:
        aucs = {m: None if e.ground_truth is None else e.ground_truth.pr_auc for m, e in r.methods.items()}
        aucs.update({f"map:{n}": v.pr_auc for n, v in (r.maps or {}).items()})
        out["pr_curves"] = plots.pr_curves(folder / "pr_curves.png", arrays.curves, aucs,
                                           f"{r.name}: score > tau against ground truth")
    out["timing"] = plots.timing_bars(folder / "timing.png", arrays.timings, f"{r.name}: time per stage")
    return out


# ----------------------------------------------------------------------------- rows
@dataclass(frozen=True)
class MethodRow:
    """One recording x method, flat: a row of compare.csv (``CSV_COLUMNS``, in that order) and of the tables."""

    recording: str
    scene: str | None
    variant: str
    method: str
    frames: int
    detections: int
    status: str
    site_x: float | None
    site_y: float | None
    site_z: float | None
    site_safe: object
    clearance_m: object
    precision: float | None
    recall: float | None
    iou: float | None
    pr_auc: float | None
    mask_iou_vs_other: float | None
    site_distance_m: float | None
    frame_median_ms: float | None
    frame_p90_ms: float | None
    score_median_ms: float | None
    mask_median_ms: float | None
    select_median_ms: float | None
    maps_median_ms: float | None
    slam_median_ms: float | None
    masks_empty: bool  # not a CSV column: the tables show "both empty" for the mask IoU


def method_rows(r: RecordingComparison) -> list[MethodRow]:
    """One flat row per method of one recording (the CSV and the tables)."""
    rows = []
    for m, e in r.methods.items():
        pair = next((p for p in r.pairs if m in p.methods), None)
        gt = e.ground_truth
        mask = None if gt is None else gt.mask
        site_gt = (None if gt is None else gt.site) or {}
        xyz = (None, None, None) if e.site is None else e.site.center_world
        t = e.timings_ms
        rows.append(MethodRow(
            recording=r.variant_of or r.name, scene=None if r.scene is None else r.scene.name,
            variant="+".join(() if r.scene is None else r.scene.variants) or "-", method=m, frames=r.frames,
            detections=e.detections, status=e.status, site_x=xyz[0], site_y=xyz[1], site_z=xyz[2],
            site_safe=site_gt.get("safe"), clearance_m=site_gt.get("clearance_m"),
            precision=None if mask is None else mask.precision, recall=None if mask is None else mask.recall,
            iou=None if mask is None else mask.iou, pr_auc=None if gt is None else gt.pr_auc,
            mask_iou_vs_other=None if pair is None else pair.mask_iou,
            site_distance_m=None if pair is None else pair.site_distance_m,
            frame_median_ms=t["frame"].median_ms, frame_p90_ms=t["frame"].p90_ms,
            score_median_ms=t["score"].median_ms, mask_median_ms=t["mask"].median_ms,
            select_median_ms=t["select"].median_ms, maps_median_ms=t["maps"].median_ms,
            slam_median_ms=t["slam"].median_ms, masks_empty=pair is not None and pair.masks_empty))
    return rows


CSV_FIELDS = tuple(f.name for f in fields(MethodRow))[:len(CSV_COLUMNS)]
assert CSV_FIELDS == CSV_COLUMNS, "MethodRow's first fields are compare.csv's columns, in order"


def csv_text(results: Sequence[RecordingComparison]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for r in results:
        writer.writerows(astuple(row)[:len(CSV_COLUMNS)] for row in method_rows(r))
    return buf.getvalue()


def variant_table(results: Sequence[RecordingComparison],
                  variants: Sequence[RecordingComparison]) -> tuple[VariantRow, ...]:
    """Per base recording and variant (the base itself first): each method's and each map's figures, and the change."""
    rows = []
    for base in results:
        mine = [v for v in variants if v.variant_of == base.name]
        if not mine or not base.ground_truth:
            continue
        ref = _variant_row(base, "base")
        rows.append(ref)
        for v in mine:
            row = _variant_row(v, "+".join(() if v.scene is None else v.scene.variants) or v.name)
            change = VariantChange(
                methods={m: {"precision": _delta(e.precision, ref.methods[m].precision),
                             "recall": _delta(e.recall, ref.methods[m].recall),
                             "pr_auc": _delta(e.pr_auc, ref.methods[m].pr_auc)} for m, e in row.methods.items()},
                maps={n: _delta(row.maps[n], ref.maps[n]) for n in row.maps})
            rows.append(replace(row, change=change))
    return tuple(rows)


def _variant_row(r: RecordingComparison, label: str) -> VariantRow:
    methods = {}
    for m, e in r.methods.items():
        gt = e.ground_truth
        mask = None if gt is None else gt.mask
        site = (None if gt is None else gt.site) or {}
        methods[m] = VariantMethod(precision=None if mask is None else mask.precision,
                                   recall=None if mask is None else mask.recall,
                                   iou=None if mask is None else mask.iou, pr_auc=None if gt is None else gt.pr_auc,
                                   status=e.status, site_safe=site.get("safe"), clearance_m=site.get("clearance_m"),
                                   frame_median_ms=e.timings_ms["frame"].median_ms)
    pair = r.pairs[0] if r.pairs else None
    maps = r.maps or {}
    return VariantRow(recording=r.variant_of or r.name, variant=label, methods=methods,
                      maps={n: v.pr_auc for n, v in maps.items()},
                      map_means={n: MapMeans(v.mean_safe, v.mean_unsafe) for n, v in maps.items()},
                      site_distance_m=None if pair is None else pair.site_distance_m,
                      mask_iou=None if pair is None else pair.mask_iou)


def _delta(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def profile_csv(rows: Sequence[ProfileRow]) -> str:
    """compare.csv of ``--profiles``: one line per recording and profile (``tracking`` as JSON)."""
    plain = [to_json_object(r) for r in rows]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(plain[0]) if plain else ["recording", "profile"],
                            lineterminator="\n")
    writer.writeheader()
    for r in plain:
        writer.writerow({k: json.dumps(v) if isinstance(v, dict) else v for k, v in r.items()})
    return buf.getvalue()


def profile_table(rows: Sequence[ProfileRow]) -> str:
    """The rows of ``compare_profiles`` as a text table (one line per recording and profile)."""
    def f(v: float | None, p: int = 3) -> str:
        return "-" if v is None else f"{v:.{p}f}"

    lines = [f"{'recording':<20} {'profile':<10} {'det':>4} {'prec':>6} {'recall':>6} {'site':<13} {'safe':>5} "
             f"{'ATE m':>6} {'ms/frame':>8}"]
    for r in rows:
        safe = "-" if r.site_safe is None else str(r.site_safe)
        lines.append(f"{r.recording[:20]:<20} {r.profile[:10]:<10} {r.detections:>4} {f(r.precision):>6} "
                     f"{f(r.recall):>6} {r.status:<13} {safe:>5} {f(r.ate_rmse_m):>6} "
                     f"{f(r.frame_ms_median, 1):>8}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- text
def _f(v: object, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "NO"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


TABLE_HEAD = ("recording", "method", "status", "precision", "recall", "IoU", "PR AUC", "site safe", "clearance m",
              "frame ms (med/p90)", "site dist m", "mask IoU")


def table_rows(results: Sequence[RecordingComparison]) -> list[list[str]]:
    out = []
    for r in results:
        for row in method_rows(r):
            label = row.recording if row.variant in ("-", "") or r.variant_of is None else \
                f"{row.recording}:{row.variant}"
            out.append([label, row.method, row.status, _f(row.precision), _f(row.recall), _f(row.iou),
                        _f(row.pr_auc), _f(row.site_safe), _f(row.clearance_m, 2),
                        f"{_f(row.frame_median_ms, 1)} / {_f(row.frame_p90_ms, 1)}",
                        _f(row.site_distance_m, 2),
                        EMPTY if row.masks_empty else _f(row.mask_iou_vs_other)])
    return out


EMPTY = "both empty"  # the pair's masks were empty in every frame: IoU and agreement say nothing
GROUND_TRUTH_HEAD = ("precision", "recall", "IoU", "PR AUC", "site safe", "clearance m")


def without_empty_truth(head: tuple[str, ...], rows: list[list[str]]) -> tuple[tuple[str, ...], list[list[str]], bool]:
    """The ground-truth columns dropped when none has a value in any row (recordings without ground truth)."""
    drop = {i for i, h in enumerate(head) if h in GROUND_TRUTH_HEAD}
    if not rows or any(r[i] != "n/a" for r in rows for i in drop):
        return head, rows, False
    keep = [i for i in range(len(head)) if i not in drop]
    return tuple(head[i] for i in keep), [[r[i] for i in keep] for r in rows], True


def text_table(summary: Comparison, output: str) -> str:
    """The stdout table: recording x method, then the pairs (site distance, mask IoU)."""
    head, rows, dropped = without_empty_truth(TABLE_HEAD, table_rows([*summary.recordings, *summary.variants]))
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)] if rows else \
        [len(h) for h in head]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    if dropped:
        lines.append("no ground truth (a slz synth recording has one): precision, recall, IoU, PR AUC and site "
                     "safety are not shown")
    for r in summary.recordings:
        same = "identical" if r.inputs_identical else "DIFFERENT"
        lines.append(f"{r.name}: {r.frames} frames, {r.detections} detection frames, SLAM "
                     f"{r.slam_backend}; frames, SLAM points and maps {same} for all methods")
    lines.append(f"-> {output}/ (compare.json, compare.csv, report.html, figures)")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- html
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1200px;color:#222}
h1{font-size:22px;margin-bottom:4px} h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
h3{font-size:15px;margin:18px 0 6px} p.note{color:#555;font-size:13px;max-width:900px}
table{border-collapse:collapse;font-size:12.5px;margin:8px 0}
td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}
th{background:#f1f1f1} td.l,th.l{text-align:left} td.bad{background:#fbe3e3} td.good{background:#e5f5e5}
img{max-width:100%;border:1px solid #ddd;margin:4px 0}
.row{display:flex;gap:12px;flex-wrap:wrap} .row img{max-width:48%}
"""


def _img(path: Path | None, alt: str) -> str:
    if path is None or not Path(path).is_file():
        return ""
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _cell(v: str, head: str) -> str:
    cls = ""
    if head == "site safe":
        cls = ' class="good"' if v == "yes" else ' class="bad"' if v == "NO" else ""
    elif head in ("recording", "method", "status", "variant"):
        cls = ' class="l"'
    return f"<td{cls}>{html.escape(v)}</td>"


def _table(head: tuple[str, ...] | list[str], rows: list[list[str]]) -> str:
    th = "".join(f'<th{" class=l" if i < 3 else ""}>{html.escape(h)}</th>' for i, h in enumerate(head))
    body = "".join("<tr>" + "".join(_cell(c, h) for c, h in zip(r, head, strict=True)) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _timing_table(r: RecordingComparison) -> str:
    stages = ("slam", "maps", "score", "mask", "select", "frame")
    head = ["method", *[f"{s} med / p90" for s in stages]]
    rows = [[m, *[f"{_f(e.timings_ms[s].median_ms, 1)} / {_f(e.timings_ms[s].p90_ms, 1)}"
                  for s in stages]] for m, e in r.methods.items()]
    return _table(head, rows)


def _change(d: float | None) -> str:
    return "" if d is None else f" ({round(d, 3) + 0.0:+.3f})"   # + 0.0: no "-0.000"


def _variant_html(rows: Sequence[VariantRow], charts: Mapping[str, Path]) -> str:
    if not rows:
        return ""
    methods = list(rows[0].methods)
    maps = list(rows[0].maps)
    head = ["recording", "variant", *[f"{m} {k}" for m in methods for k in ("prec", "recall", "AUC", "site safe")],
            *[f"{n} AUC" for n in maps], "site dist m"]
    body = []
    for row in rows:
        ch = row.change
        cells = [row.recording, row.variant]
        for m in methods:
            e = row.methods[m]
            for k, v in (("precision", e.precision), ("recall", e.recall), ("pr_auc", e.pr_auc)):
                cells.append(_f(v) + _change(ch.methods[m][k] if ch else None))
            cells.append(_f(e.site_safe))
        for n in maps:
            cells.append(_f(row.maps[n]) + _change(ch.maps[n] if ch else None))
        cells.append(_f(row.site_distance_m, 2))
        body.append(cells)
    imgs = "".join(_img(p, f"variants of {b}") for b, p in charts.items())
    return ("<h2>Sensitivity: ground material and illumination</h2><p class=note>Each variant re-renders the same "
            "flight (same seed, frames and start) with another ground material or light; the change against the base "
            "recording is in brackets. Map AUC = each terrain map alone as a detector of truly safe pixels. Note: the "
            "depth model of <code>slz synth</code> does not depend on ground material or light (the same seeded noise "
            "on the same geometry), so the maps barely move; the colour image does, and with it the ORB features, the "
            "SLAM map points and so the chosen site.</p>"
            + _table(head, body) + imgs)


def report_html(summary: Comparison, figures: Mapping[str, Mapping[str, Path]],
                variant_charts: Mapping[str, Path]) -> str:
    """One static page: the summary table, per recording the Figure 6 panel, PR curves and timing, the variants."""
    recs = summary.recordings
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>slz compare: "
             f"{html.escape(', '.join(summary.methods))}</title><style>{CSS}</style></head><body>",
             f"<h1>slz compare: {html.escape(' vs '.join(summary.methods))}</h1>",
             "<p class=note>Same frames, same SLAM map points and the same four terrain maps for every method: only "
             "the fusion (fuzzy Mamdani score vs naive-Bayes probability) and the cluster rule differ. The Bayes "
             "method is this project's reconstruction of Chatzikalymnios &amp; Moustakas (2022) [16] (BASELINE.md), "
             f"not [16] itself. Config hash {html.escape(summary.config_hash)}. Pixel figures are micro-averaged "
             "over all detection frames; PR AUC sweeps the score threshold against the ground-truth safe mask.</p>",
             *(["<p class=note>px4slp is this project's reimplementation of PX4-Avoidance's safe_landing_planner "
                "grid (PX4SLP.md): it bins the same depth points and poses in a world grid and reads none of the "
                "maps; its mask is its land-able cells, its score the waypoint generator's per-cell hysteresis, "
                "its site the first all-land-able disk on its search rays.</p>"] if "px4slp" in summary.methods
               else []),
             "<h2>Summary</h2>", _table(*without_empty_truth(TABLE_HEAD, table_rows(recs))[:2])]
    for r in [*recs, *summary.variants]:
        fig = figures.get(_key(r), {})
        pair_rows = [[" vs ".join(p.methods), _f(p.site_distance_m, 3),
                      _f(p.per_frame_site_distance_m.mean, 3), str(p.per_frame_site_distance_m.frames),
                      *([EMPTY, EMPTY] if p.masks_empty else [_f(p.mask_iou), _f(p.mask_agreement)])]
                     for p in r.pairs]
        title = r.name if r.variant_of is None else f"{r.variant_of} variant: {r.name}"
        parts += [f"<h2>{html.escape(title)}</h2>",
                  f"<p class=note>{html.escape(r.source)}: {r.frames} frames, {r.detections} detection "
                  f"frames, SLAM {html.escape(r.slam_backend)}, inputs identical for all methods: "
                  f"{'yes' if r.inputs_identical else 'NO'}.</p>",
                  _table(("methods", "committed site distance m", "per-frame site distance m (mean)",
                          "frames with both", "mask IoU", "pixel agreement"), pair_rows),
                  _timing_table(r), _img(fig.get("figure6"), "Figure 6 layout"),
                  "<div class=row>", _img(fig.get("pr_curves"), "PR curves"), _img(fig.get("timing"), "timing"),
                  "</div>"]
    parts.append(_variant_html(summary.variant_table, variant_charts))
    parts.append("</body></html>")
    return "\n".join(p for p in parts if p)
