"""How a stereo camera's depth error decorrelates between frames as the camera moves: the measurement
behind ``terrain.fusion.decorrelation_px`` and ``white_fraction`` (METHOD 2.3.6).

    python benchmarks/fusion_decorrelation.py --cache DIR [--flights GLOB]

On flights rendered by benchmarks/fusion_render.py (slz's stereo model: an infrared pair, SGBM, true
poses): every frame's depth and its exact depth go through the fusion's own cell measurement
(``fusion.measure.frame_cells``, cells of 0.082 m); a cell's error is measured height - true height. For
every pair of frames, over the cells both saw, after removing the pair's mean error (a global depth bias,
harmless to flatness), the correlation of the two frames' errors is binned by the cells' shift in the
image between the two frames. Only level ground counts (true within-cell spread < 2 cm, errors within 5
robust sigma): at object edges flying pixels and occlusions make errors fixed to the edge.
Fitted: ``rho(d) = fixed + (1 - white - fixed) exp(-d / L)``, the model of ``fusion.grid``. Writes
benchmarks/results/fusion_decorrelation_NAME.json.
"""

from __future__ import annotations

import glob
import itertools
import math
import tempfile
from pathlib import Path

import harness
import numpy as np

FLAT_SPREAD_M = 0.02
BINS_PX = (0.0, 1.0, 2.0, 4.0, 6.0, 9.0, 13.0, 18.0, 25.0, 35.0, 50.0, 70.0, 100.0, 140.0)


def cell_errors(path: Path) -> list[tuple[dict[tuple[int, int], int], np.ndarray, np.ndarray, np.ndarray]]:
    from slzcli.config import load_config
    from slzcli.fusion.measure import FusionParams, frame_cells
    from slzcli.terrain.noise import DepthNoise
    from slzcli.types import Intrinsics

    d = np.load(path)
    k = d["K"]
    intr = Intrinsics(float(k[0]), float(k[1]), float(k[2]), float(k[3]), int(k[4]), int(k[5]))
    params = FusionParams.from_config(load_config())
    noise = DepthNoise.white(0.001, "none")
    out = []
    for depth, true, T in zip(d["depth"], d["depth_true"], d["T"], strict=True):
        both = np.isfinite(depth) & np.isfinite(true)
        m = frame_cells(np.where(both, depth, np.nan), intr, T, noise, params, 0.0, 0.0)
        t = frame_cells(np.where(both, true, np.nan), intr, T, noise, params, 0.0, 0.0)
        assert m is not None and t is not None
        key_t = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(t.ix, t.iy, strict=True))}
        idx = [key_t.get((int(a), int(b)), -1) for a, b in zip(m.ix, m.iy, strict=True)]
        sel = np.array([i >= 0 for i in idx])
        ti = np.array([i for i in idx if i >= 0], dtype=np.int64)
        err = m.height_m[sel] - t.height_m[ti]
        # level ground only: cells whose true heights spread less than 2 cm (away from object edges, where
        # flying pixels and occlusions make errors fixed to the edge, not to the camera's view)
        flat = t.spread_m[ti] < FLAT_SPREAD_M
        mad = 1.4826 * float(np.median(np.abs(err[flat] - np.median(err[flat]))))
        flat &= np.abs(err - np.median(err[flat])) < 5.0 * mad
        mx, my = m.ix[sel][flat], m.iy[sel][flat]
        keys = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(mx, my, strict=True))}
        u_px, v_px = m.pixels(params.cell_m)
        out.append((keys, err[flat], u_px[sel][flat], v_px[sel][flat]))
    return out


def pair_stats(frames: list, max_pairs: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(shift, e_i, e_j) of every cell in the frame pairs (demeaned per pair)."""
    shifts, ei, ej = [], [], []
    n = len(frames)
    pairs = [(i, j) for i in range(n) for j in range(i, n)]
    for i, j in pairs[:max_pairs]:
        ki, e1, u1, v1 = frames[i]
        kj, e2, u2, v2 = frames[j]
        common = [(a, kj[key]) for key, a in ki.items() if key in kj]
        if len(common) < 200:
            continue
        a = np.array([c[0] for c in common])
        b = np.array([c[1] for c in common])
        x, y = e1[a], e2[b]
        if i == j:
            continue
        x = x - x.mean()
        y = y - y.mean()
        shifts.append(np.hypot(u1[a] - u2[b], v1[a] - v2[b]))
        ei.append(x)
        ej.append(y)
    return np.concatenate(shifts), np.concatenate(ei), np.concatenate(ej)


def main() -> None:
    ap = harness.parser(__doc__, "fusion_decorrelation", out=False)  # the name says which flights
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "slz-fusion-cache",
                    help="rendered flights (benchmarks/fusion_render.py --out)")
    ap.add_argument("--flights", default="*d435*")
    ap.add_argument("--name", default="d435")
    a = ap.parse_args()
    rows = []
    all_s, all_x, all_y = [], [], []
    for p in sorted(glob.glob(str(a.cache / (a.flights + ".npz")))):
        frames = cell_errors(Path(p))
        s, x, y = pair_stats(frames)
        all_s.append(s)
        all_x.append(x)
        all_y.append(y)
        sd = float(np.mean([np.std(f[1]) for f in frames]))
        rows.append({"flight": Path(p).name, "cell_error_std_m": sd})
        print(Path(p).name, f"one frame's cell error std {sd:.3f} m", flush=True)
    s, x, y = np.concatenate(all_s), np.concatenate(all_x), np.concatenate(all_y)
    table = []
    for lo, hi in itertools.pairwise(BINS_PX):
        sel = (s >= lo) & (s < hi)
        if sel.sum() < 500:
            continue
        r = float(np.sum(x[sel] * y[sel]) / math.sqrt(np.sum(x[sel] ** 2) * np.sum(y[sel] ** 2)))
        table.append({"shift_px_lo": lo, "shift_px_hi": hi, "median_shift_px": float(np.median(s[sel])),
                      "pairs": int(sel.sum()), "correlation": r})
        print(f"shift {lo:5.1f}-{hi:5.1f} px (median {np.median(s[sel]):5.1f}): rho {r:+.3f}  n={sel.sum()}")
    # fit rho = fixed + (1 - white - fixed) exp(-d / L) on the bins by least squares over a grid
    best = None
    obs = np.array([t["correlation"] for t in table])
    d = np.array([t["median_shift_px"] for t in table])
    for fixed in np.linspace(0.0, 0.5, 51):
        for white in np.linspace(0.0, 1.0 - fixed, 51):
            for L in np.geomspace(0.5, 200.0, 120):
                pred = fixed + (1 - white - fixed) * np.exp(-d / L)
                err = float(np.sum((pred - obs) ** 2))
                if best is None or err < best[0]:
                    best = (err, white, fixed, L)
    assert best is not None
    fit = {"white_fraction": round(float(best[1]), 3), "fixed_fraction": round(float(best[2]), 3),
           "decorrelation_px": round(float(best[3]), 2), "sse": best[0]}
    print("fit:", fit)
    harness.write_results(harness.results_path(f"fusion_decorrelation_{a.name}"),
                          {"flights": rows, "bins": table, "fit": fit}, indent=1)


if __name__ == "__main__":
    main()
