"""The text a command prints when it is done: whole sentences, figures rounded as a person reads them.

Pure functions of the summaries (the same dicts ``--json`` prints); the CLI only echoes them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def height_text(h: dict[str, Any]) -> str:
    """``0.02 m above the ground, 8.02 m below the start (frame 0's camera, map frame map)``."""
    def updown(v: float, what: str) -> str:
        return f"{abs(v):.2f} m {'above' if v >= 0 else 'below'} {what}"

    parts = [] if h.get("above_ground_m") is None else [updown(h["above_ground_m"], "the ground")]
    parts.append(updown(h["above_start_m"], f"the start (frame {h['start_frame']}'s camera, map frame "
                                             f"{h['frame_id']})"))
    return ", ".join(parts)


def slam_maps(s: dict[str, Any] | None) -> int:
    """How many SLAM maps a run's summary reports (1 for a summary written before maps were counted)."""
    return int(((s or {}).get("slam") or {}).get("maps", 1))


def _num(v: float | None, fmt: str, unit: str = "") -> str:
    return "n/a" if v is None else f"{format(v, fmt)}{unit}"


def detect_text(out: Path, s: dict[str, Any]) -> str:
    """``slz detect`` on one recording: the verdict first, then how it was reached and where the files are."""
    t = s["timings_ms"]
    maps = slam_maps(s)
    lost = (s.get("slam") or {}).get("frames_untracked")
    head = (f"{s['source']}: {s['frames']} frames" + (f" ({lost} not tracked)" if lost else "")
            + f", {s['detections']} detections ({s['method']}, "
            f"SLAM {s['slam_backend']}" + (f", {maps} maps)" if maps > 1 else ")"))
    if s.get("skipped"):
        head += " [skipped: done before with the same config and input bytes; --force redoes it]"
    if s["status"] == "site":
        x, y, z = s["site_world"]
        where = f"SLAM map {s['slam']['segment']}'s world frame" if maps > 1 else "the run's world frame"
        result = f"landing site at ({x:.2f}, {y:.2f}, {z:.2f}) m in {where}"
        if s.get("site_height"):
            result += f": {height_text(s['site_height'])}"
    else:
        result = f"no safe site: {s['reason']}"
    lines = [head, "  " + result]
    noise, lim = s.get("depth_noise") or {}, s.get("depth_limits")
    if lim:
        a = noise.get("a_per_m_median", noise.get("a_per_m"))
        where = f"a = {a:.4f} 1/m ({noise.get('source')}), " if a is not None else ""
        lines.append(f"  depth noise: {where}sigma {lim['sigma_m']:.3f} m at {lim['altitude_m']:.1f} m; maps on "
                     f"{lim['block_px']} px blocks; steps >= {lim['step_min_m']:.2f} m and slopes >= "
                     f"{lim['slope_min_deg']:.1f} deg detectable"
                     + ("" if noise.get("detections_not_vouched", 0) == 0 else
                        f"; {noise['detections_not_vouched']} detection frame(s) could not vouch"))
    write = f", write {t['write']:.1f} ms" if "write" in t else ""  # a run.json from before write was summarised
    if "write_wait" in t:  # the writer runs beside the loop: what it cost the loop is the wait
        write += f" in the background (the loop waited {t['write_wait']:.1f} ms)"
    lines.append(f"  per frame: maps {t['maps']:.1f} ms, {s['method']} {t[s['method']]:.1f} ms, "
                 f"mask {t['mask']:.1f} ms, slam {t['slam']:.1f} ms, select {t['select']:.1f} ms{write} (medians)")
    gt = s.get("ground_truth")
    if gt and gt.get("mask"):
        m = gt["mask"]
        lines.append(f"  vs ground truth: mask precision {_num(m['precision'], '.3f')}, recall "
                     f"{_num(m['recall'], '.3f')}, IoU {_num(m['iou'], '.3f')}"
                     + (f"; site safe: {gt['site']['safe']}, clearance {gt['site']['clearance_m']:.2f} m"
                        if gt.get("site") else ""))
    frames = {"summary": "", "maps": ", frames/ (maps.npz, overlay.png)", "all": ", frames/"}.get(
        s.get("outputs", "all"), ", frames/")
    mcap = ", results.mcap" if (out / "results.mcap").exists() else ""
    lines.append(f"  results: {out}/report.html (open it first); also landing.json, run.json, sites.csv, "
                 f"points.ply{mcap}{frames}")
    return "\n".join(lines)


def batch_text(t: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """A batch of ``slz detect``: one line per recording, then the totals and the summary files."""
    lines = []
    for r in rows:
        name = Path(r["run"]).name
        if r["status"] == "site":
            x, y, z = r["site_world"]
            what = f"site at ({x:.2f}, {y:.2f}, {z:.2f}) m"
        else:
            what = "no safe site" + (f": {r['summary']['reason']}" if r.get("summary") else "")
        done = "skipped (done before)" if r.get("skipped") else f"{r['frames']} frames in {r['wall_s']:.1f} s"
        maps = slam_maps(r.get("summary"))
        lines.append(f"  {name}: {what}; {done}" + (f"; {maps} SLAM maps" if maps > 1 else ""))
    return "\n".join([
        f"{t['recordings']} recordings ({t['engine']}, {t['workers']} worker(s)): {t['site']} with a site, "
        f"{t['no_safe_site']} without, {t['skipped']} skipped as done before",
        *lines,
        f"  {t['processed']} processed: {t['frames']} frames in {t['wall_s']:.1f} s = "
        f"{_num(t['frames_per_s'], '.2f')} frames/s, {_num(t['recordings_per_min'], '.1f')} recordings/min",
        f"  summary: {', '.join(t['summary_files'])}"])


def simulate_text(m: dict[str, Any], out: Path) -> str:
    """One simulated landing: the outcome, then its figures (s to 0.1, m to 0.01, px and deg to 0.1)."""
    phases = m.get("phases_s") or {}
    shown = [f"{name} {v:.1f} s" for name, v in phases.items() if v is not None]
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
