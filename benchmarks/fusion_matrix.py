"""The per-frame path against the terrain fused over the flight, over every rendered flight of a cache: the
flight matrix of METHOD 2.3.6 and docs/MEASUREMENTS.md.

    python benchmarks/fusion_matrix.py [--cache DIR] [--flights GLOB] [--every 3] [--set K=V]
                                       [--out FILE] [--markdown FILE] [--plot PNG] [--fused-only]

Flights: every ``SCENE_ALTm_SENSOR_MOTION_sSEED_NfRhz.npz`` of benchmarks/fusion_render.py's cache (slz synth's
scenes, sensors and flights, true poses, ground truth). Per flight, every frame goes through both paths with
the true pose and the run's noise estimate (``NoiseTracker``, as ``slz detect`` does):
- per frame: ``frame_maps`` -> fuzzy score -> ``mask_score`` (METHOD 2.3-2.4) on every ``--every``-th frame
  (and the last);
- fused: every frame into ``FusedTerrain``; on the same frames the verdict of the cells in view, rendered
  into the frame's pixels (``verdict_in_frame``).
Per flight: pixel precision and recall of each mask against the truth's safe pixels (counts summed over those
frames); the site (fused: ``best_site`` of each of those frames and of the last, truly safe by the truth
raster at its centre?; per frame: a proxy, the mask pixel deepest inside the mask over the flight, truly
safe?); the undecided share of the last frame's pixels with depth; the smallest step each path lets through
(per frame: the working scale's limit, median over the frames; fused: per cell, median over the cells seen
by at least half the flight's frames, and the smallest on a decided cell); the fused safe cells whose centre
the truth calls unsafe; calibration (fused height - true height, the flight's common depth bias removed,
over the stated std, on level cells: robust spread 1.4826 MAD, std, share beyond 3); the advice; CPU per
frame (``time.process_time``: a core's time, not the loaded machine's wall clock).

Restartable: each flight's row is kept in the results JSON with the hash of the code its numbers came from
(the sources of the ``slzcli`` modules each path imports, the config files, the measuring functions here)
and of the arguments; a rerun recomputes only the rows whose hash or flight file changed (a change in
``slzcli/fusion`` recomputes the fused path alone). Then the cells (scene x altitude x sensor x motion, over
seeds) and the issue's targets are aggregated into the JSON, a markdown file and a plot.
"""

from __future__ import annotations

import ast
import glob
import hashlib
import inspect
import json
import math
import os
import re
import sys
import tempfile
import textwrap
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np

NAME = "fusion_matrix"
FLIGHT = re.compile(r"^(?P<scene>.+)_(?P<alt>[0-9.]+)m_(?P<sensor>[^_]+)_(?P<motion>hover|[0-9.]+)_s(?P<seed>[0-9]+)"
                    r"_(?P<frames>[0-9]+)f(?P<rate>[0-9.]+)hz$")
OPEN_SCENES = ("clear_field", "parking_lot", "office")   # the open scenes
LEVEL_M = 0.01            # m; a cell is level ground when the true heights over it and its 8 neighbours span less
OPEN_CELLS = 6            # cells (0.49 m); open ground is this far from ground that is not level: on the D435 flights
                          # the error spread near objects falls to its plateau 4-6 cells out (edge fattening)
PRECISION_TARGET = 0.98
CALIBRATION = (0.8, 1.25)
MIN_TARGET_MOTION_M = 3.0
ALTITUDES = (5.0, 7.5, 10.0, 12.0)        # m; the matrix
MOTIONS: tuple[str | float, ...] = ("hover", 2.0, 4.0, 8.0)


# ---------------------------------------------------------------- flights and the code they were measured with

def parse_name(stem: str) -> dict[str, Any] | None:
    """The flight's cell and seed from its file name (None: not a flight of fusion_render.py)."""
    m = FLIGHT.match(stem)
    if m is None:
        return None
    motion = m["motion"]
    return {"scene": m["scene"], "altitude_m": float(m["alt"]), "sensor": m["sensor"],
            "motion": motion if motion == "hover" else float(motion), "seed": int(m["seed"]),
            "frames": int(m["frames"]), "rate_hz": float(m["rate"])}


def _import_paths() -> None:
    """Import what both paths use, lazily imported modules included, so the code hash sees them all."""
    import slzcli.config
    import slzcli.fusion.advice
    import slzcli.fusion.session
    import slzcli.scoring
    import slzcli.terrain.limits
    import slzcli.terrain.maps
    import slzcli.terrain.noise  # noqa: F401


def _hash_files(files: list[Path], extra: str) -> str:
    """A hash of what the files do, not how they are commented: Python as its syntax tree without docstrings,
    YAML as the data it loads to (a comment or a moved test path in a docstring recomputes nothing)."""
    h = hashlib.sha256(_semantic(extra).encode())
    for f in sorted(set(files)):
        h.update(str(f.relative_to(harness.REPO)).encode())
        h.update(_semantic(f.read_text(), f.suffix).encode())
    return h.hexdigest()[:16]


def _semantic(text: str, suffix: str = ".py") -> str:
    if suffix in (".yaml", ".yml"):
        import yaml
        return json.dumps(yaml.safe_load(text), sort_keys=True)
    tree = ast.parse(textwrap.dedent(text))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            node.body = body[1:] or [ast.Pass()]  # type: ignore[attr-defined]
    return ast.dump(tree)


def _module_files(prefix_out: str | None) -> list[Path]:
    files = []
    for name, mod in list(sys.modules.items()):
        if not (name == "slzcli" or name.startswith("slzcli.")):
            continue
        if prefix_out and (name == prefix_out or name.startswith(prefix_out + ".")):
            continue
        f = getattr(mod, "__file__", None)
        if f:
            files.append(Path(f).resolve())
    return files


def code_keys(every: int, sets: list[str]) -> dict[str, str]:
    """The hash each path's numbers depend on: the per-frame path on every slzcli module it imports except the
    fusion, the fused path on all of them; both on the config files, this script's measuring code and the
    arguments."""
    _import_paths()
    configs = sorted((harness.REPO / "slzcli" / "configs").glob("*.yaml"))
    args = f"ARGS = {json.dumps({'every': every, 'set': sets})!r}\n"
    return {"frame": _hash_files(_module_files("slzcli.fusion") + configs, args + _source(measure_frame_path)),
            "fused": _hash_files(_module_files(None) + configs,
                                 args + _source(measure_fused_path, _cells_truly_safe, cell_truth, calibration,
                                                _render_code, _step_stats, predicted_step_m, _predictions))}


def _source(*fns: Callable[..., Any]) -> str:
    return "".join(textwrap.dedent(inspect.getsource(f)) for f in fns)


def _file_id(p: Path) -> dict[str, int]:
    st = p.stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


# ---------------------------------------------------------------- one flight

class Flight:
    """A cached flight and its replay state shared by both paths (the noise estimate, the frames due)."""

    def __init__(self, path: Path, every: int, sets: list[str]) -> None:
        from slzcli.config import load_config
        from slzcli.scoring import get_scorer
        from slzcli.terrain.noise import NoiseTracker
        from slzcli.types import Intrinsics

        self.path = path
        self.cfg = load_config(None, sets)
        self.d = np.load(path)
        k = self.d["K"]
        self.intr = Intrinsics(float(k[0]), float(k[1]), float(k[2]), float(k[3]), int(k[4]), int(k[5]))
        self.scorer = get_scorer(self.cfg.scoring, self.cfg.mask, "fuzzy")
        self.depth, self.T, self.safe = self.d["depth"], self.d["T"], self.d["safe"]
        self.n = len(self.T)
        self.due = [i for i in range(self.n) if i % every == every - 1 or i == self.n - 1]
        tracker = NoiseTracker(self.cfg.terrain.noise, self.cfg.terrain.noise_estimate)
        self.noise = [tracker.update(self.depth[i]) for i in range(self.n)]
        self.noise_summary = tracker.summary()


def _counts(m: np.ndarray, truth: np.ndarray, c: dict[str, int]) -> None:
    c["tp"] += int(np.count_nonzero(m & truth))
    c["fp"] += int(np.count_nonzero(m & ~truth))
    c["fn"] += int(np.count_nonzero(~m & truth))


def _pr(c: dict[str, int]) -> tuple[float | None, float | None]:
    return (c["tp"] / (c["tp"] + c["fp"]) if c["tp"] + c["fp"] else None,
            c["tp"] / (c["tp"] + c["fn"]) if c["tp"] + c["fn"] else None)


def measure_frame_path(fl: Flight) -> dict[str, Any]:
    """The per-frame path (fuzzy score, mask) on the frames due."""
    from slzcli.scoring import MaskParams, mask_score
    from slzcli.terrain.maps import MapParams, frame_maps
    from slzcli.types import Frame

    c = {"tp": 0, "fp": 0, "fn": 0}
    vouched = 0
    steps: list[float] = []
    cpu: list[float] = []
    best: tuple[float, bool] | None = None
    for i in fl.due:
        depth, truth = fl.depth[i], fl.safe[i].astype(bool)
        frame = Frame(index=i, stamp_ns=int(fl.d["stamps"][i]),
                      rgb=np.zeros((fl.intr.height, fl.intr.width, 3), np.uint8), depth_m=depth,
                      intrinsics=fl.intr, T_world_camera=fl.T[i])
        t0 = time.process_time()
        maps = frame_maps(frame, MapParams.of(fl.cfg), fl.noise[i])
        m = mask_score(fl.scorer, fl.scorer(maps), depth, fl.intr, MaskParams.of(fl.cfg), maps.work,
                       maps.up_camera).mask
        cpu.append((time.process_time() - t0) * 1e3)
        vouched += bool(maps.work is None or maps.work.vouched)
        steps.append(0.0 if maps.work is None else float(maps.work.step_min_m))
        _counts(m, truth, c)
        if m.any():
            dist = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 5)
            v, u = np.unravel_index(int(np.argmax(dist)), dist.shape)
            if best is None or dist[v, u] > best[0]:
                best = (float(dist[v, u]), bool(truth[v, u]))
    p, r = _pr(c)
    return {"frame_counts": c, "frame_precision": p, "frame_recall": r, "frame_vouched_frames": vouched,
            "frame_detection_frames": len(fl.due), "frame_site_proxy_safe": None if best is None else best[1],
            "frame_step_limit_m": float(np.median(steps)), "frame_cpu_ms_median": float(np.median(cpu))}


def measure_fused_path(fl: Flight) -> dict[str, Any]:
    """The fused path: every frame fused, the verdict on the frames due."""
    from slzcli.fusion.advice import GroundTrack
    from slzcli.fusion.grid import region, seen_bounds
    from slzcli.fusion.session import FusedTerrain, verdict_in_frame
    from slzcli.fusion.verdict import SAFE, UNDECIDED, UNSAFE

    ft = FusedTerrain(fl.cfg, fl.scorer)
    track = GroundTrack()          # hover or flight, as the fused method tells them (methods/fused.py)
    c = {"tp": 0, "fp": 0, "fn": 0}
    with_safe = 0
    sites_unsafe = sites = 0
    cpu: list[float] = []
    cpu_verdict: list[float] = []
    curve: list[dict[str, Any]] = []
    und_last = 0.0
    fm = None
    for i in range(fl.n):
        depth, T = fl.depth[i], fl.T[i]
        t0 = time.process_time()
        ft.add(depth, fl.intr, T, fl.noise[i], 0, i)
        track.add(0, int(fl.d["stamps"][i]), T)
        cpu.append((time.process_time() - t0) * 1e3)
        if i not in fl.due:
            continue
        t0 = time.process_time()
        fm = ft.maps_in_view()
        cpu_verdict.append((time.process_time() - t0) * 1e3)
        assert fm is not None
        truth = fl.safe[i].astype(bool)
        fused = verdict_in_frame(fm, depth, fl.intr, T)
        with_safe += bool(fused.any())
        _counts(fused, truth, c)
        site = ft.site(fm)
        if site is not None:
            sites += 1
            sites_unsafe += not _truth_cell_safe(fl.d, site.x_m, site.y_m)
        valid = np.isfinite(depth)
        und = _render_code(fm, depth, fl.intr, T, UNDECIDED)
        und_last = float(np.count_nonzero(und & valid)) / max(1, int(np.count_nonzero(valid)))
        curve.append({"frame": i, **_step_stats(fm, i + 1)})
    assert fm is not None
    site = ft.site(fm)
    adv = ft.advice(fm, track.hovering(fl.cfg.terrain.fusion.hover_speed_m_s))
    reg = fm.region
    n_safe, n_safe_ok = _cells_truly_safe(fl.d, fm, SAFE)
    _, n_unsafe_ok = _cells_truly_safe(fl.d, fm, UNSAFE)
    p, r = _pr(c)
    assert ft.grid is not None
    b = seen_bounds(ft.grid)
    cal = calibration(fl.d, region(ft.grid, *b)) if b is not None else None
    return {
        "fused_counts": c, "fused_precision": p, "fused_recall": r, "fused_frames_with_safe": with_safe,
        "fused_sites_over_frames": sites, "fused_sites_over_frames_truly_unsafe": sites_unsafe,
        "fused_site": None if site is None else {
            "x_m": round(site.x_m, 3), "y_m": round(site.y_m, 3), "clearance_m": round(site.clearance_m, 3),
            "looks": round(site.looks, 1), "step_min_m": round(site.step_min_m, 4),
            "truly_safe": _truth_cell_safe(fl.d, site.x_m, site.y_m),
            "raised_m": None if site.raised is None or site.raised.height_m is None else round(site.raised.height_m, 3),
            "raised_cells": None if site.raised is None else site.raised.points},
        "undecided_share_last": und_last, **_step_stats(fm, fl.n), "step_curve": curve,
        "safe_cells": n_safe, "safe_cells_truly_unsafe": n_safe - n_safe_ok, "unsafe_cells_truly_safe": n_unsafe_ok,
        "looks_median": float(np.median(reg.looks[reg.seen])) if reg.seen.any() else None,
        "verdict_cells": fm.counts(), "advice": None if adv is None else adv.as_dict(), "calibration": cal,
        "fuse_cpu_ms_median": float(np.median(cpu)), "fuse_cpu_ms_p90": float(np.percentile(cpu, 90)),
        "verdict_cpu_ms_median": float(np.median(cpu_verdict)),
        "grid_mb": round(ft.grid.nbytes() / 1e6, 1), "predicted_step_m": _predictions(fl, ft.params),
    }


def predicted_step_m(noise: Any, z: float, focal_px: float, motion_m: float, frames: int, cfg: Any,
                     params: Any) -> float:
    """The smallest step the fusion's own model lets through on a cell straight below a level flight at ``z``
    that every one of ``frames`` frames sees, flying ``motion_m`` in a line (0: a still hover; inf: the floor no
    flight lowers, the error fixed to the ground): one frame's limit
    (``frame_limit_ratios``, the per-frame path's) times the std the cell's filter reaches over its one-frame
    std. No noise scale (>= 1 in a run): a lower bound of what a flight of that kind measures."""
    from slzcli.fusion.measure import cell_sigma_m, frame_limit_ratios

    step_ratio, _ = frame_limit_ratios(noise, z, focal_px, cfg, params)
    s1 = float(cell_sigma_m(noise, z, focal_px, params.cell_m))
    if math.isinf(motion_m):      # endless decorrelated looks: only the part fixed to the ground is left
        return step_ratio * math.sqrt(params.fixed_fraction) * s1
    sc2 = s1 * s1 * (1.0 - params.white_fraction - params.fixed_fraction)
    sw2 = s1 * s1 * params.white_fraction
    shift = motion_m / max(frames - 1, 1) * focal_px / z
    rho = min(math.exp(-shift / params.decorrelation_px), 1.0 - 1e-9)
    p_hh, p_hc, p_cc = sc2 + sw2, -sc2, sc2
    for _ in range(frames - 1):
        p_hc, p_cc = rho * p_hc, rho * rho * p_cc + (1 - rho * rho) * sc2
        s_t = p_hh + 2 * p_hc + p_cc + sw2
        kh, kc = (p_hh + p_hc) / s_t, (p_hc + p_cc) / s_t
        p_hh, p_hc, p_cc = p_hh - kh * kh * s_t, p_hc - kh * kc * s_t, p_cc - kc * kc * s_t
    return step_ratio * math.sqrt(p_hh + params.fixed_fraction * s1 * s1)


def _predictions(fl: Flight, params: Any) -> dict[str, dict[str, float]]:
    """``predicted_step_m`` with this flight's noise estimate, at every altitude and motion of the matrix."""
    focal = 0.5 * (fl.intr.fx + fl.intr.fy)
    return {f"{z:g}": {("floor" if m == math.inf else _motion(m)):
                       round(predicted_step_m(fl.noise[-1], z, focal, _motion_m(m), fl.n, fl.cfg, params), 4)
                       for m in (*MOTIONS, math.inf)} for z in ALTITUDES}


def _step_stats(fm: Any, frames_so_far: int) -> dict[str, float | None]:
    """The smallest step the fused noise lets through: median over the cells in view seen by at least half the
    frames so far (the ground the flight kept in view), and the smallest on a decided cell."""
    reg = fm.region
    core = reg.seen & (reg.frames >= 0.5 * frames_so_far) & np.isfinite(fm.step_min_m)
    allc = reg.seen & np.isfinite(fm.step_min_m)
    dec = fm.decided & reg.seen
    return {"step_min_core_m": float(np.median(fm.step_min_m[core])) if core.any() else None,
            "step_min_median_m": float(np.median(fm.step_min_m[allc])) if allc.any() else None,
            "step_min_decided_min_m": float(np.min(fm.step_min_m[dec])) if dec.any() else None}


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


def _render_code(fm: Any, depth: np.ndarray, intr: Any, T: np.ndarray, code: int) -> np.ndarray:
    """Pixels whose cell has verdict ``code`` (``verdict_in_frame`` for any code)."""
    from dataclasses import replace

    from slzcli.fusion.session import verdict_in_frame
    from slzcli.fusion.verdict import SAFE

    as_safe = np.where(fm.verdict == code, np.uint8(SAFE), np.uint8(0))
    return verdict_in_frame(replace(fm, verdict=as_safe), depth, intr, T)


def cell_truth(d: Any, reg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(true mean height of every cell of the region, level: the true heights over the cell and its 8 neighbours
    span less than LEVEL_M) from the truth raster, sampled 3 x 3 times per cell (NaN / False outside it)."""
    hr, org, res = d["raster_height"], d["raster_origin"], float(d["raster_res"])
    ny, nx = reg.shape
    x0, y0 = reg.origin_m
    c = reg.cell_m
    samples = []
    for fy in (1 / 6, 1 / 2, 5 / 6):
        for fx in (1 / 6, 1 / 2, 5 / 6):
            col = np.floor((x0 + (np.arange(nx) + fx) * c - org[0]) / res).astype(int)
            row = np.floor((y0 + (np.arange(ny) + fy) * c - org[1]) / res).astype(int)
            ok = (row[:, None] >= 0) & (row[:, None] < hr.shape[0]) & (col[None, :] >= 0) & (col[None, :] < hr.shape[1])
            v = hr[np.clip(row, 0, hr.shape[0] - 1)[:, None], np.clip(col, 0, hr.shape[1] - 1)[None, :]]
            samples.append(np.where(ok, v, np.nan).astype(np.float32))
    s = np.stack(samples)
    inside = np.all(np.isfinite(s), axis=0)
    h = np.where(inside, np.mean(s, axis=0), np.nan)
    lo = np.where(inside, np.min(s, axis=0), -np.inf).astype(np.float32)
    hi = np.where(inside, np.max(s, axis=0), np.inf).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    lo3 = cv2.erode(lo, k, borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    hi3 = cv2.dilate(hi, k, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)
    return h, inside & (hi3 - lo3 < LEVEL_M)


def calibration(d: Any, reg: Any) -> dict[str, Any] | None:
    """Fused height error over its stated std on the level cells the flight saw, the flight's common depth bias
    (the stereo model's subpixel bias, harmless to flatness) removed by the median error: on open ground (more
    than OPEN_CELLS from any cell that is not level, beyond the matcher's edge fattening, and from the edge of the
    region, the seen ground's bounding box, whose rim few frames saw) and near either."""
    h_true, level = cell_truth(d, reg)
    ok = reg.seen & level & np.isfinite(reg.h) & (reg.var > 0)
    if np.count_nonzero(ok) < 50:
        return None
    dist = cv2.distanceTransform(level.astype(np.uint8), cv2.DIST_L2, 5)
    err = reg.h - h_true
    bias = float(np.median(err[ok]))
    z = (err - bias) / np.sqrt(np.where(ok, reg.var, 1.0))
    out: dict[str, Any] = {"bias_m": round(bias, 4)}
    for name, sel in (("open", ok & (dist > OPEN_CELLS)), ("near", ok & (dist <= OPEN_CELLS))):
        if np.count_nonzero(sel) < 50:
            out[name] = None
            continue
        zc = z[sel] - np.median(z[sel])
        e = err[sel] - bias
        out[name] = {"cells": int(sel.sum()), "spread_robust": round(1.4826 * float(np.median(np.abs(zc))), 3),
                     "spread_std": round(float(np.std(zc)), 3), "beyond_3": round(float(np.mean(np.abs(zc) > 3)), 4),
                     "error_robust_m": round(1.4826 * float(np.median(np.abs(e - np.median(e)))), 4),
                     "sigma_median_m": round(float(np.median(np.sqrt(reg.var[sel]))), 4)}
    out["spread_robust"] = (out["open"] or {}).get("spread_robust")
    return out


# ---------------------------------------------------------------- the matrix

def cell_key(r: dict[str, Any]) -> tuple[str, float, str, str]:
    return r["scene"], r["altitude_m"], r["sensor"], _motion(r["motion"])


def _motion(m: str | float) -> str:
    return "hover" if m == "hover" else f"{float(m):g}"


def _motion_m(m: str | float) -> float:
    return 0.0 if m == "hover" else float(m)


def _site_word(x: bool | None) -> str:
    return "none" if x is None else ("yes" if x else "NO")


def aggregate(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per cell (scene x altitude x sensor x motion), over its seeds: pooled pixel counts, sites, the rest."""
    groups: dict[tuple[str, float, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[cell_key(r)].append(r)
    cells = []
    for key in sorted(groups, key=lambda k: (k[2], k[1], k[0], _motion_m(k[3]))):
        rs = sorted(groups[key], key=lambda r: r["seed"])
        out: dict[str, Any] = dict(zip(("scene", "altitude_m", "sensor", "motion"), key, strict=True))
        out["seeds"] = [r["seed"] for r in rs]
        for path in ("frame", "fused"):
            have = [r for r in rs if f"{path}_counts" in r]
            tot = {k: sum(r[f"{path}_counts"][k] for r in have) for k in ("tp", "fp", "fn")}
            out[f"{path}_precision"], out[f"{path}_recall"] = _pr(tot) if have else (None, None)
        out["frame_sites"] = [_site_word(r.get("frame_site_proxy_safe")) for r in rs]
        out["fused_sites"] = [_site_word(None if r.get("fused_site") is None else r["fused_site"]["truly_safe"])
                              for r in rs]
        out["fused_sites_over_frames_truly_unsafe"] = sum(r.get("fused_sites_over_frames_truly_unsafe", 0) for r in rs)
        out["safe_cells_truly_unsafe"] = sum(r.get("safe_cells_truly_unsafe", 0) for r in rs)
        out["frame_vouched"] = [r.get("frame_vouched_frames") for r in rs]
        out["undecided_share_last"] = _mean([r.get("undecided_share_last") for r in rs])
        out["frame_step_limit_m"] = _median([r.get("frame_step_limit_m") for r in rs])
        out["step_min_core_m"] = _median([r.get("step_min_core_m") for r in rs])
        decided = [float(r["step_min_decided_min_m"]) for r in rs if r.get("step_min_decided_min_m") is not None]
        out["step_min_decided_min_m"] = min(decided) if decided else None
        spreads = [r["calibration"]["spread_robust"] for r in rs if (r.get("calibration") or {}).get("spread_robust")]
        out["calibration_spread"] = [min(spreads), max(spreads)] if spreads else None
        out["fuse_cpu_ms_median"] = _median([r.get("fuse_cpu_ms_median") for r in rs])
        out["verdict_cpu_ms_median"] = _median([r.get("verdict_cpu_ms_median") for r in rs])
        out["frame_cpu_ms_median"] = _median([r.get("frame_cpu_ms_median") for r in rs])
        out["advice"] = [(r.get("advice") or {}).get("text") for r in rs]
        cells.append(out)
    return cells


def _mean(xs: list[float | None]) -> float | None:
    v = [x for x in xs if x is not None]
    return float(np.mean(v)) if v else None


def _median(xs: list[float | None]) -> float | None:
    v = [x for x in xs if x is not None]
    return float(np.median(v)) if v else None


def targets(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The issue's targets, each with what it was measured on and pass / fail (None: nothing to measure)."""
    out = []
    for path in ("fused", "frame"):
        pk = f"{path}_precision"
        called = [r for r in rows if f"{path}_counts" in r and r[f"{path}_counts"]["tp"] + r[f"{path}_counts"]["fp"]]
        low = [f"{r['flight']} {r[pk]:.3f}" for r in called if r[pk] < PRECISION_TARGET]
        out.append({"target": f"precision >= {PRECISION_TARGET} wherever anything is called safe ({path})",
                    "measured_on": f"{len(called)} flights with safe pixels",
                    "result": (f"lowest {min(r[pk] for r in called):.3f}" if called else "nothing safe")
                    + (f"; below: {', '.join(low)}" if low else ""),
                    "pass": (not low) if called else None})
    fused = [r for r in rows if "fused_counts" in r]
    bad_final = [r["flight"] for r in fused if r.get("fused_site") and not r["fused_site"]["truly_safe"]]
    n_sites = sum(r.get("fused_site") is not None for r in fused)
    bad_any = sum(r["fused_sites_over_frames_truly_unsafe"] for r in fused)
    n_any = sum(r["fused_sites_over_frames"] for r in fused)
    out.append({"target": "0 unsafe committed sites in the whole matrix (fused)",
                "measured_on": f"{len(fused)} flights: {n_sites} last-frame sites; {n_any} sites over the "
                "detection frames",
                "result": f"{len(bad_final)} truly unsafe last-frame sites, {bad_any} over the detection frames"
                + (f" ({', '.join(bad_final)})" if bad_final else ""),
                "pass": not bad_final and bad_any == 0})
    frame = [r for r in rows if "frame_counts" in r]
    bad_frame = [r["flight"] for r in frame if r.get("frame_site_proxy_safe") is False]
    n_frame_sites = sum(r.get("frame_site_proxy_safe") is not None for r in frame)
    out.append({"target": "0 unsafe committed sites in the whole matrix (per frame, site proxy)",
                "measured_on": f"{len(frame)} flights, {n_frame_sites} sites",
                "result": f"{len(bad_frame)} truly unsafe" + (f" ({', '.join(bad_frame)})" if bad_frame else ""),
                "pass": not bad_frame})
    for sensor, alts, label in (("d435", (7.5, 8.0), "D435 at 7.5-8 m"), ("d455", (10.0,), "D455 at 10 m")):
        sel = [r for r in fused if r["sensor"] == sensor and r["altitude_m"] in alts
               and _motion_m(r["motion"]) >= MIN_TARGET_MOTION_M and r["scene"] in OPEN_SCENES]
        per_scene = {s: [_site_word(None if r.get("fused_site") is None else r["fused_site"]["truly_safe"])
                         for r in sorted(sel, key=lambda r: (r["seed"], _motion_m(r["motion"]))) if r["scene"] == s]
                     for s in OPEN_SCENES}
        missing = [s for s, v in per_scene.items() if not v]
        ok = all(all(w == "yes" for w in v) for v in per_scene.values())     # on the scenes rendered
        out.append({"target": f"{label} after >= {MIN_TARGET_MOTION_M:g} m of motion: a truly safe site on every "
                    "open scene",
                    "measured_on": f"{len(sel)} flights (motion 4 / 8 m, seeds as rendered)",
                    "result": "; ".join(f"{s}: {' '.join(v) if v else 'not rendered'}" for s, v in per_scene.items()),
                    "pass": None if missing and ok else ok})
    nos = [r for r in fused if r["scene"] == "no_site"]
    out.append({"target": "no_site: never a site", "measured_on": f"{len(nos)} flights",
                "result": "not rendered" if not nos else
                f"{sum(r.get('fused_site') is not None for r in nos)} fused sites, "
                f"{sum(r.get('frame_site_proxy_safe') is not None for r in nos)} per-frame",
                "pass": None if not nos else all(r.get("fused_site") is None for r in nos)})
    hov = [r for r in fused if r["motion"] == "hover"]
    bad_h, undecided_h, advised_h, move_h, safe_h = [], 0, 0, 0, 0
    for r in hov:
        unsafe_site = (r.get("fused_site") is not None and not r["fused_site"]["truly_safe"]) \
            or r["fused_sites_over_frames_truly_unsafe"] > 0 or r["safe_cells_truly_unsafe"] > 0
        if unsafe_site:
            bad_h.append(r["flight"])
        if r.get("fused_site") is None:
            undecided_h += 1
            adv = r.get("advice") or {}
            advised_h += bool(adv.get("text"))
            move_h += bool(adv.get("hover"))
        else:
            safe_h += 1
    out.append({"target": "hovering: undecided with the advice, never unsafe (fused)",
                "measured_on": f"{len(hov)} hover flights",
                "result": f"{undecided_h} without a site ({advised_h} of them with advice, {move_h} saying to move), "
                f"{safe_h} with a truly "
                f"safe site, {len(bad_h)} with anything truly unsafe called safe"
                + (f" ({', '.join(bad_h)})" if bad_h else ""),
                "pass": (not bad_h and advised_h == undecided_h) if hov else None})
    for sensor in sorted({r["sensor"] for r in fused}):
        for moving in (True, False):
            sp = [r["calibration"]["spread_robust"] for r in fused if r["sensor"] == sensor
                  and (r.get("calibration") or {}).get("spread_robust") and (r["motion"] != "hover") == moving]
            if not sp:
                continue
            out.append({"target": f"calibration spread within {CALIBRATION[0]}-{CALIBRATION[1]}: {sensor}, "
                        + ("moving" if moving else "hovering"),
                        "measured_on": f"{len(sp)} flights (level cells)",
                        "result": f"{min(sp):.2f}-{max(sp):.2f} (median {np.median(sp):.2f})",
                        "pass": CALIBRATION[0] <= min(sp) and max(sp) <= CALIBRATION[1]})
    both = [r for r in rows if "frame_counts" in r and "fused_counts" in r]
    fs = sum(bool(r.get("fused_site") and r["fused_site"]["truly_safe"]) for r in both)
    ps = sum(r.get("frame_site_proxy_safe") is True for r in both)
    out.append({"target": "default: flights with a truly safe site, per frame (proxy) vs fused",
                "measured_on": f"{len(both)} flights", "result": f"per frame {ps}, fused {fs}", "pass": None})
    return out


def predictions(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per sensor and scene: the model's smallest step at every altitude and motion (median over its flights'
    noise estimates), and how the flights measured against it (measured core step / predicted at their own
    altitude and motion)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r.get("predicted_step_m"):
            groups[(r["sensor"], r["scene"])].append(r)
    out = []
    for (sensor, scene), rs in sorted(groups.items()):
        first = rs[0]["predicted_step_m"]
        pred = {z: {m: float(np.median([r["predicted_step_m"][z][m] for r in rs])) for m in first[z]} for z in first}
        ratios = [r["step_min_core_m"] / r["predicted_step_m"][f"{r['altitude_m']:g}"][_motion(r["motion"])]
                  for r in rs if r.get("step_min_core_m") and f"{r['altitude_m']:g}" in r["predicted_step_m"]]
        out.append({"sensor": sensor, "scene": scene, "flights": len(rs),
                    "a_per_m": _median([(r.get("noise") or {}).get("a_per_m_median") for r in rs]),
                    "predicted_step_m": pred, "measured_over_predicted": [round(x, 2) for x in sorted(ratios)]})
    return out


# ---------------------------------------------------------------- output

def _f(x: float | None, nd: int = 3) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def markdown(cells: list[dict[str, Any]], tg: list[dict[str, Any]], pred: list[dict[str, Any]],
             rows: list[dict[str, Any]], missing: list[str]) -> str:
    lines = ["| sensor | z m | scene | motion m | seeds | per frame P / R | fused P / R | site per frame (proxy) | "
             "fused site | undecided | step per frame / fused / decided (m) | calibration | CPU fuse / verdict ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        cal = c["calibration_spread"]
        lines.append(
            f"| {c['sensor']} | {c['altitude_m']:g} | {c['scene']} | {c['motion']} | "
            f"{','.join(map(str, c['seeds']))} | {_f(c['frame_precision'])} / {_f(c['frame_recall'])} | "
            f"{_f(c['fused_precision'])} / {_f(c['fused_recall'])} | "
            f"{' '.join(c['frame_sites'])} | {' '.join(c['fused_sites'])} | {_f(c['undecided_share_last'], 2)} | "
            f"{_f(c['frame_step_limit_m'])} / {_f(c['step_min_core_m'])} / {_f(c['step_min_decided_min_m'])} | "
            f"{'-' if cal is None else f'{cal[0]:.2f}-{cal[1]:.2f}'} | "
            f"{_f(c['fuse_cpu_ms_median'], 1)} / {_f(c['verdict_cpu_ms_median'], 0)} |")
    if pred:
        alts = list(pred[0]["predicted_step_m"])
        motions = list(pred[0]["predicted_step_m"][alts[0]])
        lines += ["", "| sensor | scene | a (1/m) | " + " | ".join(f"{z} m: {' / '.join(motions)}" for z in alts)
                  + " | measured / predicted |", "|---|---|---|" + "---|" * len(alts) + "---|"]
        for p in pred:
            lines.append(f"| {p['sensor']} | {p['scene']} | {_f(p['a_per_m'], 5)} | " + " | ".join(
                " / ".join(f"{p['predicted_step_m'][z][m]:.3f}" for m in motions) for z in alts)
                + f" | {' '.join(f'{x:.2f}' for x in p['measured_over_predicted'])} |")
    lines += ["", "| target | measured on | result | pass |", "|---|---|---|---|"]
    for t in tg:
        lines.append(f"| {t['target']} | {t['measured_on']} | {t['result']} | "
                     f"{'-' if t['pass'] is None else ('yes' if t['pass'] else '**no**')} |")
    ft = frames_table(rows)
    if ft:
        lines += ["", ft]
    if missing:
        groups: dict[str, list[str]] = defaultdict(list)
        for name in missing:
            m = re.match(r"^(.+)_([0-9.]+m)_([^_]+)_([^_]+)_(s[0-9]+)$", name)
            if m:
                groups[f"{m[3]} {m[2]} {m[4]}{'' if m[4] == 'hover' else ' m'} {m[5]}"].append(m[1])
        lines += ["", f"Not rendered yet ({len(missing)} queued flights): "
                  + "; ".join(f"{k} ({len(v)} scenes)" for k, v in groups.items())]
    return "\n".join(lines) + "\n"


def frames_table(rows: list[dict[str, Any]], scene: str = "clear_field") -> str:
    """The smallest step the fused map lets through on ``scene`` as the frames come in (median over seeds of the
    median over the cells kept in view), per sensor, altitude and motion."""
    groups: dict[tuple[str, float, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r["scene"] == scene and r.get("step_curve"):
            groups[(r["sensor"], r["altitude_m"], _motion(r["motion"]))].append(r)
    if not groups:
        return ""
    frames = sorted({e["frame"] + 1 for rs in groups.values() for r in rs for e in r["step_curve"]})
    lines = [f"| {scene}: sensor | z m | motion m | " + " | ".join(f"{n} frames" for n in frames) + " |",
             "|---|---|---|" + "---|" * len(frames)]
    for (sensor, z, motion), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], _motion_m(kv[0][2]))):
        vals = []
        for n in frames:
            v = [e["step_min_core_m"] for r in rs for e in r["step_curve"] if e["frame"] + 1 == n
                 and e["step_min_core_m"] is not None]
            vals.append(_f(float(np.median(v)) if v else None))
        lines.append(f"| {sensor} | {z:g} | {motion} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def plot(cells: list[dict[str, Any]], rows: list[dict[str, Any]], pred: list[dict[str, Any]], path: Path,
         tolerance_m: float) -> None:
    """Left: the smallest step the fused map lets through against altitude: each flight measured (markers, the
    median over the cells the flight kept in view), the model (lines: the 4 m transect, solid; the floor no flight
    lowers, dashed; clear_field's noise, the best texture); right: recall and precision per frame against fused,
    per cell."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(11, 3.4), dpi=90)
    colours = {"d435": "#D55E00", "d455": "#0072B2", "gauss0.003": "#009E73"}
    markers = {"hover": "x", "2": "v", "4": "o", "8": "s"}
    for r in rows:
        if r.get("step_min_core_m") is not None:
            ax[0].plot(r["altitude_m"], r["step_min_core_m"], markers.get(_motion(r["motion"]), "+"),
                       color=colours.get(r["sensor"], "k"), ms=4, alpha=0.8)
    for pr in pred:
        if pr["scene"] != "clear_field":
            continue
        zs = sorted(pr["predicted_step_m"], key=float)
        col = colours.get(pr["sensor"], "k")
        ax[0].plot([float(z) for z in zs], [pr["predicted_step_m"][z]["4"] for z in zs], "-", color=col, lw=1,
                   label=str(pr["sensor"]))
        ax[0].plot([float(z) for z in zs], [pr["predicted_step_m"][z]["floor"] for z in zs], "--", color=col, lw=0.7)
    for m, mk in markers.items():
        ax[0].plot([], [], mk, color="k", ms=4, label=m if m == "hover" else f"{m} m")
    ax[0].axhline(tolerance_m, color="grey", lw=0.8)
    ax[0].axhline(tolerance_m / 2, color="grey", lw=0.6, ls=":")
    ax[0].text(4.6, tolerance_m, "UAV tolerance", va="bottom", fontsize=7, color="grey")
    ax[0].text(4.6, tolerance_m / 2, "half of it", va="bottom", fontsize=7, color="grey")
    ax[0].set_yscale("log")
    ax[0].set_xlim(4.5, 12.5)
    ax[0].set_xlabel("altitude (m)")
    ax[0].set_ylabel("smallest step let through (m)")
    ax[0].set_title("fused, 30 frames in 2 s", fontsize=9)
    ax[0].legend(fontsize=6, ncol=2, loc="lower right")
    for k, (what, a) in enumerate((("recall", ax[1]), ("precision", ax[2]))):
        for c in cells:
            x, y = c[f"frame_{what}"], c[f"fused_{what}"]
            if x is None and y is None:
                continue
            mk = markers.get(c["motion"], "+")
            a.plot(-0.02 if x is None else x, -0.02 if y is None else y, mk, color=colours.get(c["sensor"], "k"), ms=4,
                   alpha=0.8)
        lo = 0.9 if k else 0.0
        a.plot([lo, 1], [lo, 1], color="grey", lw=0.6)
        a.set_xlim(lo - 0.03, 1.01)
        a.set_ylim(lo - 0.03, 1.01)
        a.set_xlabel(f"{what} per frame (-: nothing safe)")
        a.set_ylabel(f"{what} fused")
        a.set_title(f"mask {what} per cell", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    print(f"wrote {path}")


def _write(path: Path, data: dict[str, Any]) -> None:
    """Atomically (a killed run leaves the previous file whole)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({**data, "machine": harness.machine()}, indent=1) + "\n")
    os.replace(tmp, path)


def _queue_order(queue: Path | None) -> dict[str, int]:
    """Flight name (without frames and rate) -> its place in the render queue (the order it is measured in)."""
    if queue is None or not queue.exists():
        return {}
    out: dict[str, int] = {}
    for line in queue.read_text().splitlines():
        parts = line.split()
        if len(parts) == 5:
            scene, alt, sensor, motion, seed = parts
            out.setdefault(f"{scene}_{float(alt):g}m_{sensor}_{motion}_s{seed}", len(out))
    return out


def main() -> None:
    ap = harness.parser(__doc__, NAME)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache",
                    help="rendered flights (benchmarks/fusion_render.py --out)")
    ap.add_argument("--flights", default="*", help="glob of flight names within the cache")
    ap.add_argument("--every", type=int, default=3, help="a detection frame every N frames")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--fused-only", action="store_true", help="skip the per-frame path")
    ap.add_argument("--markdown", type=Path, help="write the cell and target tables here")
    ap.add_argument("--plot", type=Path, help="write the plot here (PNG)")
    ap.add_argument("--cached-only", action="store_true", help="aggregate the flights already measured with this "
                    "code, measure none")
    ap.add_argument("--queue", type=Path, help="the render queue (scene alt sensor motion seed per line): list "
                    "the flights not rendered yet")
    a = ap.parse_args()
    keys = code_keys(a.every, a.set)
    hashed = set(_module_files(None))
    old = json.loads(a.out.read_text()) if a.out.exists() else {}
    cached = {r["flight"]: r for r in old.get("flights", [])}
    rows: dict[str, dict[str, Any]] = {}
    order = _queue_order(a.queue)
    paths = sorted(glob.glob(str(a.cache / (a.flights + ".npz"))),
                   key=lambda p: (order.get(Path(p).stem.rsplit("_", 1)[0], len(order)), p))
    for p in paths:
        path = Path(p)
        meta = parse_name(path.stem)
        if p.endswith(".tmp.npz") or meta is None:
            continue
        fid = _file_id(path)
        prev = cached.get(path.name, {})
        same_file = prev.get("file") == fid
        need = [k for k in ("frame", "fused") if not (k == "frame" and a.fused_only)
                and not (same_file and prev.get(f"key_{k}") == keys[k])]
        if need and a.cached_only:
            continue
        row = dict(prev) if same_file else {}
        row.update({"flight": path.name, **meta, "file": fid, "every": a.every})
        if need:
            t0 = time.perf_counter()
            fl = Flight(path, a.every, a.set)
            row["noise"] = fl.noise_summary
            for k in need:
                row.update(measure_frame_path(fl) if k == "frame" else measure_fused_path(fl))
                row[f"key_{k}"] = keys[k]
            rows[path.name] = row
            _write(a.out, {"code": keys, "set": a.set, "every": a.every, "flights": list(rows.values())
                           + [r for n, r in cached.items() if n not in rows]})
            site = row.get("fused_site")
            print(f"{path.name:44s} [{'+'.join(need)} {time.perf_counter() - t0:4.0f} s] "
                  f"frame P {_f(row.get('frame_precision'))} R {_f(row.get('frame_recall'))} | "
                  f"fused P {_f(row.get('fused_precision'))} R {_f(row.get('fused_recall'))} "
                  f"site {'-' if site is None else site['truly_safe']} step {_f(row.get('step_min_core_m'))} "
                  f"cal {(row.get('calibration') or {}).get('spread_robust', '-')}", flush=True)
        rows[path.name] = row
    late = set(_module_files(None)) - hashed
    if late:
        print(f"warning: the code hash misses modules imported later (add them to _import_paths): {sorted(late)}")
    flights = sorted(rows.values(), key=lambda r: (r["sensor"], r["altitude_m"], r["scene"],
                                                   _motion_m(r["motion"]), r["seed"]))
    cells = aggregate(flights)
    tg = targets(flights)
    rendered = {Path(p).stem.rsplit("_", 1)[0] for p in paths}
    missing = [name for name in order if name not in rendered]
    unmeasured = sorted(rendered - {Path(n).stem.rsplit("_", 1)[0] for n in rows})
    pred = predictions(flights)
    result = {"code": keys, "set": a.set, "every": a.every, "cells": cells, "targets": tg, "predictions": pred,
              "not_rendered": missing, "rendered_not_measured": unmeasured, "flights": flights}
    _write(a.out, result)
    print(f"wrote {a.out}")
    md = markdown(cells, tg, pred, flights, missing)
    print(md)
    if unmeasured:
        print(f"rendered, not measured ({len(unmeasured)}): {', '.join(unmeasured)}")
    if a.markdown:
        a.markdown.parent.mkdir(parents=True, exist_ok=True)
        a.markdown.write_text(md)
    if a.plot:
        from slzcli.config import load_config
        plot(cells, flights, pred, a.plot, load_config(None, a.set).uav.max_step_m)


if __name__ == "__main__":
    main()
