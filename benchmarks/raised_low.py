"""Low raised surfaces: does either path land on a box top a little above the UAV's step tolerance?

    python benchmarks/raised_low.py [--heights 0.06,0.12,0.2,0.3,0.5] [--sensors gauss0.003,d435,d455]
                                    [--altitudes 5,7.5] [--motions hover,4] [--seeds 0,1,2]
                                    [--cache /tmp/raised_low] [--render-only] [--set KEY=VALUE ...]

The raised-surface rule (landing/raised.py, METHOD 2.5.1) refuses a site more than ``uav.max_step_m`` (0.09 m)
above the ground around it; on fused cells it takes the ground's noise from the cells' own scatter too, which
makes it more lenient than per frame. Here it meets boxes of heights around the tolerance.

Scene: level dirt ground with one 3.4 x 3.0 m concrete box at the origin, its top wide enough for the landing
square (0.86 m with margins) to sit 1 m inside every edge, so that only the raised rule can refuse it (the
maps see a low box's edge as a step only when it exceeds the tolerance). The box is an object, not a landable
surface (slz synth's truth: only ground and ramps are), so the truth calls its top unsafe at any height; a
site there is a *defect* of the rule only when the box is higher than ``uav.max_step_m`` (below it, the top is
ground to the UAV by slz's own model, and only the truth's convention says otherwise).

Flights: ``slz synth`` at 640 x 480 (the paper's field of view), 30 frames at 15 Hz, from ``--altitudes``; motion
``hover`` (the synth hover over the box's centre) or a transect of that many metres due east over it (its
middle over the box's centre); sensors as benchmarks/fusion_render.py names them. Rendered once into
``--cache`` (a stereo flight takes 1.5-4 min on a shared machine; ``--render-only`` fills the cache and stops).

Per flight, ``slz detect`` per frame (``--method fuzzy``) and fused (``--method fused``), true poses
(``slam.backend=recorded``, the synth's ground-truth pose topic; map points sampled from the keyframes' depth):
the status; the committed site's true position, whether the truth calls it safe, whether it lies on the box
top; every detection frame's chosen site on the box top (sites.csv); the raised rule's reading there (per
frame: sites.csv ``raised_m`` / ``raised_cells`` of clusters on the box top, and how many the rule refused;
fused: each verdict's ``patch_tests`` of the patches whose best cell lies on the box top, read by a spy on
``verdict.raised_patches``: height, threshold, refused); the mask's pixel precision (the truth's); fused, the
last landing map's SAFE cells on the box top. Prints a table per path and box height, writes
benchmarks/results/raised_low.json.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections import defaultdict
from pathlib import Path
from typing import Any

import harness
import numpy as np
from fusion_render import SENSORS
from tilt_fused import _world_of_map

BOX_HALF = (1.7, 1.5)
FRAMES, RATE_HZ = 30, 15.0
TRUE_POSES = ("--set", "slam.backend=recorded", "--set", "sources.use_ground_truth_pose=true")


def scene_text(height_m: float) -> str:
    return (f'description: "A 3.4 x 3.0 m concrete box {height_m:g} m high on level dirt ground."\n'
            "ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}\n"
            "objects:\n"
            f"  - {{name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, {height_m:g}], material: concrete}}\n")


def flight_name(height: float, alt: float, sensor: str, motion: str, seed: int) -> str:
    return f"box{height:g}_{alt:g}m_{sensor}_{motion}_s{seed}"


def render(cache: Path, height: float, alt: float, sensor: str, motion: str, seed: int) -> Path:
    """The flight's recording in the cache (rendered by ``slz synth`` when missing)."""
    from slzcli.synth.scenes import SCENES_DIR

    rec = cache / (flight_name(height, alt, sensor, motion, seed) + ".mcap")
    if rec.exists() and Path(str(rec) + ".gt.npz").exists():
        return rec
    scene = cache / f"box{height:g}.yaml"
    if not scene.exists():
        shutil.copy(SCENES_DIR / "_common.yaml", cache / "_common.yaml")   # the shared materials
        scene.write_text(scene_text(height))
    if motion == "hover":
        path, start, speed = "hover", f"0,0,{alt}", []
    else:
        v = float(motion) * RATE_HZ / FRAMES
        path, start = "transect", f"{-0.5 * v * (FRAMES - 1) / RATE_HZ:.3f},0,{alt}"   # east (heading_deg 90)
        speed = ["--set", f"synth.flight.speed_m_s={v}"]
    sets = [a for kv in SENSORS[sensor] for a in ("--set", kv)]
    harness.slz("synth", str(scene), "-o", str(rec), "--frames", str(FRAMES), "--rate", str(RATE_HZ), "--path", path,
                "--start", start, "--seed", str(seed), "--force", *sets, *speed)
    return rec


def on_box(xy: Any) -> bool:
    return xy is not None and abs(xy[0]) <= BOX_HALF[0] and abs(xy[1]) <= BOX_HALF[1]


class RuleSpy:
    """Records what the raised-surface rule found: per call of the fused verdict's ``raised_patches``, each
    patch's best cell (map frame) and its ``Raised``; per call of ``select_site``'s rule (per frame, and on the
    fused method's mask), the cluster's centroid and its ``Raised``."""

    def __init__(self) -> None:
        self.patches: list[tuple[float, float, float, Any]] = []
        self.clusters: list[tuple[float, float, float, Any]] = []

    def __enter__(self) -> RuleSpy:
        from slzcli.fusion import verdict
        from slzcli.landing import select
        from slzcli.landing.raised import Raised, RaisedParams

        self._orig = verdict.raised_patches, select.raised_site

        def patches(reg: Any, ok: Any, safe: Any, clear_score: Any, params: Any) -> Any:
            patch, tests = self._orig[0](reg, ok, safe, clear_score, params)
            _, rank = verdict._site_rank(safe, clear_score)
            for k, t in enumerate(tests, start=1):
                f = int(np.argmax(np.where(patch == k, rank, -np.inf)))
                j, i = divmod(f, patch.shape[1])
                self.patches.append((reg.origin_m[0] + (i + 0.5) * reg.cell_m,
                                     reg.origin_m[1] + (j + 0.5) * reg.cell_m, float(reg.h[j, i]), t))
            return patch, tests

        def cluster(centroid: np.ndarray, normals: np.ndarray, pts: np.ndarray, around: np.ndarray,
                    params: RaisedParams, up: np.ndarray) -> Raised:
            r = self._orig[1](centroid, normals, pts, around, params, up)
            self.clusters.append((float(centroid[0]), float(centroid[1]), float(centroid[2]), r))
            return r

        verdict.raised_patches, select.raised_site = patches, cluster
        return self

    def __exit__(self, *exc: Any) -> None:
        from slzcli.fusion import verdict
        from slzcli.landing import select

        verdict.raised_patches, select.raised_site = self._orig


def readings(found: list[Any], T: np.ndarray, box: bool) -> dict[str, Any]:
    """The rule's findings on the box top (``box``) or off it: how many, refused, unmeasured, the heights read
    and the thresholds (ranges), the highest height passed."""
    tests = [t for (x, y, z, t) in found if on_box(_to_world(T, x, y, z)) == box]
    hs = [t.height_m for t in tests if t.measured]
    return {"n": len(tests), "refused": sum(t.refused for t in tests), "unmeasured": sum(not t.measured for t in tests),
            "height_m": [min(hs), max(hs)] if hs else None,
            "threshold_m": [min(t.threshold_m for t in tests), max(t.threshold_m for t in tests)] if tests else None,
            "passed_max_m": max((t.height_m for t in tests if t.measured and not t.refused), default=None)}


def _to_world(T: np.ndarray, x: float, y: float, z: float) -> tuple[float, float]:
    p = T[:3, :3] @ np.array([x, y, z]) + T[:3, 3]
    return float(p[0]), float(p[1])


def detect(runner: Any, rec: Path, method: str, extra: list[str]) -> dict[str, Any]:
    from slzcli.cli import main

    out = rec.with_name(f"{rec.stem}_{method}")
    with RuleSpy() as spy:
        res = runner.invoke(main, ["detect", str(rec), "-o", str(out), "--force", "--json", "--method", method,
                                   *TRUE_POSES, *extra])
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    truth = np.load(str(rec) + ".gt.npz")
    T = _world_of_map(out, truth)
    gt = s.get("ground_truth") or {}
    site = gt.get("site") or {}
    xy = site.get("true_xy")
    mask = gt.get("mask") or {}
    with (out / "sites.csv").open() as fh:
        chosen = [r for r in csv.DictReader(fh) if r["chosen"] == "True"]
    row: dict[str, Any] = {
        "status": s["status"], "site_safe": site.get("safe"), "site_true_xy": xy, "site_on_box": on_box(xy),
        "mask_precision": mask.get("precision"), "mask_recall": mask.get("recall"),
        "frames_with_site": len(chosen),
        "frames_site_on_box": sum(on_box(_to_world(T, float(r["x"]), float(r["y"]), float(r["z"]))) for r in chosen),
        "clusters_box": readings(spy.clusters, T, True), "clusters_ground": readings(spy.clusters, T, False),
        "reason": s.get("reason")}
    if method == "fused":
        row.update({"patches_box": readings(spy.patches, T, True), "patches_ground": readings(spy.patches, T, False),
                    "box_cells_safe": _box_cells_safe(out, truth, T)})
    shutil.rmtree(out, ignore_errors=True)
    return row


def _box_cells_safe(out: Path, truth: Any, T: np.ndarray) -> int:
    """SAFE cells of the last landing map whose centre lies on the box top."""
    from slzcli.fusion.verdict import SAFE

    lm = np.load(out / "landing_map.npz")
    verdict, res, org = lm["verdict"], float(lm["resolution_m"]), lm["origin_xy"]
    jj, ii = np.nonzero(verdict == SAFE)
    if not len(jj):
        return 0
    xyz = np.stack([org[0] + (ii + 0.5) * res, org[1] + (jj + 0.5) * res, lm["height_m"][jj, ii]], axis=1)
    w = xyz @ T[:3, :3].T + T[:3, 3]
    return int(np.sum((np.abs(w[:, 0]) <= BOX_HALF[0]) & (np.abs(w[:, 1]) <= BOX_HALF[1])))


def _span(vals: list[Any]) -> list[float] | None:
    vals = [v for v in vals if v is not None]
    return [min(v[0] for v in vals), max(v[1] for v in vals)] if vals else None


def summarise(rows: list[dict[str, Any]], max_step: float) -> list[dict[str, Any]]:
    """Per path x sensor x altitude x box height, over motions and seeds. The rule's findings: the fused verdict's
    patches for the fused path, the clusters' for the per-frame one."""
    groups: dict[tuple[str, str, float, float], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(r["method"], r["sensor"], r["altitude_m"], r["height_m"])].append(r)
    out = []
    for (method, sensor, alt, h), g in sorted(groups.items()):
        key = "patches" if method == "fused" else "clusters"
        box, ground = [r[f"{key}_box"] for r in g], [r[f"{key}_ground"] for r in g]
        prec = [r["mask_precision"] for r in g if r["mask_precision"] is not None]
        out.append({"method": method, "sensor": sensor, "altitude_m": alt, "height_m": h, "runs": len(g),
                    "raised_by_tolerance": h > max_step, "sites": sum(r["status"] == "site" for r in g),
                    "sites_on_box": sum(r["status"] == "site" and r["site_on_box"] for r in g),
                    "sites_truly_safe": sum(r["status"] == "site" and bool(r["site_safe"]) for r in g),
                    "frame_sites": sum(r["frames_with_site"] for r in g),
                    "frame_sites_on_box": sum(r["frames_site_on_box"] for r in g),
                    "box_tests": sum(b["n"] for b in box), "box_refused": sum(b["refused"] for b in box),
                    "box_read_m": _span([b["height_m"] for b in box]),
                    "box_threshold_m": _span([b["threshold_m"] for b in box]),
                    "box_passed_max_m": max((b["passed_max_m"] for b in box if b["passed_max_m"] is not None),
                                            default=None),
                    "ground_tests": sum(b["n"] for b in ground), "ground_refused": sum(b["refused"] for b in ground),
                    "ground_read_m": _span([b["height_m"] for b in ground]),
                    "box_cells_safe": sum(r["box_cells_safe"] for r in g) if method == "fused" else None,
                    "mask_precision_min": min(prec) if prec else None})
    return out


def main() -> None:
    from click.testing import CliRunner

    from slzcli.config import load_config

    ap = harness.parser(__doc__, "raised_low")
    ap.add_argument("--heights", default="0.06,0.12,0.2,0.3,0.5", help="box heights, m")
    ap.add_argument("--sensors", default="gauss0.003,d435,d455")
    ap.add_argument("--altitudes", default="5,7.5")
    ap.add_argument("--motions", default="hover,4")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/raised_low"), help="rendered flights")
    ap.add_argument("--render-only", action="store_true")
    ap.add_argument("--rendered-only", action="store_true", help="measure only the flights already in the cache "
                    "(beside a --render-only run)")
    ap.add_argument("--rows", type=Path, default=None, help="keep each run's row in this folder and reuse it "
                    "(a rerun of the same code measures only what is missing)")
    ap.add_argument("--set", dest="sets", action="append", default=[])
    args = ap.parse_args()
    extra = [a for kv in args.sets for a in ("--set", kv)]
    max_step = load_config(None, args.sets).uav.max_step_m
    args.cache.mkdir(parents=True, exist_ok=True)
    runner = CliRunner()
    rows: list[dict[str, Any]] = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for sensor in args.sensors.split(","):
            for alt in (float(a) for a in args.altitudes.split(",")):
                for motion in args.motions.split(","):
                    for h in (float(v) for v in args.heights.split(",")):
                        name = flight_name(h, alt, sensor, motion, seed)
                        if args.rendered_only and not (args.cache / f"{name}.mcap.gt.npz").exists():
                            continue
                        rec = render(args.cache, h, alt, sensor, motion, seed)
                        if args.render_only:
                            print(rec.name, flush=True)
                            continue
                        for method in ("fuzzy", "fused"):
                            kept = None if args.rows is None else args.rows / f"{name}_{method}.json"
                            if kept is not None and kept.exists():
                                rows.append(json.loads(kept.read_text()))
                                continue
                            row = {"height_m": h, "sensor": sensor, "altitude_m": alt, "motion": motion, "seed": seed,
                                   "method": method, **detect(runner, rec, method, extra)}
                            if kept is not None:
                                kept.parent.mkdir(parents=True, exist_ok=True)
                                kept.write_text(json.dumps(row))
                            rows.append(row)
                            print(json.dumps(row), flush=True)
    if args.render_only:
        return
    table = summarise(rows, max_step)
    harness.write_results(args.out, {"max_step_m": max_step, "heights": args.heights, "sensors": args.sensors,
                                     "altitudes": args.altitudes, "motions": args.motions, "seeds": args.seeds,
                                     "frames": FRAMES, "rate_hz": RATE_HZ, "set": args.sets, "table": table,
                                     "rows": rows}, indent=1)
    def rng(v: Any) -> str:
        return "-" if v is None else f"{v[0]:.3f}..{v[1]:.3f}"

    print(f"{'method':6} {'sensor':10} {'alt':>4} {'box_m':>5} {'runs':>4} {'sites':>5} {'onbox':>5} {'safe':>4} "
          f"{'frOnBox':>7} {'boxTest':>7} {'refused':>7} {'box_read_m':>13} {'threshold_m':>13} {'gndRef':>6} "
          f"{'ground_read_m':>14} {'cells':>5} {'minP':>6}")
    for t in table:
        p = "-" if t["mask_precision_min"] is None else f"{t['mask_precision_min']:.3f}"
        c = "-" if t["box_cells_safe"] is None else str(t["box_cells_safe"])
        print(f"{t['method']:6} {t['sensor']:10} {t['altitude_m']:>4g} {t['height_m']:>5g} {t['runs']:>4} "
              f"{t['sites']:>5} {t['sites_on_box']:>5} {t['sites_truly_safe']:>4} "
              f"{t['frame_sites_on_box']:>3}/{t['frame_sites']:<3} {t['box_tests']:>7} {t['box_refused']:>7} "
              f"{rng(t['box_read_m']):>13} {rng(t['box_threshold_m']):>13} "
              f"{t['ground_refused']:>3}/{t['ground_tests']:<3}{rng(t['ground_read_m']):>14} {c:>5} {p:>6}")


if __name__ == "__main__":
    main()
