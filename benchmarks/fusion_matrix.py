"""The per-frame path against the terrain fused over the flight, on rendered flights with ground truth.

    python benchmarks/fusion_matrix.py --cache DIR [--flights GLOB] [--every 3] [--out NAME] [--set K=V] [--fused-only]

Flights: benchmarks/fusion_render.py's cache (slz synth's scenes, sensors and flights, true poses). Per
flight, every frame goes through both paths with the true pose and the run's noise estimate
(``NoiseTracker``, as ``slz detect`` does):
- per frame: ``frame_maps`` -> fuzzy score -> ``mask_score`` (METHOD 2.3-2.4) on every ``--every``-th frame;
- fused: every frame into ``FusedTerrain``; on the same frames the verdict of the cells in view, rendered
  into the frame's pixels (``verdict_in_frame``).
Reported per flight (``--fused-only``: the fused path alone): pixel precision and recall of the mask
against the truth's safe pixels (summed over those frames), frames that vouched (per frame) or had a safe
cell (fused), the undecided share of the frame's pixels with depth (fused), the site (fused: ``best_site``
of the last frame, truly safe in the raster?; per frame: a proxy, the mask pixel deepest inside the mask
over the flight, truly safe?), the fused safe cells of the last frame's region whose centre the truth
raster calls unsafe (and the unsafe cells it calls safe), the smallest step the fused noise lets through
(median over the cells in view at the end; and the smallest on a decided cell), the advice, and the
fusion's CPU time per frame (``time.process_time``: a core's time, not the loaded machine's wall clock).
Writes benchmarks/results/fusion_matrix[_NAME].json and prints a table.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent


def _truth_cell_safe(d: Any, x: float, y: float) -> bool:
    rs, org, res = d["raster_safe"], d["raster_origin"], float(d["raster_res"])
    c, r = math.floor((x - org[0]) / res), math.floor((y - org[1]) / res)
    return bool(0 <= r < rs.shape[0] and 0 <= c < rs.shape[1] and rs[r, c])


def _cells_truly_safe(d: Any, fm: Any, code: int) -> tuple[int, int]:
    """(cells of the fused verdict ``code``, of them the ones whose centre the truth raster calls safe)."""
    reg = fm.region
    jj, ii = np.nonzero(fm.verdict == code)
    x = reg.origin_m[0] + (ii + 0.5) * reg.cell_m
    y = reg.origin_m[1] + (jj + 0.5) * reg.cell_m
    rs, org, res = d["raster_safe"], d["raster_origin"], float(d["raster_res"])
    c, r = np.floor((x - org[0]) / res).astype(int), np.floor((y - org[1]) / res).astype(int)
    inside = (r >= 0) & (r < rs.shape[0]) & (c >= 0) & (c < rs.shape[1])
    truth = np.zeros(jj.size, bool)
    truth[inside] = rs[r[inside], c[inside]].astype(bool)
    return int(jj.size), int(np.count_nonzero(truth))


def run_flight(path: Path, every: int, sets: list[str], fused_only: bool = False) -> dict[str, Any]:
    from dataclasses import replace

    from slzcli.config import load_config
    from slzcli.fusion.session import FusedTerrain, verdict_in_frame
    from slzcli.fusion.verdict import SAFE, UNDECIDED, UNSAFE
    from slzcli.scoring import MaskParams, get_scorer, mask_score
    from slzcli.terrain.maps import MapParams, frame_maps
    from slzcli.terrain.noise import NoiseTracker
    from slzcli.types import Frame, Intrinsics

    cfg = load_config(None, sets)
    d = np.load(path)
    k = d["K"]
    intr = Intrinsics(float(k[0]), float(k[1]), float(k[2]), float(k[3]), int(k[4]), int(k[5]))
    scorer = get_scorer(cfg.scoring, cfg.mask, "fuzzy")
    ft = FusedTerrain(cfg, scorer)
    tracker = NoiseTracker(cfg.terrain.noise, cfg.terrain.noise_estimate)
    cnt = {p: {"tp": 0, "fp": 0, "fn": 0} for p in ("frame", "fused")}
    vouched = fused_frames = 0
    undecided: list[float] = []
    cpu: list[float] = []
    best_frame: tuple[float, bool] | None = None
    fm = None
    depth_all, T_all, safe_all = d["depth"], d["T"], d["safe"]
    for i in range(len(T_all)):
        depth, T, truth = depth_all[i], T_all[i], safe_all[i].astype(bool)
        noise = tracker.update(depth)
        t0 = time.process_time()
        ft.add(depth, intr, T, noise, 0, i)
        cpu.append((time.process_time() - t0) * 1e3)
        if i % every != every - 1 and i != len(T_all) - 1:
            continue
        frame = Frame(index=i, stamp_ns=int(d["stamps"][i]), rgb=np.zeros((intr.height, intr.width, 3), np.uint8),
                      depth_m=depth, intrinsics=intr, T_world_camera=T)
        if fused_only:
            per = np.zeros_like(truth)
        else:
            maps = frame_maps(frame, MapParams.of(cfg), noise)
            sm = mask_score(scorer, scorer(maps), depth, intr, MaskParams.of(cfg), maps.work, maps.up_camera)
            per = sm.mask
            vouched += bool(maps.work is None or maps.work.vouched)
        fm = ft.maps_in_view()
        assert fm is not None
        fused = verdict_in_frame(fm, depth, intr, T)
        fused_frames += bool(fused.any())
        for name, m in (("frame", per), ("fused", fused)):
            cnt[name]["tp"] += int(np.count_nonzero(m & truth))
            cnt[name]["fp"] += int(np.count_nonzero(m & ~truth))
            cnt[name]["fn"] += int(np.count_nonzero(~m & truth))
        valid = np.isfinite(depth)
        und = _render_code(fm, depth, intr, T, UNDECIDED)
        undecided.append(float(np.count_nonzero(und & valid)) / max(1, int(np.count_nonzero(valid))))
        if per.any():
            dist = cv2.distanceTransform(per.astype(np.uint8), cv2.DIST_L2, 5)
            v, u = np.unravel_index(int(np.argmax(dist)), dist.shape)
            if best_frame is None or dist[v, u] > best_frame[0]:
                best_frame = (float(dist[v, u]), bool(truth[v, u]))
    assert fm is not None
    site = ft.site(fm)
    adv = ft.advice(fm)
    reg = fm.region
    step_seen = fm.step_min_m[reg.seen & np.isfinite(fm.step_min_m)]
    dec = fm.decided & reg.seen
    n_safe, n_safe_ok = _cells_truly_safe(d, fm, SAFE)
    _, n_unsafe_ok = _cells_truly_safe(d, fm, UNSAFE)
    out: dict[str, Any] = {"flight": path.name, "frames": len(T_all), "every": every}
    for name in ("fused",) if fused_only else ("frame", "fused"):
        c = cnt[name]
        out[f"{name}_precision"] = c["tp"] / (c["tp"] + c["fp"]) if c["tp"] + c["fp"] else None
        out[f"{name}_recall"] = c["tp"] / (c["tp"] + c["fn"]) if c["tp"] + c["fn"] else None
    out.update({
        "frame_vouched_frames": None if fused_only else vouched, "fused_frames_with_safe": fused_frames,
        "frame_site_proxy_safe": None if best_frame is None else best_frame[1],
        "fused_site": None if site is None else {"x_m": round(site.x_m, 3), "y_m": round(site.y_m, 3),
                                                 "clearance_m": round(site.clearance_m, 3),
                                                 "looks": round(site.looks, 1),
                                                 "truly_safe": _truth_cell_safe(d, site.x_m, site.y_m)},
        "undecided_share_last": undecided[-1], "undecided_share_mean": float(np.mean(undecided)),
        "step_min_median_m": float(np.median(step_seen)) if step_seen.size else None,
        "safe_cells_truly_unsafe": n_safe - n_safe_ok, "unsafe_cells_truly_safe": n_unsafe_ok,
        "step_min_decided_min_m": float(np.min(fm.step_min_m[dec])) if dec.any() else None,
        "looks_median": float(np.median(reg.looks[reg.seen])) if reg.seen.any() else None,
        "verdict_cells": fm.counts(), "advice": None if adv is None else adv.as_dict(),
        "fuse_cpu_ms_median": float(np.median(cpu)), "fuse_cpu_ms_p90": float(np.percentile(cpu, 90)),
        "noise": tracker.summary(), "grid_mb": round(ft.grid.nbytes() / 1e6, 1) if ft.grid is not None else None,
    })
    del replace
    return out


def _render_code(fm: Any, depth: np.ndarray, intr: Any, T: np.ndarray, code: int) -> np.ndarray:
    """Pixels whose cell has verdict ``code`` (``verdict_in_frame`` for any code)."""
    from dataclasses import replace

    from slzcli.fusion.session import verdict_in_frame
    from slzcli.fusion.verdict import SAFE

    as_safe = np.where(fm.verdict == code, np.uint8(SAFE), np.uint8(0))
    return verdict_in_frame(replace(fm, verdict=as_safe), depth, intr, T)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache",
                    help="rendered flights (benchmarks/fusion_render.py --out)")
    ap.add_argument("--flights", default="*")
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--out", default="")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--fused-only", action="store_true", help="skip the per-frame path (its numbers are null)")
    a = ap.parse_args()
    rows = []
    for p in sorted(glob.glob(str(a.cache / (a.flights + ".npz")))):
        if p.endswith(".tmp.npz"):
            continue
        r = run_flight(Path(p), a.every, a.set, a.fused_only)
        rows.append(r)
        site = r["fused_site"]
        print(f"{r['flight']:48s} frame P {_f(r.get('frame_precision'))} R {_f(r.get('frame_recall'))} "
              f"vouched {r['frame_vouched_frames']} | fused P {_f(r['fused_precision'])} R {_f(r['fused_recall'])} "
              f"und {r['undecided_share_last']:.2f} site {'-' if site is None else site['truly_safe']} "
              f"step {_f(r['step_min_median_m'])} looks {_f(r['looks_median'], 1)} "
              f"cpu {r['fuse_cpu_ms_median']:.1f} ms | {(r['advice'] or {}).get('text', '')}", flush=True)
    name = f"fusion_matrix_{a.out}.json" if a.out else "fusion_matrix.json"
    (HERE / "results" / name).write_text(json.dumps({"set": a.set, "every": a.every, "flights": rows}, indent=1)
                                         + "\n")


def _f(x: float | None, nd: int = 3) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


if __name__ == "__main__":
    main()
