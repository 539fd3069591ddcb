"""Robustness of the built-in odometry: ATE over scene seeds, sensor-noise seeds and depth cuts.

Why: an ATE limit is only honest if it holds over inputs that differ slightly (issue 14: a 5 cm change
of the depth cut swung the ATE of tests/slam/test_slam.py from 2.35 to 6.44 cm). For every input of the
SLAM tests (tests/slam_flight.py 'line' 480x360 and 'out_back' 320x240, 100 frames each) and each seed
this runs the odometry: the line flight at the default depth range and at each depth cut of the sweep
(the triangulation test), the out-and-back flight (loss and recovery). Optionally also the odometry of
an older git revision (``--baseline REV``, loaded from ``git show`` into this process) so that ATE and the
median time per frame compare on the same frames, and with cv2.setNumThreads(1) against the default.
Rendered frames are cached under $TMPDIR/slz_slam_robustness (rendering costs more than tracking).
Prints a table; writes results/slam_robustness.json (``--out`` to change).
Usage: .venv/bin/python benchmarks/slam_robustness.py [--baseline d5543df] [--seeds 0 1 2 3 4]
"""

from __future__ import annotations

import importlib.util
import pickle
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import cv2
import harness
import numpy as np

harness.use_test_helpers()

import slam_flight  # noqa: E402

from slzcli.config import load_config  # noqa: E402
from slzcli.evaluate.slam import ate  # noqa: E402
from slzcli.geometry import transform_points  # noqa: E402
from slzcli.slam import TrackingState  # noqa: E402
from slzcli.slam import odometry as current_odometry  # noqa: E402

CACHE = Path(tempfile.gettempdir()) / "slz_slam_robustness"
FLIGHTS = {"line": (480, 360), "out_back": (320, 240)}
CUTS = [round(3.5 + 0.05 * i, 2) for i in range(11)]


def flight(kind: str, seed: int, noise_seed: int | None) -> tuple[list, list]:
    """The test's flight (100 frames, supersample 1) for a scene seed and an optional noise seed; cached."""
    w, h = FLIGHTS[kind]
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"{kind}_{w}x{h}_s{seed}_n{noise_seed}.pkl"
    if path.exists():
        with path.open("rb") as f:
            return pickle.load(f)
    out = slam_flight.render_flight(100, kind, width=w, height=h, supersample=1, seed=seed, noise_seed=noise_seed)
    with path.open("wb") as f:
        pickle.dump(out, f)
    return out


def baseline_module(rev: str) -> ModuleType:
    """slzcli/slam/odometry.py as it was at git revision ``rev``, as a module of its own."""
    src = harness.source_at(rev, "slzcli/slam/odometry.py")
    spec = importlib.util.spec_from_loader(f"slzcli.slam._odometry_{rev}", loader=None)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    exec(compile(src, f"{rev}:slzcli/slam/odometry.py", "exec"), mod.__dict__)
    return mod


def run(mod: ModuleType, frames: list, truth: list, overrides: list[str]) -> dict:
    config = load_config(overrides=["slam.backend=odometry", *overrides])
    results, keyframes, times = [], [], []
    cpu0 = time.process_time()
    with mod.OdometryBackend(config.slam) as b:
        for f in frames:
            t0 = time.perf_counter()
            results.append(b.track(f))
            times.append(time.perf_counter() - t0)
            kf = b.keyframe()
            if kf is not None:
                keyframes.append(kf)
    cpu = time.process_time() - cpu0  # CPU time: less at the mercy of other jobs on a shared machine than wall time
    poses = [r.T_world_camera for r in results]
    a = ate(poses, truth)
    row = {"ate_cm": 100 * a.rmse_m, "ate_max_cm": 100 * a.max_m, "ate_frames": a.n,
           "ok": sum(r.state is TrackingState.OK for r in results),
           "lost": sum(r.state is TrackingState.LOST for r in results),
           "segments": len({r.segment for r in results}), "keyframes": len(keyframes),
           "ms_per_frame_median": 1e3 * float(np.median(times[1:])), "cpu_ms_per_frame": 1e3 * cpu / len(frames)}
    cut = next((float(o.split("=")[1]) for o in overrides if o.startswith("slam.odometry.max_depth_m=")), None)
    if cut is not None:  # the triangulation test's checks: points beyond the cut, on the ground
        beyond = []
        for kf in keyframes:
            depth = transform_points(np.linalg.inv(kf.T_world_camera), kf.xyz_world)[:, 2]
            beyond.append(kf.xyz_world[depth > cut])
        far = np.concatenate(beyond) if beyond else np.zeros((0, 3))
        row["far_points"] = len(far)
        gz = (far @ a.alignment.R.T + a.alignment.t)[:, 2] if len(far) else np.array([np.nan])
        row["far_ground_median_cm"] = 100 * float(np.median(np.abs(gz)))
    return row


Case = tuple[str, int, int | None, float | None]


def cases(seeds: list[int], noise_seeds: list[int], cuts: list[float]) -> list[Case]:
    """(flight, scene seed, noise seed, depth cut) of every run."""
    inputs = [(s, None) for s in seeds] + [(0, n) for n in noise_seeds]
    out: list[Case] = []
    for s, n in inputs:
        out.append(("line", s, n, None))
        out += [("line", s, n, c) for c in cuts]
        out.append(("out_back", s, n, None))
    return out


def summarise(rows: list[dict]) -> list[dict]:
    """Median / max ATE and median ms per frame by implementation and test case."""
    groups: dict[tuple[str, str, int], list[dict]] = {}
    for r in rows:
        case = r["flight"] if r["cut_m"] is None else f"{r['flight']} cut"
        groups.setdefault((r["impl"], case, r["threads"]), []).append(r)
    out = []
    for (impl, case, threads), g in sorted(groups.items()):
        a = np.array([r["ate_cm"] for r in g])
        worst = g[int(np.argmax(a))]
        out.append({"impl": impl, "case": case, "threads": threads, "runs": len(g),
                    "ate_median_cm": float(np.median(a)), "ate_max_cm": float(a.max()),
                    "worst": {k: worst[k] for k in ("seed", "noise_seed", "cut_m")},
                    "not_all_ok": sum(r["ok"] < len_ok(r) for r in g),
                    "min_far_points": min((r["far_points"] for r in g if "far_points" in r), default=None),
                    "max_far_ground_median_cm": max((r["far_ground_median_cm"] for r in g
                                                     if "far_ground_median_cm" in r), default=None),
                    "ms_per_frame_median": float(np.median([r["ms_per_frame_median"] for r in g])),
                    "cpu_ms_per_frame": float(np.median([r["cpu_ms_per_frame"] for r in g]))})
    return out


def len_ok(r: dict) -> int:
    """Frames that must be tracked: all but the first on the line flight (out_back is checked by its test)."""
    return 99 if r["flight"] == "line" else 0


def main() -> None:
    ap = harness.parser(__doc__, "slam_robustness")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="scene seeds (noise-free)")
    ap.add_argument("--noise-seeds", type=int, nargs="*", default=[0, 1], help="noise seeds on scene 0")
    ap.add_argument("--cuts", type=float, nargs="*", default=CUTS, help="depth cuts (m) for the line flight")
    ap.add_argument("--baseline", help="git revision whose odometry.py runs too (e.g. d5543df)")
    ap.add_argument("--no-current", action="store_true", help="run only the baseline")
    ap.add_argument("--threads-check", action="store_true", help="also seed 0 with cv2.setNumThreads(1)")
    args = ap.parse_args()
    impls: dict[str, ModuleType] = {}
    if args.baseline:
        impls[f"baseline {args.baseline}"] = baseline_module(args.baseline)
    if not args.no_current:
        impls["current"] = current_odometry
    default_threads = cv2.getNumThreads()
    todo = [(c, default_threads) for c in cases(args.seeds, args.noise_seeds, args.cuts)]
    if args.threads_check:
        todo += [(c, 1) for c in cases([0], [], [3.75])]
    rows = []
    t_start = time.perf_counter()
    for (kind, seed, noise, cut), threads in todo:
        frames, truth = flight(kind, seed, noise)
        overrides = [] if cut is None else [f"slam.odometry.max_depth_m={cut}"]
        for impl, mod in impls.items():
            cv2.setNumThreads(threads)
            row = {"impl": impl, "flight": kind, "seed": seed, "noise_seed": noise, "cut_m": cut, "threads": threads,
                   **run(mod, frames, truth, overrides)}
            cv2.setNumThreads(default_threads)
            rows.append(row)
            print(f"{impl:18} {kind:8} seed {seed} noise {noise!s:4} cut {cut!s:5} thr {threads}: "
                  f"ATE {row['ate_cm']:6.2f} cm  ok {row['ok']:3} lost {row['lost']:3} seg {row['segments']} "
                  f"KFs {row['keyframes']:3} {row['ms_per_frame_median']:6.1f} ms/frame "
                  f"{row['cpu_ms_per_frame']:5.1f} cpu"
                  + (f"  far {row['far_points']:5} ground {row['far_ground_median_cm']:.2f} cm" if cut else ""),
                  flush=True)
    summary = summarise(rows)
    head = f"{'impl':18} {'case':13} {'thr':>3} {'runs':>4} {'ATE med cm':>10} {'ATE max cm':>10} {'worst at':24} " \
           f"{'!ok':>3} {'ms/frame':>8} {'cpu ms/fr':>9}"
    print("\n" + head + "\n" + "-" * len(head))
    for s in summary:
        w = s["worst"]
        at = f"seed {w['seed']} noise {w['noise_seed']} cut {w['cut_m']}"
        print(f"{s['impl']:18} {s['case']:13} {s['threads']:>3} {s['runs']:>4} {s['ate_median_cm']:10.2f} "
              f"{s['ate_max_cm']:10.2f} {at:24} {s['not_all_ok']:>3} {s['ms_per_frame_median']:8.1f} "
              f"{s['cpu_ms_per_frame']:9.1f}")
    harness.write_results(args.out, {"cv2_threads_default": default_threads, "args": vars(args),
                                     "wall_s": time.perf_counter() - t_start, "summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
