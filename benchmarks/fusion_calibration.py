"""What makes the fused map's stated height std wrong where it is (METHOD 2.3.6, "Calibration"): per flight,
one frame's cell error against its stated std, the fused cell error split by wavelength, and what the map's
own local residuals would say about it without the truth.

    python benchmarks/fusion_calibration.py --cache DIR [--flights GLOB] [--stride N] [--set K=V] [--out FILE]

``--stride N`` fuses every N-th frame only (the same flight N times as fast, N times fewer frames); ``--set``
overrides config keys (what-ifs such as ``terrain.fusion.white_fraction=0.6``).

On flights rendered by benchmarks/fusion_render.py (true poses, exact depth beside the measured one), every
frame goes through the fused method's own code (``FusedTerrain.add``, the run's noise estimate as
benchmarks/fusion_matrix.py replays it). Per flight:
- ``frame_spread``: one frame's cell error (measured - exact depth through the same cell measurement,
  ``measure_frame``; the frame's median error removed) over its stated one-frame std (robust spread 1.4826 MAD,
  median over frames): is one look's noise right? ``noise_scale_median``: the median over the open level cells
  of the fused map's own noise scale (``grid.noise_scale``) at the end.
- ``spread``: the fused cell error over its stated std on open level cells (``fusion_matrix.calibration``'s
  cells and bias), and its split into a long-wavelength part (the normalised error smoothed by a Gaussian
  of 2 and 6 cells, ``lp2``, ``lp6``) and the rest (``hp2``, ``hp6``): where the fused map is overconfident,
  which wavelengths carry the excess?
- ``fixed_px``, ``image_fixed``, ``ground_fixed``, ``moving``: where the long-wavelength part of one frame's error
  lives. One frame's normalised cell errors (as ``frame_spread``) averaged over blocks ``FIXED_BLOCK_PX`` wide at the
  frame's median depth, per frame; the blocks taken once in the image (fixed pixel ranges) and once on the ground
  (fixed world squares of the same size). ``image_fixed``: the variance of the image blocks' means over the frames
  (a pattern the camera carries); ``ground_fixed``: that of the ground blocks' means over the frames that saw them
  (at least ``FIXED_MIN_FRAMES``), less their own sampling variance (a pattern the ground carries: every difference
  of two looks cancels it); ``moving``: the rest of the per-frame block variance (what motion averages), all in
  units of the stated one-frame variance.
- ``spread_looks_n``, ``share_looks_n``: ``spread`` on the open level cells seen by at least n frames (their own
  common bias removed), and their share of them: is the excess where the map has many looks or few?
- ``local_n``: the map's own consistency, truth-free: the residual std of the fused heights about the plane
  of every n x n cells (n = 3, 7, 15) over what their stated variances give (``verdict._plane_fit``; the
  depth-variance map's noise share), median over full windows (``_all``: every seen cell, relief included;
  ``_open``: the open level cells above): could a scale >= 1 from the map itself see the excess?
- ``step_*``: is what the verdict refuses out of reach, or only out of its statement? The same frames' exact
  depth fused beside the measured (``FusedTerrain.add`` alike): the step fitted across each open level cell
  (``verdict.step_fits``, the verdict's windows) on both, their difference the fit's true error. Per direction
  (``x``: a step between columns; the flights run along x) its robust spread in metres (``step_true_sd_*``), the
  stated one (``step_stated_sd_*``: the verdict's limit over k, its stripes' scale included, median) and the
  spread of their ratio (``step_spread_*``). ``step_pass``: the open level squares (every cell of the landing
  square open level ground) whose step test passes as the verdict states it (the square and its windows beyond,
  as ``fused_maps``); ``step_pass_true``: the same with each direction's limit times ``step_spread_*``, what a
  test that knew the fit's true error would pass. Passing the step test is necessary for SAFE, so where
  ``step_pass_true`` is 0 no k-sigma test on this flight's fused map could call level ground safe.
"""

from __future__ import annotations

import glob
import math
import tempfile
from pathlib import Path
from typing import Any

import cv2
import fusion_matrix as fmx
import harness
import numpy as np

SMOOTH_CELLS = (2.0, 6.0)     # Gaussian sigma (cells) of the long-wavelength part
FIXED_BLOCK_PX = 40           # px; the blocks of the image / ground-fixed split (the correlation lengths measured on
                              # the overconfident flights are 40-180 px, METHOD 2.3.6)
FIXED_MIN_FRAMES = 10         # frames a ground block needs for its mean over them
LOOKS_BANDS = (10, 20)        # frames; the spread again on the cells seen by at least this many
LOCAL_CELLS = (3, 7, 15)      # windows of the map's own plane residuals: 3 x 3 (the depth-variance map), the
                              # footprint's 7 x 7 (steps, slope), twice the footprint


def robust(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else math.nan


def smooth(a: np.ndarray, ok: np.ndarray, s: float) -> np.ndarray:
    """Normalised Gaussian smoothing of ``a`` over the cells ``ok`` (NaN where they are too few)."""
    k = int(6 * s) | 1
    num = cv2.GaussianBlur(np.where(ok, a, 0.0), (k, k), s)
    den = cv2.GaussianBlur(ok.astype(np.float64), (k, k), s)
    return np.where(den > 0.2, num / np.maximum(den, 1e-9), np.nan)


def frame_errors(fl: fmx.Flight, i: int, ft: Any) -> tuple[np.ndarray, ...] | None:
    """Frame i's cell errors over their stated one-frame std (the frame's median error removed), with the cells'
    indices and pixels (None: no depth)."""
    from slzcli.fusion.measure import measure_frame

    m = measure_frame(fl.depth[i], fl.intr, fl.T[i], fl.noise[i], fl.cfg, ft.params)
    mt = measure_frame(fl.d["depth_true"][i], fl.intr, fl.T[i], fl.noise[i], fl.cfg, ft.params)
    if m is None or mt is None:
        return None
    ka = (m.ix << 32) ^ (m.iy & 0xFFFFFFFF)
    kb = (mt.ix << 32) ^ (mt.iy & 0xFFFFFFFF)
    _, ia, ib = np.intersect1d(ka, kb, return_indices=True)
    e = m.height_m[ia] - mt.height_m[ib]
    s1 = np.sqrt((m.sigma_w_m[ia] ** 2 + m.sigma_c_m[ia] ** 2) / (1.0 - ft.params.fixed_fraction))
    u, v = m.pixels(ft.params.cell_m)
    return (e - np.median(e)) / s1, m.ix[ia], m.iy[ia], u[ia], v[ia], np.array(m.depth_m)


def _block_means(key: np.ndarray, z: np.ndarray, min_cells: int) -> dict[int, float]:
    uk, inv = np.unique(key, return_inverse=True)
    sums, cnts = np.bincount(inv, z), np.bincount(inv)
    return {int(k): float(s / c) for k, s, c in zip(uk, sums, cnts, strict=True) if c >= min_cells}


def fixed_parts(frames: list[tuple[np.ndarray, ...]], cell_m: float, focal_px: float,
                open_keys: np.ndarray) -> dict[str, float]:
    """The image- and ground-fixed shares of the frames' long-wavelength error (the docstring's ``image_fixed``,
    ``ground_fixed``, ``moving``), on the open level cells (``open_keys``: their ``ix << 32 ^ iy``) as ``spread``."""
    z_med = float(np.median([f[5] for f in frames]))
    g = max(1, round(FIXED_BLOCK_PX * z_med / focal_px / cell_m))          # ground block, cells
    min_cells = max(4, g * g // 4)
    img: dict[int, list[float]] = {}
    ground: dict[int, list[float]] = {}
    per_frame: list[float] = []
    for z, ix, iy, u, v, _ in frames:
        ok = (np.abs(z) < 6.0) & np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0)
        ok &= np.isin((ix << 32) ^ (iy & 0xFFFFFFFF), open_keys)
        bu = (u[ok] // FIXED_BLOCK_PX).astype(np.int64)
        bv = (v[ok] // FIXED_BLOCK_PX).astype(np.int64)
        for k, val in _block_means((bu << 20) + bv, z[ok], min_cells).items():
            img.setdefault(k, []).append(val)
            per_frame.append(val)
        gx, gy = np.floor_divide(ix[ok], g), np.floor_divide(iy[ok], g)
        for k, val in _block_means((gx << 32) + (gy & 0xFFFFFFFF), z[ok], min_cells).items():
            ground.setdefault(k, []).append(val)
    total = float(np.var(per_frame))
    im = [np.mean(v) for v in img.values() if len(v) >= FIXED_MIN_FRAMES]
    gr = [v for v in ground.values() if len(v) >= FIXED_MIN_FRAMES]
    within = float(np.mean([np.var(v, ddof=1) for v in gr])) if gr else math.nan
    n_mean = float(np.mean([len(v) for v in gr])) if gr else math.nan
    ground_fixed = float(np.var([np.mean(v) for v in gr])) - within / n_mean if gr else math.nan
    image_fixed = float(np.var(im)) if im else math.nan
    return {"fixed_px": FIXED_BLOCK_PX, "block_var": round(total, 3), "image_fixed": round(image_fixed, 3),
            "ground_fixed": round(ground_fixed, 3), "moving": round(total - image_fixed - ground_fixed, 3)}


def step_reach(fl: fmx.Flight, ft: Any, exact: Any, b: tuple[int, int, int, int],
               open_: np.ndarray) -> dict[str, Any]:
    """The ``step_*`` columns of the docstring: the fused step fit's true error (measured - exact depth's
    fusion) on the open level cells, and the squares its step test passes as stated and with its true error."""
    from slzcli.fusion.grid import region
    from slzcli.fusion.verdict import _erode, _odd, fused_maps, square_cells, step_fits, step_passes

    reg, rex = region(ft.grid, *b), region(exact.grid, *b)
    fm = fused_maps(reg, fl.cfg, ft.params, fl.scorer)
    both = reg.seen & rex.seen & np.isfinite(reg.h) & np.isfinite(rex.h)
    n_fp = max(3, _odd(max(fl.cfg.uav.footprint_m) / reg.cell_m))
    half = max(2, n_fp // 2)
    fits = [step_fits(np.where(both, r.h, 0.0), both, n_fp, half) for r in (reg, rex)]
    k, max_step = ft.params.confidence_sigma, fl.cfg.uav.max_step_m
    step_min = fm.step_min_m.astype(np.float64)
    out: dict[str, Any] = {}
    lim, lim_true, s_abs = [], [], []
    for axis, s, s_exact, scale, s_verdict in (("x", fits[0][0], fits[1][0], fm.steps.scale_x, fm.steps.x_m),
                                               ("y", fits[0][1], fits[1][1], fm.steps.scale_y, fm.steps.y_m)):
        sel = open_ & both & np.isfinite(s) & np.isfinite(s_exact) & np.isfinite(step_min)
        if np.count_nonzero(sel) < 50:
            return out
        err, stated = (s - s_exact)[sel], scale * step_min[sel] / k
        spread = robust(err / stated)
        out[f"step_true_sd_{axis}"] = round(robust(err), 4)
        out[f"step_stated_sd_{axis}"] = round(float(np.median(stated)), 4)
        out[f"step_spread_{axis}"] = round(spread, 3)
        lim.append(scale * step_min)
        lim_true.append(spread * scale * step_min)
        s_abs.append(s_verdict)
    n_sq, reach = square_cells(ft.params.square_m, reg.cell_m), n_fp // 2
    squares = _erode(open_, n_sq, n_sq)
    out["open_squares"] = int(np.count_nonzero(squares))
    for name, (lx, ly) in (("step_pass", lim), ("step_pass_true", lim_true)):
        fine = step_passes(s_abs[0], s_abs[1], lx, ly, n_sq, reach, max_step)
        out[name] = int(np.count_nonzero(fine & squares))
    return out


def measure(path: Path, stride: int = 1, sets: tuple[str, ...] = ()) -> dict[str, Any]:
    from slzcli.fusion import kernels
    from slzcli.fusion.grid import region, seen_bounds
    from slzcli.fusion.session import FusedTerrain
    from slzcli.fusion.verdict import _box, _plane_fit

    fl = fmx.Flight(path, 3, list(sets))
    ft = FusedTerrain(fl.cfg, fl.scorer)
    exact = FusedTerrain(fl.cfg, fl.scorer)
    frames, errors = [], []
    for i in range(0, fl.n, stride):
        fe = frame_errors(fl, i, ft)
        if fe is not None:
            frames.append(robust(fe[0]))
            errors.append(fe)
        ft.add(fl.depth[i], fl.intr, fl.T[i], fl.noise[i], 0, i)
        exact.add(fl.d["depth_true"][i], fl.intr, fl.T[i], fl.noise[i], 0, i)
    out: dict[str, Any] = {"flight": path.name, **(fmx.parse_name(path.stem) or {})}
    if frames:
        out["frame_spread"] = round(float(np.median(frames)), 3)
    b = seen_bounds(ft.grid) if ft.grid is not None else None
    if ft.grid is None or b is None:
        return out
    reg = region(ft.grid, *b)
    g = ft.grid
    raw_var = kernels.region_cells(g.owner, g.state, g.frames, g.rejected, g.column, g.blocked, *b,
                                   g.params.side_cells, g.params.fixed_fraction)[1][1]    # before the noise scale
    h_true, level = fmx.cell_truth(fl.d, reg)
    ok = reg.seen & level & np.isfinite(reg.h) & (reg.var > 0)
    dist = cv2.distanceTransform(level.astype(np.uint8), cv2.DIST_L2, 5)
    open_ = ok & (dist > fmx.OPEN_CELLS)
    if np.count_nonzero(open_) < 50:
        return out
    err = reg.h - h_true
    z = np.where(ok, (err - np.median(err[ok])) / np.sqrt(np.where(ok, reg.var, 1.0)), np.nan)
    out["spread"] = round(robust(z[open_]), 3)
    out["noise_scale_median"] = round(float(np.median(reg.var[open_] / raw_var[open_])), 3)
    for n in LOOKS_BANDS:         # the cells seen by at least n frames, their own common bias removed
        sel = open_ & (reg.frames >= n)
        if np.count_nonzero(sel) >= 50:
            e = err[sel]
            out[f"spread_looks_{n}"] = round(robust((e - np.median(e)) / np.sqrt(reg.var[sel])), 3)
            out[f"share_looks_{n}"] = round(float(np.count_nonzero(sel) / np.count_nonzero(open_)), 3)
    jj, ii = np.nonzero(open_)
    out.update(fixed_parts(errors, ft.params.cell_m, 0.5 * (fl.intr.fx + fl.intr.fy),
                           ((ii.astype(np.int64) + reg.x0) << 32) ^ ((jj.astype(np.int64) + reg.y0) & 0xFFFFFFFF)))
    out["error_robust_m"] = round(robust(err[open_]), 4)
    out["sigma_median_m"] = round(float(np.median(np.sqrt(reg.var[open_]))), 4)
    for s in SMOOTH_CELLS:
        lp = smooth(np.nan_to_num(z), ok, s)
        out[f"lp{s:g}"] = round(robust(lp[open_]), 3)
        out[f"hp{s:g}"] = round(robust((z - lp)[open_]), 3)
    seen = reg.seen & np.isfinite(reg.h)
    hc = np.where(seen, reg.h - np.median(reg.h[seen]), 0.0)
    for n in LOCAL_CELLS:
        _, _, res, valid, cnt = _plane_fit(hc, seen, n, reg.cell_m)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = res / (_box(np.where(seen, reg.var, 0.0), n) / cnt * (cnt - 3) / cnt)
        full = valid & np.isfinite(ratio) & (cnt >= n * n - 0.5)
        out[f"local_{n}_all"] = round(math.sqrt(float(np.median(ratio[full]))), 3) if full.any() else None
        sel = full & open_
        out[f"local_{n}_open"] = round(math.sqrt(float(np.median(ratio[sel]))), 3) if sel.any() else None
    out.update(step_reach(fl, ft, exact, b, open_))
    return out


def main() -> None:
    ap = harness.parser(__doc__, "fusion_calibration")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache",
                    help="rendered flights (benchmarks/fusion_render.py --out)")
    ap.add_argument("--flights", action="append", default=[], help="glob of flight names within the cache "
                    "(repeatable; default: every flight)")
    ap.add_argument("--stride", type=int, default=1, help="fuse every N-th frame only")
    ap.add_argument("--set", action="append", default=[], help="config override K=V (repeatable)")
    a = ap.parse_args()
    rows = []
    for pat in a.flights or ["*"]:
        for p in sorted(glob.glob(str(a.cache / (pat + ".npz")))):
            if p.endswith(".tmp.npz") or fmx.parse_name(Path(p).stem) is None:
                continue
            row = measure(Path(p), a.stride, tuple(a.set))
            if a.stride > 1 or a.set:
                row.update(stride=a.stride, sets=a.set)
            rows.append(row)
            print(" ".join(f"{k}={v}" for k, v in row.items() if k not in ("scene", "altitude_m", "sensor", "motion",
                                                                         "seed", "frames", "rate_hz")), flush=True)
    harness.write_results(a.out, {"flights": rows})


if __name__ == "__main__":
    main()
