"""What `slz detect` commits at the end of a run, fused against per frame: is the committed site truly safe?

    python benchmarks/fused_detect.py [--scenes clear_field,parking_lot,office,slopes,no_site]
                                      [--flights 7.5:d435,10:d455,10:gauss0.003] [--motion 4] [--seeds 0,1]
                                      [--methods fuzzy,fused] [--frames 30] [--rate 15] [--size WxH]
                                      [--cache /tmp/fused_detect] [--rows DIR] [--true-poses] [--render-only]
                                      [--set KEY=VALUE ...]

benchmarks/fusion_matrix.py measures the fused verdict and its ``best_site`` frame by frame; this measures what
the run as a whole writes to landing.json: the sites ``select_site`` took on the detection frames (the
raised-surface rule included), then the commit (``landing/commit.py``: sites refuted by the other detections'
raised-surface readings left out, the agreed site ranked). The project's safety target: no committed site is
truly unsafe, and the no_site scene never gives one.

Flights: ``slz synth SCENE`` with ``--path transect`` due east, ``--motion`` metres over the flight
(``synth.flight.speed_m_s`` = metres / (frames / rate), centred on the scene's scenario x, y, as
benchmarks/fusion_render.py renders the flight matrix), ``--frames`` at ``--rate`` Hz, at each ``ALT:SENSOR`` of
``--flights`` (sensors as fusion_render.SENSORS names them: the stereo D435 / D455 presets, gaussian
a = 0.003), seeds ``--seeds``; 640 x 480 (the paper's camera, as the other stereo benchmarks) unless
``--size``. Rendered once into ``--cache`` with their ground-truth sidecars (``--render-only`` fills it): a
stereo flight took ~77 s on a shared 2-core machine, the default matrix (30 flights, 60 runs) 28 min from an
empty cache, 4 min from a full one (a run is 3-5 s).

Per flight and method: ``slz detect REC -o DIR --json --method M`` through the CLI in a fresh process, the
default config (SLAM as ``slz detect`` runs it: ORB-SLAM3 when installed; ``--true-poses`` gives it the synth's
true pose topic instead). Read back: the status, the committed site's truth as slz itself evaluates it with the
``.gt.*`` sidecars (landing.json ``site.ground_truth``: its centre through its frame's TRUE pose, safe when the
truth raster calls its cell safe for the footprint plus margin, its clearance to the nearest hazard), the
reason and the advice when there is none, the mask's pixel precision / recall (run.json); every detection
frame's chosen site (sites.csv), each put into the truth world through its own frame's true pose
(trajectory.tum gives the map pose at its stamp) and checked against the same raster; fused, the last landing
map's SAFE cells and how many of them the truth calls unsafe. A run without a site is put down to the stage
that lost it, from its reason: the per-frame depth noise (the frames could not vouch), the fused verdict (nothing
in view decided safe), the raised-surface rule (the best cluster not told from raised, or raised beyond doubt),
no cluster of map points qualifying, too few map points on the mask (or on any one region of it), the commit's
refutation, or every site failing its acceptance test.

Prints a row per run (status, committed site truly safe: yes / NO / none, detection frames with a site / of them
not truly safe, the stage, the reason or the site's acceptance) and the totals per method (committed sites, those
not truly safe, those committed although their acceptance test failed, the no_site scene's sites, the no-site
stages); writes benchmarks/results/fused_detect.json (with ``--true-poses`` give ``--out``, e.g.
benchmarks/results/fused_detect_true_poses.json). ORB-SLAM3 tracks in threads: a rerun of the SLAM pass may differ.
"""

from __future__ import annotations

import csv
import json
import shutil
import time
from pathlib import Path
from typing import Any

import harness
import numpy as np
from fusion_render import SENSORS

from slzcli.errors import DatasetError
from slzcli.synth.groundtruth import GroundTruth, load_ground_truth

SCENES = ("clear_field", "parking_lot", "office", "slopes", "no_site")
TRUE_POSES = ("--set", "slam.backend=recorded", "--set", "sources.use_ground_truth_pose=true")


def flight_name(scene: str, alt: float, sensor: str, motion: float, seed: int, frames: int, rate: float,
                size: str | None) -> str:
    tail = "" if size is None else f"_{size}"
    return f"{scene}_{alt:g}m_{sensor}_{motion:g}_s{seed}_{frames}f{rate:g}hz{tail}"


def render(cache: Path, scene: str, alt: float, sensor: str, motion: float, seed: int, frames: int, rate: float,
           size: str | None) -> Path:
    """The flight's recording in the cache (``slz synth`` when missing or without its sidecars)."""
    from slzcli.config import load_config
    from slzcli.synth.record import scenario_start
    from slzcli.synth.scenes import load_scene

    rec = cache / (flight_name(scene, alt, sensor, motion, seed, frames, rate, size) + ".mcap")
    if rec.exists() and Path(f"{rec}.gt.npz").exists() and Path(f"{rec}.gt.json").exists():
        return rec
    x, y, _ = scenario_start(load_config(None, []).synth.scenarios, load_scene(scene).scenario)
    sets = [a for kv in [*SENSORS[sensor], f"synth.flight.speed_m_s={motion / (frames / rate)}"]
            for a in ("--set", kv)]
    sizes = [] if size is None else harness.size_overrides(size)
    harness.slz("synth", scene, "-o", str(rec), "--frames", str(frames), "--rate", f"{rate:g}", "--path", "transect",
                "--start", f"{x - 0.5 * motion:.3f},{y:.3f},{alt:g}", "--seed", str(seed), "--force", *sets, *sizes)
    return rec


# ---------------------------------------------------------------- the run against the truth

def _map_poses(out: Path) -> dict[int, np.ndarray]:
    """trajectory.tum: the map pose (4x4 T_map_camera) of every tracked frame, by its stamp in microseconds
    (a stamp of 15 Hz is not a whole number of them: look a frame up with ``_pose_at``)."""
    from scipy.spatial.transform import Rotation

    poses: dict[int, np.ndarray] = {}
    path = out / "trajectory.tum"
    if not path.exists():
        return poses
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        v = [float(s) for s in line.split()]
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[4:8]).as_matrix()
        T[:3, 3] = v[1:4]
        poses[round(v[0] * 1e6)] = T
    return poses


def _pose_at(poses: dict[int, np.ndarray], stamp_ns: int) -> np.ndarray | None:
    """The map pose of the frame at ``stamp_ns`` (within 1 ms), None when it was not tracked."""
    if not poses:
        return None
    us = min(poses, key=lambda k: abs(k - stamp_ns / 1e3))
    return poses[us] if abs(us - stamp_ns / 1e3) < 1000 else None


def _true_pose(truth: GroundTruth, stamp_ns: int) -> np.ndarray | None:
    """The recording's true camera pose at ``stamp_ns`` (within 1 ms), None when it has no frame there."""
    try:
        return np.asarray(truth.T_world_camera[truth.index_of(stamp_ns, 1_000_000)], np.float64)
    except DatasetError:
        return None


def _to_world(truth: GroundTruth, poses: dict[int, np.ndarray], stamp_ns: int,
              p_map: np.ndarray) -> np.ndarray | None:
    """A point of the map frame in the truth's world through its frame's true pose (as slz's own site truth does:
    the point's position relative to the camera that saw it, not the map's drift)."""
    T_map = _pose_at(poses, stamp_ns)
    T_true = _true_pose(truth, stamp_ns)
    if T_map is None or T_true is None:
        return None
    T = T_true @ np.linalg.inv(T_map)
    return np.asarray(p_map, np.float64) @ T[:3, :3].T + T[:3, 3]


def frame_sites(out: Path, truth: GroundTruth, poses: dict[int, np.ndarray]) -> dict[str, Any]:
    """Every detection frame's chosen site (sites.csv) against the truth; the candidate clusters, those that
    qualified and those the raised-surface rule refused (not told from raised / raised beyond doubt), with the
    points of the clusters it measured (its margin on the site's level shrinks with their number)."""
    path = out / "sites.csv"
    rows: list[dict[str, str]] = []
    if path.exists():
        with path.open() as fh:
            rows = list(csv.DictReader(fh))
    measured = [r for r in rows if r["raised_m"]]
    chosen = [r for r in rows if r["chosen"] == "True"]
    safe = unsafe = unplaced = 0
    unsafe_frames = []
    for r in chosen:
        w = _to_world(truth, poses, int(r["stamp_ns"]), np.array([float(r["x"]), float(r["y"]), float(r["z"])]))
        if w is None:
            unplaced += 1
        elif truth.raster.safe_at(w[0], w[1]):
            safe += 1
        else:
            unsafe += 1
            unsafe_frames.append({"frame": int(r["frame"]), "true_xy": [round(float(w[0]), 3), round(float(w[1]), 3)],
                                  "raised_m": r["raised_m"] or None})
    return {"frames_with_site": len(chosen), "frame_sites_safe": safe, "frame_sites_unsafe": unsafe,
            "frame_sites_unplaced": unplaced, "unsafe_frames": unsafe_frames, "clusters": len(rows),
            "clusters_qualified": sum(r["qualifies"] == "True" for r in rows),
            "clusters_raised_measured": len(measured),
            "clusters_raised_not_told": sum("not told" in r["reason"] for r in rows),
            "clusters_raised_beyond": sum(r["reason"].startswith("on a surface") and "not told" not in r["reason"]
                                          for r in rows),
            "raised_points_median": float(np.median([int(r["points"]) for r in measured])) if measured else None}


def landing_map_cells(out: Path, truth: GroundTruth, poses: dict[int, np.ndarray]) -> dict[str, Any]:
    """The last landing map (fused): its SAFE cells and those whose centre the truth calls unsafe (through the last
    tracked frame's true pose)."""
    from slzcli.fusion.verdict import SAFE

    path = out / "landing_map.npz"
    if not path.exists() or not poses:
        return {"safe_cells": None, "safe_cells_truly_unsafe": None}
    lm = np.load(path)
    verdict, res, org = lm["verdict"], float(lm["resolution_m"]), lm["origin_xy"]
    jj, ii = np.nonzero(verdict == SAFE)
    if not len(jj):
        return {"safe_cells": 0, "safe_cells_truly_unsafe": 0}
    last = max(poses)
    xyz = np.stack([org[0] + (ii + 0.5) * res, org[1] + (jj + 0.5) * res, lm["height_m"][jj, ii]], axis=1)
    w = _to_world(truth, poses, last * 1000, xyz)
    if w is None:
        return {"safe_cells": len(jj), "safe_cells_truly_unsafe": None}
    return {"safe_cells": len(jj), "safe_cells_truly_unsafe": int(np.sum(~truth.raster.safe_at(w[:, 0], w[:, 1])))}


def detect(rec: Path, method: str, extra: list[str], keep: bool) -> dict[str, Any]:
    """One ``slz detect --method METHOD --json`` run and what it committed, against the truth."""
    out = rec.with_name(f"{rec.stem}_{method}")
    t0 = time.perf_counter()
    res = harness.slz("detect", str(rec), "-o", str(out), "--json", "--force", "--method", method, *extra, check=False)
    wall = round(time.perf_counter() - t0, 1)
    if res.returncode != 0:
        return {"status": "failed", "error": res.stderr.strip().splitlines()[-1:] or [str(res.returncode)],
                "wall_s": wall}
    s = json.loads(res.stdout)
    landing = json.loads((out / "landing.json").read_text())
    site = landing.get("site") or {}
    gt = site.get("ground_truth") or {}
    mask = (s.get("ground_truth") or {}).get("mask") or {}
    advice = landing.get("advice") or {}
    truth = load_ground_truth(rec)
    poses = _map_poses(out)
    row: dict[str, Any] = {
        "status": s["status"], "site_safe": gt.get("safe") if site else None,
        "site_true_xy": gt.get("true_xy"), "site_clearance_m": gt.get("clearance_m"),
        "site_world": site.get("center_world"), "site_frame": (landing.get("frame") or {}).get("index"),
        "site_score": site.get("score"), "support": site.get("support"),
        "site_source": site.get("source"),   # map points (a cluster) or the fused terrain
        "site_accepted": (site.get("acceptance") or {}).get("passed"),
        "acceptance": (site.get("acceptance") or {}).get("reason"),
        "reason": landing.get("reason"), "advice": advice.get("text"), "advice_hover": advice.get("hover"),
        "detections": s.get("detections"), "frames": s.get("frames"), "slam_backend": s.get("slam_backend"),
        "slam_ate_m": (s.get("ground_truth") or {}).get("slam_ate_rmse_m"),
        "mask_precision": mask.get("precision"), "mask_recall": mask.get("recall"),
        **frame_sites(out, truth, poses), "wall_s": wall}
    if method == "fused":
        row.update(landing_map_cells(out, truth, poses))
    row["stage"] = stage(row)
    finding = row["status"] == "site" and row["site_safe"] is not True
    if not keep and not finding:
        shutil.rmtree(out, ignore_errors=True)
    else:
        row["run"] = str(out)
    return row


# ---------------------------------------------------------------- table and totals

STAGES = (("refutes every site", "commit: refuted"), ("not told from one higher", "raised: not told"),
          ("above the ground around it (more than", "raised: beyond doubt"),
          ("nothing in view is decided safe", "fused: nothing safe"), ("depth noise", "per frame: not vouched"),
          ("no cluster qualifies", "no cluster qualifies"), ("failed its acceptance test", "commit: acceptance"),
          ("SLAM map points", "too few map points"))


def stage(r: dict[str, Any]) -> str | None:
    """Where a run without a site lost it, from its reason (the first that names it)."""
    if r["status"] == "site":
        return None
    why = r.get("reason") or ""
    return next((name for text, name in STAGES if text in why), "other")


def truly_safe(r: dict[str, Any]) -> str:
    if r["status"] != "site":
        return "none"
    return "yes" if r["site_safe"] else "NO"


def totals(rows: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        sites = [r for r in mine if r["status"] == "site"]
        no_site = [r for r in mine if r["scene"] == "no_site"]
        out[m] = {"runs": len(mine), "failed": sum(r["status"] == "failed" for r in mine),
                  "committed_sites": len(sites), "unsafe_committed_sites": sum(not r["site_safe"] for r in sites),
                  "committed_not_accepted": sum(r["site_accepted"] is False for r in sites),
                  "committed_by_fused_terrain": sum(r.get("site_source") == "fused terrain" for r in sites),
                  "no_site_runs": len(no_site), "no_site_sites": sum(r["status"] == "site" for r in no_site),
                  "frame_sites": sum(r.get("frames_with_site", 0) for r in mine),
                  "frame_sites_unsafe": sum(r.get("frame_sites_unsafe", 0) for r in mine),
                  "safe_cells_truly_unsafe": sum(r.get("safe_cells_truly_unsafe") or 0 for r in mine),
                  "no_site_stage": {}, "sites_by_flight": {}}
        for r in mine:
            if r["status"] not in ("site", "failed"):
                st = out[m]["no_site_stage"]
                st[r["stage"]] = st.get(r["stage"], 0) + 1
        for r in mine:
            key = f"{r['altitude_m']:g}m_{r['sensor']}"
            d = out[m]["sites_by_flight"].setdefault(key, {"runs": 0, "sites": 0, "truly_safe": 0})
            d["runs"] += 1
            d["sites"] += r["status"] == "site"
            d["truly_safe"] += r["status"] == "site" and bool(r["site_safe"])
    return out


def print_row(r: dict[str, Any]) -> None:
    why = r.get("reason") or r.get("acceptance") or ""
    if r["status"] == "failed":
        why = " ".join(r.get("error") or [])
    fs = f"{r.get('frames_with_site', 0)}/{r.get('frame_sites_unsafe', 0)}"
    print(f"{r['scene']:<12} {r['altitude_m']:>4g} {r['sensor']:<10} {r['seed']:>2} {r['method']:<6} "
          f"{r['status']:<13} {truly_safe(r):<5} {fs:>6} {r.get('stage') or '-':<22} {r.get('wall_s', 0):>5.1f}  "
          f"{why[:100]}", flush=True)


def main() -> None:
    from slzcli.config import load_config

    ap = harness.parser(__doc__, "fused_detect")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--flights", default="7.5:d435,10:d455,10:gauss0.003", help="ALT:SENSOR pairs (m, sensor)")
    ap.add_argument("--motion", type=float, default=4.0, help="metres of transect over the flight")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--methods", default="fuzzy,fused")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--rate", type=float, default=15.0)
    ap.add_argument("--size", default=None, help="WxH render (default: the paper's 640x480)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fused_detect"), help="rendered flights")
    ap.add_argument("--rows", type=Path, default=None, help="keep each run's row in this folder and reuse it "
                    "(a rerun measures only what is missing)")
    ap.add_argument("--true-poses", action="store_true", help="the synth's true pose topic instead of SLAM")
    ap.add_argument("--keep-runs", action="store_true", help="keep every run folder (default: only those whose "
                    "committed site is not truly safe)")
    ap.add_argument("--render-only", action="store_true")
    ap.add_argument("--set", dest="sets", action="append", default=[])
    args = ap.parse_args()
    extra = [*(TRUE_POSES if args.true_poses else ()), *(a for kv in args.sets for a in ("--set", kv))]
    load_config(None, args.sets)   # a bad key fails here, before an hour of renders
    methods = args.methods.split(",")
    flights = [(float(a), s) for a, s in (f.split(":") for f in args.flights.split(","))]
    args.cache.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rows: list[dict[str, Any]] = []
    print(f"{'scene':<12} {'alt':>4} {'sensor':<10} {'s':>2} {'method':<6} {'status':<13} {'safe':<5} "
          f"{'fr/bad':>6} {'lost at':<22} {'wall':>5}  reason / acceptance")
    for seed in (int(s) for s in args.seeds.split(",")):
        for alt, sensor in flights:
            for scene in args.scenes.split(","):
                name = flight_name(scene, alt, sensor, args.motion, seed, args.frames, args.rate, args.size)
                t0 = time.perf_counter()
                rec = render(args.cache, scene, alt, sensor, args.motion, seed, args.frames, args.rate, args.size)
                render_s = round(time.perf_counter() - t0, 1)
                if args.render_only:
                    print(f"{rec.name} {render_s} s", flush=True)
                    continue
                for method in methods:
                    kept = None if args.rows is None else args.rows / f"{name}_{method}.json"
                    if kept is not None and kept.exists():
                        row = json.loads(kept.read_text())
                    else:
                        row = {"scene": scene, "altitude_m": alt, "sensor": sensor, "motion_m": args.motion,
                               "seed": seed, "method": method, "flight": name,
                               **detect(rec, method, extra, args.keep_runs)}
                        if kept is not None:
                            kept.parent.mkdir(parents=True, exist_ok=True)
                            kept.write_text(json.dumps(row))
                    rows.append(row)
                    print_row(row)
    if args.render_only:
        return
    tot = totals(rows, methods)
    wall = round(time.perf_counter() - t_start, 1)
    harness.write_results(args.out, {"scenes": args.scenes, "flights": args.flights, "motion_m": args.motion,
                                     "seeds": args.seeds, "methods": methods, "frames": args.frames,
                                     "rate_hz": args.rate, "size": args.size or "640x480",
                                     "poses": "true (recorded)" if args.true_poses else "SLAM (slz detect's default)",
                                     "set": args.sets, "wall_s": wall, "totals": tot, "rows": rows}, indent=1)
    for m, t in tot.items():
        print(f"{m}: {t['committed_sites']} committed sites of {t['runs']} runs, {t['unsafe_committed_sites']} not "
              f"truly safe; no_site: {t['no_site_sites']} sites of {t['no_site_runs']} runs; detection frames with "
              f"a site {t['frame_sites']} ({t['frame_sites_unsafe']} not truly safe); failed {t['failed']}; "
              f"committed with a failed acceptance test {t['committed_not_accepted']}; no site lost at "
              f"{t['no_site_stage']}")
    print(f"wall {wall} s")


if __name__ == "__main__":
    main()
