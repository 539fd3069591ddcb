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
from pathlib import Path
from typing import Any

from slzcli.config import Config
from slzcli.outputs import files, plots

CSV_COLUMNS = ("recording", "scene", "variant", "method", "frames", "detections", "status", "site_x", "site_y",
               "site_z", "site_safe", "clearance_m", "precision", "recall", "iou", "pr_auc", "mask_iou_vs_other",
               "site_distance_m", "frame_median_ms", "frame_p90_ms", "score_median_ms", "mask_median_ms",
               "select_median_ms", "maps_median_ms", "slam_median_ms")


def write_comparison(out: Path, config: Config, methods: tuple[str, ...], results: list[dict[str, Any]],
                     variants: list[dict[str, Any]]) -> dict[str, Any]:
    """Write everything into ``out`` (a temporary folder the caller renames); return the JSON summary."""
    figures: dict[str, dict[str, Path]] = {}
    for r in results + variants:
        figures[_key(r)] = _figures(out / _key(r), r)
    variant_rows = variant_table(results, variants)
    variants_png = None
    if variant_rows:
        by_base: dict[str, list[dict[str, Any]]] = {}
        for row in variant_rows:
            by_base.setdefault(row["recording"], []).append(row)
        variants_png = {base: plots.variants_chart(out / f"variants_{base}.png", rows, f"{base}: variants")
                        for base, rows in by_base.items()}
    summary = {"methods": list(methods), "config_hash": config.hash(),
               "recordings": [_public(r) for r in results], "variants": [_public(r) for r in variants],
               "variant_table": variant_rows}
    files.write_json(out / "compare.json", {**summary, "config": config.to_dict()})
    files.write_text(out / "compare.csv", csv_text(results + variants))
    files.write_text(out / "report.html", report_html(summary, figures, variants_png or {}))
    return summary


def _key(r: dict[str, Any]) -> str:
    return r["name"] if "variant_of" not in r else f"variants/{r['variant_of']}/{r['name']}"


def _public(r: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in r.items() if not k.startswith("_")}


def _figures(folder: Path, r: dict[str, Any]) -> dict[str, Path]:
    arrays = r["_arrays"]
    out: dict[str, Path] = {}
    if arrays["figure_frame"] is not None:
        out["figure6"] = plots.figure6(folder / "figure6.png", arrays["figure_frame"], r["name"])
    if arrays["curves"]:
        aucs = {m: e["ground_truth"]["pr_auc"] for m, e in r["methods"].items()}
        aucs.update({f"map:{n}": v["pr_auc"] for n, v in r.get("maps", {}).items()})
        out["pr_curves"] = plots.pr_curves(folder / "pr_curves.png", arrays["curves"], aucs,
                                           f"{r['name']}: score > tau against ground truth")
    out["timing"] = plots.timing_bars(folder / "timing.png", arrays["timings"], f"{r['name']}: time per stage")
    return out


# ----------------------------------------------------------------------------- rows
def method_rows(r: dict[str, Any]) -> list[dict[str, Any]]:
    """One flat row per method of one recording (the CSV and the tables)."""
    rows = []
    for m, e in r["methods"].items():
        pair = next((p for p in r["pairs"] if m in p["methods"]), None)
        gt = e.get("ground_truth") or {}
        mask = gt.get("mask") or {}
        site_gt = gt.get("site") or {}
        site = e.get("site") or {}
        xyz = site.get("center_world") or [None, None, None]
        t = e["timings_ms"]
        scene = r.get("scene") or {}
        rows.append({
            "recording": r.get("variant_of", r["name"]), "scene": scene.get("name"),
            "variant": "+".join(scene.get("variants", [])) or "-", "method": m, "frames": r["frames"],
            "detections": e["detections"], "status": e["status"], "site_x": xyz[0], "site_y": xyz[1], "site_z": xyz[2],
            "site_safe": site_gt.get("safe"), "clearance_m": site_gt.get("clearance_m"),
            "precision": mask.get("precision"), "recall": mask.get("recall"), "iou": mask.get("iou"),
            "pr_auc": gt.get("pr_auc"), "mask_iou_vs_other": pair and pair["mask_iou"],
            "site_distance_m": pair and pair["site_distance_m"],
            "masks_empty": bool(pair and pair.get("masks_empty")),
            "frame_median_ms": t["frame"]["median_ms"], "frame_p90_ms": t["frame"]["p90_ms"],
            "score_median_ms": t["score"]["median_ms"], "mask_median_ms": t["mask"]["median_ms"],
            "select_median_ms": t["select"]["median_ms"], "maps_median_ms": t["maps"]["median_ms"],
            "slam_median_ms": t["slam"]["median_ms"]})
    return rows


def csv_text(results: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    for r in results:
        writer.writerows(method_rows(r))
    return buf.getvalue()


def variant_table(results: list[dict[str, Any]], variants: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per base recording and variant (the base itself first): each method's and each map's figures, and the change."""
    rows = []
    for base in results:
        mine = [v for v in variants if v.get("variant_of") == base["name"]]
        if not mine or not base.get("ground_truth"):
            continue
        ref = _variant_row(base, "base")
        rows.append(ref)
        for v in mine:
            row = _variant_row(v, "+".join((v.get("scene") or {}).get("variants", [])) or v["name"])
            row["change"] = {
                "methods": {m: {k: _delta(row["methods"][m].get(k), ref["methods"][m].get(k))
                                for k in ("precision", "recall", "pr_auc")} for m in row["methods"]},
                "maps": {n: _delta(row["maps"][n], ref["maps"][n]) for n in row["maps"]}}
            rows.append(row)
    return rows


def _variant_row(r: dict[str, Any], label: str) -> dict[str, Any]:
    methods = {}
    for m, e in r["methods"].items():
        gt = e.get("ground_truth") or {}
        site = gt.get("site") or {}
        methods[m] = {"precision": gt["mask"]["precision"], "recall": gt["mask"]["recall"], "iou": gt["mask"]["iou"],
                      "pr_auc": gt.get("pr_auc"), "status": e["status"], "site_safe": site.get("safe"),
                      "clearance_m": site.get("clearance_m"), "frame_median_ms": e["timings_ms"]["frame"]["median_ms"]}
    pair = r["pairs"][0] if r["pairs"] else {}
    return {"recording": r.get("variant_of", r["name"]), "variant": label, "methods": methods,
            "maps": {n: v["pr_auc"] for n, v in (r.get("maps") or {}).items()},
            "map_means": {n: {"safe": v["mean_safe"], "unsafe": v["mean_unsafe"]}
                          for n, v in (r.get("maps") or {}).items()},
            "site_distance_m": pair.get("site_distance_m"), "mask_iou": pair.get("mask_iou")}


def _delta(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


# ----------------------------------------------------------------------------- text
def _f(v: Any, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "NO"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


TABLE_HEAD = ("recording", "method", "status", "precision", "recall", "IoU", "PR AUC", "site safe", "clearance m",
              "frame ms (med/p90)", "site dist m", "mask IoU")


def table_rows(results: list[dict[str, Any]]) -> list[list[str]]:
    out = []
    for r in results:
        for row in method_rows(r):
            label = row["recording"] if row["variant"] in ("-", "") or "variant_of" not in r else \
                f"{row['recording']}:{row['variant']}"
            out.append([label, row["method"], row["status"], _f(row["precision"]), _f(row["recall"]), _f(row["iou"]),
                        _f(row["pr_auc"]), _f(row["site_safe"]), _f(row["clearance_m"], 2),
                        f"{_f(row['frame_median_ms'], 1)} / {_f(row['frame_p90_ms'], 1)}",
                        _f(row["site_distance_m"], 2),
                        EMPTY if row["masks_empty"] else _f(row["mask_iou_vs_other"])])
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


def text_table(summary: dict[str, Any], output: str) -> str:
    """The stdout table: recording x method, then the pairs (site distance, mask IoU)."""
    head, rows, dropped = without_empty_truth(TABLE_HEAD, table_rows(summary["recordings"] + summary["variants"]))
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)] if rows else \
        [len(h) for h in head]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    if dropped:
        lines.append("no ground truth (a slz synth recording has one): precision, recall, IoU, PR AUC and site "
                     "safety are not shown")
    for r in summary["recordings"]:
        same = "identical" if r["inputs_identical"] else "DIFFERENT"
        lines.append(f"{r['name']}: {r['frames']} frames, {r['detections']} detection frames, SLAM "
                     f"{r['slam_backend']}; frames, SLAM points and maps {same} for all methods")
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


def _timing_table(r: dict[str, Any]) -> str:
    stages = ("slam", "maps", "score", "mask", "select", "frame")
    head = ["method", *[f"{s} med / p90" for s in stages]]
    rows = [[m, *[f"{_f(e['timings_ms'][s]['median_ms'], 1)} / {_f(e['timings_ms'][s]['p90_ms'], 1)}"
                  for s in stages]] for m, e in r["methods"].items()]
    return _table(head, rows)


def _change(d: float | None) -> str:
    return "" if d is None else f" ({round(d, 3) + 0.0:+.3f})"   # + 0.0: no "-0.000"


def _variant_html(rows: list[dict[str, Any]], charts: dict[str, Path]) -> str:
    if not rows:
        return ""
    methods = list(rows[0]["methods"])
    maps = list(rows[0]["maps"])
    head = ["recording", "variant", *[f"{m} {k}" for m in methods for k in ("prec", "recall", "AUC", "site safe")],
            *[f"{n} AUC" for n in maps], "site dist m"]
    body = []
    for row in rows:
        ch = row.get("change")
        cells = [row["recording"], row["variant"]]
        for m in methods:
            e = row["methods"][m]
            for k in ("precision", "recall", "pr_auc"):
                d = ch["methods"][m][k] if ch else None
                cells.append(_f(e[k]) + _change(d))
            cells.append(_f(e["site_safe"]))
        for n in maps:
            d = ch["maps"][n] if ch else None
            cells.append(_f(row["maps"][n]) + _change(d))
        cells.append(_f(row["site_distance_m"], 2))
        body.append(cells)
    imgs = "".join(_img(p, f"variants of {b}") for b, p in charts.items())
    return ("<h2>Sensitivity: ground material and illumination</h2><p class=note>Each variant re-renders the same "
            "flight (same seed, frames and start) with another ground material or light; the change against the base "
            "recording is in brackets. Map AUC = each terrain map alone as a detector of truly safe pixels. Note: the "
            "depth model of <code>slz synth</code> does not depend on ground material or light (the same seeded noise "
            "on the same geometry), so the maps barely move; the colour image does, and with it the ORB features, the "
            "SLAM map points and so the chosen site.</p>"
            + _table(head, body) + imgs)


def report_html(summary: dict[str, Any], figures: dict[str, dict[str, Path]], variant_charts: dict[str, Path]) -> str:
    """One static page: the summary table, per recording the Figure 6 panel, PR curves and timing, the variants."""
    recs = summary["recordings"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>slz compare: "
             f"{html.escape(', '.join(summary['methods']))}</title><style>{CSS}</style></head><body>",
             f"<h1>slz compare: {html.escape(' vs '.join(summary['methods']))}</h1>",
             "<p class=note>Same frames, same SLAM map points and the same four terrain maps for every method: only "
             "the fusion (fuzzy Mamdani score vs naive-Bayes probability) and the cluster rule differ. The Bayes "
             "method is this project's reconstruction of Chatzikalymnios &amp; Moustakas (2022) [16] (BASELINE.md), "
             f"not [16] itself. Config hash {html.escape(summary['config_hash'])}. Pixel figures are micro-averaged "
             "over all detection frames; PR AUC sweeps the score threshold against the ground-truth safe mask.</p>",
             *(["<p class=note>px4slp is this project's reimplementation of PX4-Avoidance's safe_landing_planner "
                "grid (PX4SLP.md): it bins the same depth points and poses in a world grid and reads none of the "
                "maps; its mask is its land-able cells, its score the waypoint generator's per-cell hysteresis, "
                "its site the first all-land-able disk on its search rays.</p>"] if "px4slp" in summary["methods"]
               else []),
             "<h2>Summary</h2>", _table(*without_empty_truth(TABLE_HEAD, table_rows(recs))[:2])]
    for r in recs + summary["variants"]:
        key = _key(r)
        fig = figures.get(key, {})
        pair_rows = [[" vs ".join(p["methods"]), _f(p["site_distance_m"], 3),
                      _f(p["per_frame_site_distance_m"]["mean"], 3), str(p["per_frame_site_distance_m"]["frames"]),
                      *([EMPTY, EMPTY] if p.get("masks_empty") else [_f(p["mask_iou"]), _f(p["mask_agreement"])])]
                     for p in r["pairs"]]
        title = r["name"] if "variant_of" not in r else f"{r['variant_of']} variant: {r['name']}"
        parts += [f"<h2>{html.escape(title)}</h2>",
                  f"<p class=note>{html.escape(r['source'])}: {r['frames']} frames, {r['detections']} detection "
                  f"frames, SLAM {html.escape(r['slam_backend'])}, inputs identical for all methods: "
                  f"{'yes' if r['inputs_identical'] else 'NO'}.</p>",
                  _table(("methods", "committed site distance m", "per-frame site distance m (mean)",
                          "frames with both", "mask IoU", "pixel agreement"), pair_rows),
                  _timing_table(r), _img(fig.get("figure6"), "Figure 6 layout"),
                  "<div class=row>", _img(fig.get("pr_curves"), "PR curves"), _img(fig.get("timing"), "timing"),
                  "</div>"]
    parts.append(_variant_html(summary.get("variant_table", []), variant_charts))
    parts.append("</body></html>")
    return "\n".join(p for p in parts if p)
