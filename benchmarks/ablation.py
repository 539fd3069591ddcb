"""Ablation: the paper as published (``--profile paper``) with slz's decisions switched on one at a time, and all.

    python benchmarks/ablation.py [--scenes a,b] [--altitudes 5,10] [--sensors d435] [--seeds 0]
                                  [--frames 20] [--rate 10] [--decisions a,b] [--workers 2]
                                  [--leave-one-out] [--variants a,b]
    python benchmarks/ablation.py --recordings A.mcap B.mcap      # your own recordings (with or without truth)
    python benchmarks/ablation.py --table benchmarks/results/ablation_seed*.json  # docs/ABLATION.md from results

Per cell (scene x altitude x sensor x seed, the grid of benchmarks/sensor_matrix.py) one `slz synth` recording,
then every variant on it with `slz compare`'s machinery (``compare.compare_recording``, the variant's own
method): ``paper``; ``paper_rgbd`` (the paper with slz's RGB-D SLAM); ``+D``, that base plus decision D, for
every other decision D below; and ``default`` (all of them: tests/config/test_profiles.py holds that paper + every
decision is exactly the default config). The base of the map, mask and commit decisions is ``paper_rgbd``,
not ``paper``, because the paper's monocular SLAM does not start on every flight (next paragraph): without a
map there are no keyframes and so no detection to change, and a base that detects on some cells only would
mix "the decision helps" with "the map started". Reported per variant: mask precision and recall (pixels
summed over its detection frames), whether the committed site is truly safe, SLAM ATE (m, against the true
poses) and the median time per detection frame (SLAM + maps + score + mask + select, ms, same process, same
machine).

The flight: a straight survey line (``slz synth --path transect``: 2 m/s due east, the hover's drift and tilt
wobble on top) at ``--rate`` 10 Hz, so monocular SLAM has parallax from the second frame. Monocular ORB-SLAM3
also needs relief in view: over near-planar ground it takes the fundamental matrix, which a plane leaves
undetermined (docs/METHOD.md 2.2). benchmarks/monocular_init.py measured it on these transects (24 frames,
6 scenes x 5, 10 m x seeds 0, 1): it started on 18 of 24, 11 of them by frame 2, never on clear_field (flat
grass), on parking_lot with seed 1 only; ATE 0.7-10 cm where it did. A cell where it does not start is
reported as such (no keyframe, no detection), not dropped.
Writes benchmarks/results/ablation.json after every cell and prints a table.
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Literal

import harness
import numpy as np

SCENES = ("clear_field", "parking_lot", "playground", "office", "slopes", "no_site")
SENSORS: dict[str, list[str]] = {   # as benchmarks/sensor_matrix.py
    "ideal": ["synth.sensor.model=ideal"],
    "gauss0.0015": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.0015"],
    "gauss0.003": ["synth.sensor.model=gaussian", "synth.sensor.depth_sigma_a=0.003"],
    "d435": ["synth.sensor.model=stereo", "synth.sensor.preset=d435"],
    "d455": ["synth.sensor.model=stereo", "synth.sensor.preset=d455"],
}
PATH: Literal["transect"] = "transect"   # a survey line (synth.flight.speed_m_s, heading_deg): parallax (above)
FLIGHT: list[str] = []   # the flight keys of default.yaml (2 m/s due east, the hover's drift and tilt wobble on top)

# slz's decisions against the paper, each as the --set items that switch it on over `--profile paper`.
DECISIONS: dict[str, list[str]] = {
    # METHOD 2.2: RGB-D ORB-SLAM3 (depth makes the first frame a metric map) instead of monocular
    "slam_rgbd": ["slam.backend=auto", "slam.orbslam3.sensor=rgbd", "slam.orbslam3.nominal_period_s=auto"],
    # METHOD 2.3: absolute ranges (1 = good in every frame) instead of per-frame min-max (Eq. 5)
    "absolute": ["terrain.depth_variance.normalise=absolute", "terrain.depth_variance.s0_m=0.05",
                 "terrain.flatness.normalise=absolute", "terrain.inclination.normalise=absolute",
                 "terrain.steepness.normalise=absolute"],
    # METHOD 2.3.5: windows, block size and Canny scaling from the measured depth noise; vouching
    "noise_aware": ["terrain.noise=auto"],
    # METHOD 2.3.1: residual std about a plane fit, noise removed, instead of the plain local std
    "plane_variance": ["terrain.depth_variance.statistic=plane"],
    # METHOD 2.3.2: Canny on detrended inverse depth after a blur; holes under 5 cm are not edges
    "detrended_edges": ["terrain.flatness.detrend_px=15", "terrain.flatness.blur_px=3",
                        "terrain.flatness.hole_min_m=0.05"],
    # METHOD 2.3.4: a 0.3 m plane-fit window for slopes instead of the 0.5 m KNN radius
    "local_slope": ["terrain.steepness.normal_size_m=0.3", "terrain.steepness.normal_max_px=61"],
    # METHOD 2.4.3: Gaussian smoothing of the score before the minimum filter
    "smoothing": ["mask.smooth_m=0.1"],
    # METHOD 2.4.3: the footprint minimum filter on the ground plane (+ descent column) instead of the image
    "plan_filter": ["mask.clearance=plan"],
    # METHOD 2.5: the site most detections agree on instead of the latest keyframe's
    "agreement": ["landing.commit=agree"],
    # METHOD 2.3.5 / 2.4.3: maps on blocks of at least 2.5 cm on the ground, the plan filter on 2 samples
    # per footprint cell (speed: the paper works on every pixel)
    "working_grid": ["terrain.limits.finest_block_m=0.025", "mask.plan_samples_per_cell=2.0"],
}


def variants(decisions: list[str], leave_one_out: bool = False) -> dict[str, tuple[str | None, list[str]]]:
    """name -> (profile, --set items): the paper; the paper with RGB-D SLAM (``paper_rgbd``, the base of the
    other decisions, see the module docstring); that base plus each other decision; the default (all); with
    ``leave_one_out`` also the default with each decision back at the paper's value (what it buys among the rest)."""
    out: dict[str, tuple[str | None, list[str]]] = {"paper": ("paper", [])}
    base = DECISIONS["slam_rgbd"] if "slam_rgbd" in decisions else []
    if base:
        out["paper_rgbd"] = ("paper", base)
    out.update({f"+{d}": ("paper", base + DECISIONS[d]) for d in decisions if d != "slam_rgbd"})
    out["default"] = (None, [])
    if leave_one_out:
        out.update({f"default-{d}": (None, revert(d)) for d in decisions if d != "slam_rgbd"})
    return out


def revert(decision: str) -> list[str]:
    """The --set items that switch ``decision`` back to the paper's values over the default config."""
    from slzcli.config import load_config

    paper = load_config(profile="paper")
    out = []
    for item in DECISIONS[decision]:
        key = item.partition("=")[0]
        node: Any = paper
        for part in key.split("."):
            node = getattr(node, part)
        out.append(f"{key}={node}")
    return out


def run_variants(path: Path, decisions: list[str], base: list[str], leave_one_out: bool = False,
                 only: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Every variant (or those named in ``only``) over one recording, in this process (times comparable within
    the cell)."""
    from slzcli.compare import compare_recording, profile_row
    from slzcli.config import load_config
    from slzcli.outputs.records_json import to_json_object

    rows = []
    for name, (profile, items) in variants(decisions, leave_one_out).items():
        if only and name not in only:
            continue
        cfg = load_config(None, base + items, profile)
        t0 = time.perf_counter()
        row: dict[str, object]
        try:
            r = compare_recording(path, cfg, (cfg.scoring.method,)).record
            row = to_json_object(profile_row(r, name, cfg.scoring.method))
        except Exception as err:  # one variant's failure is a row
            row = {"recording": path.name, "profile": name, "error": f"{type(err).__name__}: {err}"}
        row["wall_s"] = round(time.perf_counter() - t0, 1)
        rows.append(row)
    return rows


def run_cell(scene: str, altitude: float, sensor: str, seed: int, frames: int, rate: float, decisions: list[str],
             tmp: str, leave_one_out: bool = False, only: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    from slzcli.config import load_config
    from slzcli.synth.record import SynthOptions, scenario_start, synthesize
    from slzcli.synth.scenes import load_scene

    cfg = load_config(None, SENSORS[sensor] + FLIGHT)
    x, y, _ = scenario_start(cfg.synth.scenarios, load_scene(scene).scenario)
    path = Path(tmp) / f"{scene}_{altitude:g}_{sensor}_{seed}.mcap"
    synthesize(path, SynthOptions(scene, frames, rate, PATH, seed, (x, y, altitude)), cfg)
    rows = run_variants(path, decisions, [], leave_one_out, only)
    for r in rows:
        r.update(scene=scene, altitude_m=altitude, sensor=sensor, seed=seed)
    path.unlink(missing_ok=True)
    return rows


def _f(v: Any, p: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{p}f}"


def print_row(r: dict[str, Any]) -> None:
    cell = f"{r.get('scene', r['recording'])[:11]:<11} {r.get('altitude_m', 0):>4g} {r.get('sensor', '-'):<6}"
    if "error" in r:
        print(f"{cell} {r['profile']:<17} ERROR {r['error']}", flush=True)
        return
    safe = "-" if r["site_safe"] is None else str(r["site_safe"])
    print(f"{cell} {r['profile']:<17} {r['detections']:>4} {_f(r['precision']):>6} {_f(r['recall']):>6} "
          f"{r['status']:<12} {safe:>5} {_f(r['ate_rmse_m']):>6} {_f(r['frame_ms_median'], 0):>7}", flush=True)


def summarise(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per variant over all cells: mean precision / recall, sites truly safe / committed, median ATE and time."""
    out: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(r["profile"] for r in rows):
        mine = [r for r in rows if r["profile"] == name and "error" not in r]

        def vals(k: str, mine: list[dict[str, Any]] = mine) -> list[Any]:
            return [r[k] for r in mine if r.get(k) is not None]

        sites = [r for r in mine if r["status"] == "site"]
        out[name] = {"cells": len(mine), "errors": sum(r["profile"] == name and "error" in r for r in rows),
                     "precision_mean": float(np.mean(vals("precision"))) if vals("precision") else None,
                     "recall_mean": float(np.mean(vals("recall"))) if vals("recall") else None,
                     "sites": len(sites), "sites_safe": sum(r["site_safe"] is True for r in sites),
                     "ate_median_m": float(np.median(vals("ate_rmse_m"))) if vals("ate_rmse_m") else None,
                     "frame_ms_median": float(np.median(vals("frame_ms_median"))) if vals("frame_ms_median") else None,
                     "detections": int(sum(vals("detections")))}
    return out


def _flight(r: dict[str, Any]) -> tuple[Any, ...]:
    return r.get("scene"), r.get("altitude_m"), r.get("sensor"), r.get("seed")


def merge(files: list[Path]) -> list[dict[str, Any]]:
    """The rows of several result files, one per (cell, variant): a later file's row replaces an earlier one's."""
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    for f in files:
        for r in json.loads(f.read_text())["rows"]:
            key = (*_flight(r), r["profile"])
            rows[key] = r
    return list(rows.values())


def _cell(rows: list[dict[str, Any]]) -> str:
    """One table cell over several runs: truly safe / committed sites, mean recall (runs where the truth has
    safe ground), and how many runs had a map where some had none (monocular SLAM that never started)."""
    if not rows:
        return ""
    ok = [r for r in rows if "error" not in r]
    sites = [r for r in ok if r["status"] == "site"]
    recall = [r["recall"] for r in ok if r.get("recall") is not None]
    mean = float(np.mean(recall)) if recall else None
    text = f"{sum(r['site_safe'] is True for r in sites)}/{len(sites)}, {_f(mean, 2)}"
    nomap = sum(r["detections"] == 0 for r in ok)
    errors = len(rows) - len(ok)
    return text + (f"; mapped {len(ok) - nomap}/{len(ok)}" if nomap else "") + (f"; {errors} errors" if errors else "")


def _overall(rows: list[dict[str, Any]], names: list[str], title: str) -> list[str]:
    summary = summarise(rows)
    out = [title, "", "| variant | flights | sites truly safe / committed | recall (mean) | precision (mean / worst) | "
           "ATE m (median) | ms/frame (median) |", "|---|---|---|---|---|---|---|"]
    for name in names:
        if name not in summary:
            continue
        s = summary[name]
        prec = [r["precision"] for r in rows if r["profile"] == name and r.get("precision") is not None]
        out.append(f"| {name} | {s['cells']} | {s['sites_safe']}/{s['sites']} | {_f(s['recall_mean'], 3)} | "
                   f"{_f(s['precision_mean'], 3)} / {_f(min(prec) if prec else None, 3)} | {_f(s['ate_median_m'])} | "
                   f"{_f(s['frame_ms_median'], 0)} |")
    return [*out, ""]


def tables(rows: list[dict[str, Any]]) -> str:
    """Markdown: per sensor, variant x altitude (sites truly safe / committed, mean recall over the scenes and
    seeds); one table over every flight (precision, ATE and time too); and, where some variants ran on fewer
    flights (``--leave-one-out`` at one altitude, say), the same over the flights every variant ran on."""
    names = list(dict.fromkeys(r["profile"] for r in rows))
    alts = sorted({r["altitude_m"] for r in rows})
    out = []
    for sensor in dict.fromkeys(r["sensor"] for r in rows):
        mine = [r for r in rows if r["sensor"] == sensor]
        out += [f"{sensor} ({len({_flight(r) for r in mine})} flights): sites truly safe / committed, mean recall",
                "", "| variant | " + " | ".join(f"{a:g} m" for a in alts) + " |", "|---" * (len(alts) + 1) + "|"]
        for name in names:
            cells = [_cell([r for r in mine if r["profile"] == name and r["altitude_m"] == a]) for a in alts]
            if any(cells):
                out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    out += _overall(rows, names, "Every flight")
    flights = [{_flight(r) for r in rows if r["profile"] == n} for n in names]
    common = set.intersection(*flights) if flights else set()
    if common and any(f != common for f in flights):
        out += _overall([r for r in rows if _flight(r) in common], names,
                        f"The {len(common)} flights every variant ran on")
    return "\n".join(out)


def main() -> None:
    ap = harness.parser(__doc__, "ablation")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--altitudes", default="3,5,7.5,10")
    ap.add_argument("--sensors", default=",".join(SENSORS))
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--decisions", default=",".join(DECISIONS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--leave-one-out", action="store_true", help="Also the default with each decision switched back.")
    ap.add_argument("--variants", default="", help="Run only these variants (names as printed, e.g. "
                    "default,default-absolute); default: all.")
    ap.add_argument("--recordings", nargs="*", type=Path, help="Run the variants on these recordings instead.")
    ap.add_argument("--table", nargs="+", type=Path, metavar="RESULT",
                    help="Print the README's tables from these result files (a later file's row wins) and exit.")
    args = ap.parse_args()
    if args.table:
        print(tables(merge(args.table)), end="")
        return
    decisions = [d for d in args.decisions.split(",") if d]
    only = tuple(v for v in args.variants.split(",") if v)
    known = variants(decisions, args.leave_one_out) if only else {}
    if [v for v in only if v not in known]:
        sys.exit(f"unknown variant(s) {', '.join(v for v in only if v not in known)}; known: {', '.join(known)}")
    unknown = [d for d in decisions if d not in DECISIONS]
    if unknown:
        sys.exit(f"unknown decision(s) {', '.join(unknown)}; known: {', '.join(DECISIONS)}")
    print(f"{'cell':<23} {'variant':<17} {'det':>4} {'prec':>6} {'recall':>6} {'site':<12} {'safe':>5} "
          f"{'ATE m':>6} {'ms/frm':>7}")
    rows: list[dict[str, Any]] = []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    run = {"frames": args.frames, "rate_hz": args.rate, "path": PATH, "flight": FLIGHT, "decisions": {d: DECISIONS[d]
                                                                                        for d in decisions}}

    def save() -> None:
        harness.write_results(args.out, {**run, "rows": rows, "summary": summarise(rows)}, indent=1, say=False)

    if args.recordings:
        for p in args.recordings:
            for r in run_variants(p, decisions, [], args.leave_one_out, only):
                rows.append(r)
                print_row(r)
            save()
    else:
        # altitude-major: a run stopped part way has covered every scene and sensor at the first altitudes
        cells = [(s, float(z), sensor, int(seed)) for seed in args.seeds.split(",") for z in args.altitudes.split(",")
                 for s in args.scenes.split(",") for sensor in args.sensors.split(",")]
        run.update(cells=[list(c) for c in cells])
        fresh: dict[str, Any] = {"max_tasks_per_child": 1} if sys.version_info >= (3, 11) else {}
        with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(args.workers, **fresh) as pool:
            futures = [pool.submit(run_cell, s, z, sensor, seed, args.frames, args.rate, decisions, tmp,
                                   args.leave_one_out, only)
                       for s, z, sensor, seed in cells]
            for cell, fut in zip(cells, futures, strict=True):
                try:
                    cell_rows = fut.result()
                except Exception as err:  # one cell's failure is a row, not the end of the run
                    cell_rows = [{"scene": cell[0], "altitude_m": cell[1], "sensor": cell[2], "seed": cell[3],
                                  "recording": cell[0], "profile": "(cell)", "error": f"{type(err).__name__}: {err}"}]
                for r in cell_rows:
                    rows.append(r)
                    print_row(r)
                save()
    print("\nper variant over all cells:")
    for name, s in summarise(rows).items():
        print(f"  {name:<17} cells {s['cells']:>2}  precision {_f(s['precision_mean'])}  recall {_f(s['recall_mean'])}"
              f"  sites {s['sites_safe']}/{s['sites']} safe  ATE {_f(s['ate_median_m'])} m  "
              f"{_f(s['frame_ms_median'], 0)} ms/frame  detections {s['detections']}")
    save()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
