"""What makes the fused map's stated height std wrong where it is (METHOD 2.3.6, "Calibration"): per flight,
one frame's cell error against its stated std, the fused cell error split by wavelength, and what the map's
own local residuals would say about it without the truth.

    python benchmarks/fusion_calibration.py --cache DIR [--flights GLOB] [--out FILE]

On flights rendered by benchmarks/fusion_render.py (true poses, exact depth beside the measured one), every
frame goes through the fused method's own code (``FusedTerrain.add``, the run's noise estimate as
benchmarks/fusion_matrix.py replays it). Per flight:
- ``frame_spread``, ``frame_spread_scaled``: one frame's cell error (measured - exact depth through the same
  cell measurement, ``measure_frame``; the frame's median error removed) over its stated one-frame std, without
  and with the noise scale the innovations had asked for by then (robust spread 1.4826 MAD, median over
  frames): is one look's noise right?
- ``spread``: the fused cell error over its stated std on open level cells (``fusion_matrix.calibration``'s
  cells and bias), and its split into a long-wavelength part (the normalised error smoothed by a Gaussian
  of 2 and 6 cells, ``lp2``, ``lp6``) and the rest (``hp2``, ``hp6``): where the fused map is overconfident,
  which wavelengths carry the excess?
- ``local_n``: the map's own consistency, truth-free: the residual std of the fused heights about the plane
  of every n x n cells (n = 3, 7, 15) over what their stated variances give (``verdict._plane_fit``; the
  depth-variance map's noise share), median over full windows (``_all``: every seen cell, relief included;
  ``_open``: the open level cells above): could a scale >= 1 from the map itself see the excess?
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


def one_frame(fl: fmx.Flight, i: int, ft: Any) -> tuple[float, float] | None:
    """(spread, spread with the current noise scale) of frame i's cell errors over their stated one-frame std."""
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
    z = (e - np.median(e)) / s1
    return robust(z), robust(z / math.sqrt(ft.noise_scale()))


def measure(path: Path) -> dict[str, Any]:
    from slzcli.fusion.grid import region, seen_bounds
    from slzcli.fusion.session import FusedTerrain
    from slzcli.fusion.verdict import _box, _plane_fit

    fl = fmx.Flight(path, 3, [])
    ft = FusedTerrain(fl.cfg, fl.scorer)
    frames = []
    for i in range(fl.n):
        f = one_frame(fl, i, ft)
        if f is not None:
            frames.append(f)
        ft.add(fl.depth[i], fl.intr, fl.T[i], fl.noise[i], 0, i)
    out: dict[str, Any] = {"flight": path.name, **(fmx.parse_name(path.stem) or {}),
                           "noise_scale_last": round(ft.noise_scale(), 3)}
    if frames:
        out["frame_spread"] = round(float(np.median([f[0] for f in frames])), 3)
        out["frame_spread_scaled"] = round(float(np.median([f[1] for f in frames])), 3)
    b = seen_bounds(ft.grid) if ft.grid is not None else None
    if ft.grid is None or b is None:
        return out
    reg = region(ft.grid, *b)
    h_true, level = fmx.cell_truth(fl.d, reg)
    ok = reg.seen & level & np.isfinite(reg.h) & (reg.var > 0)
    dist = cv2.distanceTransform(level.astype(np.uint8), cv2.DIST_L2, 5)
    open_ = ok & (dist > fmx.OPEN_CELLS)
    if np.count_nonzero(open_) < 50:
        return out
    err = reg.h - h_true
    z = np.where(ok, (err - np.median(err[ok])) / np.sqrt(np.where(ok, reg.var, 1.0)), np.nan)
    out["spread"] = round(robust(z[open_]), 3)
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
    return out


def main() -> None:
    ap = harness.parser(__doc__, "fusion_calibration")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache",
                    help="rendered flights (benchmarks/fusion_render.py --out)")
    ap.add_argument("--flights", action="append", default=[], help="glob of flight names within the cache "
                    "(repeatable; default: every flight)")
    a = ap.parse_args()
    rows = []
    for pat in a.flights or ["*"]:
        for p in sorted(glob.glob(str(a.cache / (pat + ".npz")))):
            if p.endswith(".tmp.npz") or fmx.parse_name(Path(p).stem) is None:
                continue
            row = measure(Path(p))
            rows.append(row)
            print(" ".join(f"{k}={v}" for k, v in row.items() if k not in ("scene", "altitude_m", "sensor", "motion",
                                                                         "seed", "frames", "rate_hz")), flush=True)
    harness.write_results(a.out, {"flights": rows})


if __name__ == "__main__":
    main()
