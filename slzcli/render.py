"""The text a command prints when it is done: whole sentences, figures rounded as a person reads them.

Pure functions of the summaries (``records.RunSummary``, the dicts of the other commands' ``--json``);
the CLI only echoes them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from slzcli.records import SITE_FROM_FUSED, BatchRow, JsonObject, RunSummary, SiteHeight


def height_text(h: SiteHeight) -> str:
    """``0.02 m above the ground, 8.02 m below the start (frame 0's camera, map frame map)``."""
    def updown(v: float, what: str) -> str:
        return f"{abs(v):.2f} m {'above' if v >= 0 else 'below'} {what}"

    parts = [] if h.above_ground_m is None else [updown(h.above_ground_m, "the ground")]
    parts.append(updown(h.above_start_m, f"the start (frame {h.start_frame}'s camera, map frame {h.frame_id})"))
    return ", ".join(parts)


def slam_maps(s: RunSummary | None) -> int:
    """How many SLAM maps a run's summary reports (1 for a summary written before maps were counted)."""
    return 1 if s is None or s.slam is None else s.slam.maps


def _num(v: object, fmt: str, unit: str = "") -> str:
    """``v`` formatted (a number of a summary or of JSON read back), "n/a" for None."""
    return "n/a" if v is None else f"{format(v, fmt)}{unit}"


def _get(obj: JsonObject | None, key: str) -> object:
    """A value of a JSON object another module describes (None when the object or the key is missing)."""
    return None if obj is None else obj.get(key)


def detect_text(out: Path, s: RunSummary) -> str:
    """``slz detect`` on one recording: the verdict first, then how it was reached and where the files are."""
    t = s.timings_ms
    maps = slam_maps(s)
    lost = None if s.slam is None else s.slam.untracked.frames_untracked
    head = (f"{s.source}: {s.frames} frames" + (f" ({lost} not tracked)" if lost else "")
            + f", {s.detections} detections ({s.method}, "
            f"SLAM {s.slam_backend}" + (f", {maps} maps)" if maps > 1 else ")"))
    if s.skipped:
        head += " [skipped: done before with the same config and input bytes; --force redoes it]"
    if s.status == "site" and s.site_world is not None:
        x, y, z = s.site_world
        segment = None if s.slam is None else s.slam.segment
        where = f"SLAM map {segment}'s world frame" if maps > 1 else "the run's world frame"
        result = f"landing site at ({x:.2f}, {y:.2f}, {z:.2f}) m in {where}"
        if s.site_height:
            result += f": {height_text(s.site_height)}"
        if s.site_source == SITE_FROM_FUSED:
            result += " (the fused terrain's own safe square: too few SLAM map points on it to cluster)"
    else:
        result = f"no safe site: {s.reason}"
    lines = [head, "  " + result]
    if s.advice is not None:
        lines.append(f"  what would decide it: {s.advice.text}")
    gv = s.gravity
    if gv:
        disagreements = _get(gv, "disagreements")
        apart = f" ({len(disagreements)} disagreement(s): see the warnings)" \
            if isinstance(disagreements, list) and disagreements else ""
        lines.append(f"  gravity: {gv['source']}, camera tilted {_get(gv, 'tilt_deg'):.1f} deg from straight "
                     f"down{apart}")
    noise, lim = s.depth_noise, s.depth_limits
    if lim:
        a = noise.get("a_per_m_median", noise.get("a_per_m"))
        where = f"a = {a:.4f} 1/m ({noise.get('source')}), " if isinstance(a, float | int) else ""
        not_vouched = _get(noise, "detections_not_vouched") or 0
        lines.append(f"  depth noise: {where}sigma {_get(lim, 'sigma_m'):.3f} m at {_get(lim, 'altitude_m'):.1f} m; "
                     f"maps on {lim['block_px']} px blocks; steps >= {_get(lim, 'step_min_m'):.2f} m and slopes >= "
                     f"{_get(lim, 'slope_min_deg'):.1f} deg detectable"
                     + ("" if not_vouched == 0 else f"; {not_vouched} detection frame(s) could not vouch"))
    write = f", write {t['write']:.1f} ms" if "write" in t else ""  # a run.json from before write was summarised
    if "write_wait" in t:  # the writer runs beside the loop: what it cost the loop is the wait
        write += f" in the background (the loop waited {t['write_wait']:.1f} ms)"
    lines.append(f"  per frame: maps {t['maps']:.1f} ms, {s.method} {t[s.method]:.1f} ms, "
                 f"mask {t['mask']:.1f} ms, slam {t['slam']:.1f} ms, select {t['select']:.1f} ms{write} (medians)")
    gt = s.ground_truth
    m = _get(gt, "mask")
    if isinstance(m, Mapping) and m:
        site = _get(gt, "site")
        lines.append(f"  vs ground truth: mask precision {_num(m['precision'], '.3f')}, recall "
                     f"{_num(m['recall'], '.3f')}, IoU {_num(m['iou'], '.3f')}"
                     + (f"; site safe: {site['safe']}, clearance {site['clearance_m']:.2f} m"
                        if isinstance(site, Mapping) and site else ""))
    frames = {"summary": "", "maps": ", frames/ (maps.npz, overlay.png)", "all": ", frames/"}.get(
        s.outputs, ", frames/")
    mcap = ", results.mcap" if (out / "results.mcap").exists() else ""
    lines.append(f"  results: {out}/report.html (open it first); also landing.json, run.json, sites.csv, "
                 f"points.ply{mcap}{frames}")
    return "\n".join(lines)


def batch_text(t: Mapping[str, Any], rows: Sequence[BatchRow]) -> str:
    """A batch of ``slz detect``: one line per recording, then the totals and the summary files."""
    lines = []
    for r in rows:
        name = Path(r.run).name
        if r.status == "site" and r.site_world is not None:
            x, y, z = r.site_world
            what = f"site at ({x:.2f}, {y:.2f}, {z:.2f}) m"
        else:
            what = "no safe site" + (f": {r.summary.reason}" if r.summary is not None else "")
        done = "skipped (done before)" if r.skipped else f"{r.frames} frames in {r.wall_s or 0.0:.1f} s"
        maps = slam_maps(r.summary)
        lines.append(f"  {name}: {what}; {done}" + (f"; {maps} SLAM maps" if maps > 1 else ""))
    return "\n".join([
        f"{t['recordings']} recordings ({t['engine']}, {t['workers']} worker(s)): {t['site']} with a site, "
        f"{t['no_safe_site']} without, {t['skipped']} skipped as done before",
        *lines,
        f"  {t['processed']} processed: {t['frames']} frames in {t['wall_s']:.1f} s = "
        f"{_num(t['frames_per_s'], '.2f')} frames/s, {_num(t['recordings_per_min'], '.1f')} recordings/min",
        f"  summary: {', '.join(t['summary_files'])}"])


def simulate_text(m: Mapping[str, object], out: Path) -> str:
    """One simulated landing (metrics.json): the outcome, then its figures (s to 0.1, m to 0.01, px and deg to 0.1)."""
    phases = m.get("phases_s")
    shown = [f"{name} {v:.1f} s" for name, v in phases.items() if v is not None] if isinstance(phases, Mapping) else []
    lines = [
        f"{'Landed' if m['success'] else 'Landing FAILED'} ({m['reason']}) after "
        f"{_num(m['landing_time_s'], '.1f', ' s')}.",
        f"  phases: {', '.join(shown) or 'none'}; {m['recoveries']} recover"
        f"{'y' if m['recoveries'] == 1 else 'ies'} (corners lost and found again)",
        f"  touch-down error {_num(m['touchdown_error_m'], '.2f', ' m')}, speed "
        f"{_num(m['touchdown_speed_m_s'], '.2f', ' m/s')}; final feature error "
        f"{_num(m['final_feature_error_px'], '.1f', ' px')}, yaw error "
        f"{_num(m['final_yaw_error_deg'], '.1f', ' deg')}",
        f"  stabilisation {_num(m['stabilisation_time_s'], '.1f', ' s')}, max tilt "
        f"{_num(m['max_tilt_deg'], '.1f', ' deg')}",
        f"  results: {out}/ (metrics.json, trajectory.csv, plots)",
    ]
    return "\n".join(lines)


def synth_text(summary: dict[str, Any], fmt: str, color_encoding: str, depth_encoding: str) -> str:
    """``slz synth``: what was written, from where, and how much of it is safe."""
    s = summary
    variants = "+" + "+".join(s["variants"]) if s["variants"] else ""
    start = ", ".join(f"{v:g}" for v in s["start_m"])
    return (f"{s['recording']}: {s['frames']} frames of {s['scene']}{variants} ({fmt}, {color_encoding}/"
            f"{depth_encoding}) from ({start}) m, seed {s['seed']}; ground truth {s['ground_truth']} "
            f"({100 * s['safe_fraction_first_frame']:.1f} % of frame 0 safe); preview {s['preview']}")
