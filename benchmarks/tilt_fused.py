"""Tilted cameras: the fused method and the raised-surface rule on mounts that are not nadir.

    python benchmarks/tilt_fused.py [--seeds 0,1,2] [--tilts 0,15,30] [--scenes level,box,boxrocks]
                                    [--gravity imu,wrong] [--set KEY=VALUE ...]

Per scene x camera pitch on the vehicle (``synth.flight.mount_pitch_deg``; the recording does not say it) x
seed: ``slz synth`` renders a 20-frame transect (1 m/s at 10 Hz, 2 m, from 5.5 m, the view's centre passing
over the origin) with an IMU topic, at 320 x 240 with the gaussian depth model; ``slz detect`` (odometry
SLAM, deterministic) runs per-frame (``--method fuzzy``, the default) and fused (``--method fused``) on it,
with gravity as slz resolves it (``imu``: the IMU topic) and, for a tilted camera, with a wrong one (``wrong``:
``camera.gravity.source=mount`` and the straight-down ``camera.mount``, off by the whole tilt). Scenes, written
beside the recordings: ``level`` (level dirt, nothing on it), ``box`` (a 3.4 x 3.0 x 1.5 m concrete box at the
origin on that ground), ``boxrocks`` (a 1.8 m box on ground strewn with 0.3 m rocks: its top is the only flat
ground in view, every site is unsafe).

Per run: the status, whether the committed site is truly safe (the synth's truth), whether it lies on the
box; the mask's pixel precision and recall over the detection frames (fused: the verdict rendered into them);
fused only: the SAFE cells' precision and recall against the truth raster (cells of the last landing map,
their centres in the synth's world through the first pose) and the level check of the fused heights (a plane
through the seen cells of a level scene: its tilt in degrees and the residuals' 1.4826 MAD); per-frame only:
clusters refused as raised (run.json funnel). Prints a table, writes benchmarks/results/tilt_fused.json.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

import harness
import numpy as np

SIZE = ("--set", "camera.width=320", "--set", "camera.height=240", "--set", "camera.fx=231.0685",
        "--set", "camera.fy=231.0685", "--set", "camera.cx=160", "--set", "camera.cy=120")
ALTITUDE_M = 5.5
SPEED_M_S = 1.0
FRAMES, RATE_HZ = 20, 10.0
SCENES = {
    "level": """description: "Level dirt ground, nothing on it."
ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}
objects: []
""",
    "box": """description: "A 3.4 x 3.0 m concrete box 1.5 m high on level dirt ground."
ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}
objects:
  - {name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, 1.5], material: concrete}
""",
    "boxrocks": """description: "A 3.4 x 3.0 m concrete box 1.8 m high on ground strewn with rocks."
ground: {size_m: [40, 40], center_m: [0, 0], material: dirt}
objects:
  - {name: rock, kind: box, at_m: [-8.0, -10.0], size_m: [0.35, 0.35, 0.3], material: rock,
     repeat: {count: [21, 26], pitch_m: [0.8, 0.8]}}
  - {name: box, kind: box, at_m: [0.0, 0.0], size_m: [3.4, 3.0, 1.8], material: concrete}
""",
}
BOX_HALF = (1.7, 1.5)


def write_scenes(folder: Path) -> None:
    from slzcli.synth.scenes import SCENES_DIR

    shutil.copy(SCENES_DIR / "_common.yaml", folder / "_common.yaml")   # the shared materials
    for name, text in SCENES.items():
        (folder / f"{name}.yaml").write_text(text)


def start_of(tilt_deg: float) -> str:
    """The start whose view centre crosses the origin halfway through the transect (north, +y)."""
    y = -ALTITUDE_M * math.tan(math.radians(tilt_deg)) - 0.5 * SPEED_M_S * (FRAMES - 1) / RATE_HZ
    return f"0,{y:.3f},{ALTITUDE_M}"


def synth(runner: Any, folder: Path, scene: str, tilt: float, seed: int, imu: bool, extra: list[str]) -> Path:
    from slzcli.cli import main

    rec = folder / f"{scene}_t{tilt:g}_s{seed}{'' if imu else '_noimu'}.mcap"
    if not rec.exists():
        res = runner.invoke(main, ["synth", str(folder / f"{scene}.yaml"), "-o", str(rec), "--frames", str(FRAMES),
                                   "--rate", str(RATE_HZ), "--path", "transect", "--start", start_of(tilt),
                                   "--seed", str(seed), "--set", "synth.sensor.model=gaussian",
                                   "--set", f"synth.flight.speed_m_s={SPEED_M_S}",
                                   "--set", f"synth.flight.mount_pitch_deg={tilt}",
                                   "--set", f"synth.imu.enabled={str(imu).lower()}", *SIZE, *extra])
        assert res.exit_code == 0, res.output
    return rec


def _world_of_map(out: Path, truth: Any) -> np.ndarray:
    """4x4 T_world_map: the run's map frame in the synth's world, through the first frame's pose in each."""
    from scipy.spatial.transform import Rotation

    row = next(ln for ln in (out / "trajectory.tum").read_text().splitlines() if not ln.startswith("#")).split()
    T_map_cam = np.eye(4)
    T_map_cam[:3, :3] = Rotation.from_quat([float(v) for v in row[4:8]]).as_matrix()
    T_map_cam[:3, 3] = [float(v) for v in row[1:4]]
    return np.asarray(truth["T_world_camera"][0]) @ np.linalg.inv(T_map_cam)


def fused_cells(out: Path, truth: Any, level: bool) -> dict[str, Any]:
    """The last landing map's SAFE cells against the truth raster, and (level scenes) the heights' levelness."""
    from slzcli.fusion.verdict import SAFE, UNSAFE

    lm = np.load(out / "landing_map.npz")
    verdict, res, org = lm["verdict"], float(lm["resolution_m"]), lm["origin_xy"]
    T = _world_of_map(out, truth)
    jj, ii = np.nonzero(verdict > 0)
    xy_map = np.stack([org[0] + (ii + 0.5) * res, org[1] + (jj + 0.5) * res, lm["height_m"][jj, ii]], axis=1)
    xyz = xy_map @ T[:3, :3].T + T[:3, 3]
    rs, rorg, rres = truth["raster_safe"], truth["raster_origin_xy"], float(truth["raster_resolution_m"])
    c = np.floor((xyz[:, 0] - rorg[0]) / rres).astype(int)
    r = np.floor((xyz[:, 1] - rorg[1]) / rres).astype(int)
    inside = (r >= 0) & (r < rs.shape[0]) & (c >= 0) & (c < rs.shape[1])
    true_safe = np.zeros(len(c), bool)
    true_safe[inside] = rs[r[inside], c[inside]]
    v = verdict[jj, ii]
    said = v == SAFE
    tp, fp, fn = int(np.sum(said & true_safe)), int(np.sum(said & ~true_safe)), int(np.sum(~said & true_safe))
    out_d: dict[str, Any] = {
        "cells_seen": len(v), "cells_safe": int(said.sum()), "cells_unsafe": int(np.sum(v == UNSAFE)),
        "cells_true_safe_seen": int(true_safe.sum()),
        "cell_precision": tp / (tp + fp) if tp + fp else None, "cell_recall": tp / (tp + fn) if tp + fn else None}
    if level:   # the heights of level ground: a plane through them (map frame, gravity-aligned z)
        h = xy_map[:, 2].astype(np.float64)
        ok = np.isfinite(h)
        a = np.c_[np.ones(int(ok.sum())), xy_map[ok, 0], xy_map[ok, 1]]
        coef = np.linalg.lstsq(a, h[ok], rcond=None)[0]
        resid = h[ok] - a @ coef
        out_d["height_tilt_deg"] = math.degrees(math.atan(math.hypot(coef[1], coef[2])))
        out_d["height_resid_m"] = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
        w = np.c_[np.ones(int(ok.sum())), xyz[ok, 0], xyz[ok, 1]]
        cw = np.linalg.lstsq(w, xyz[ok, 2], rcond=None)[0]
        out_d["world_tilt_deg"] = math.degrees(math.atan(math.hypot(cw[1], cw[2])))   # the geometry alone
    return out_d


def detect(runner: Any, rec: Path, method: str, gravity: str, extra: list[str]) -> dict[str, Any]:
    from slzcli.cli import main

    out = rec.with_name(f"{rec.stem}_{method}_{gravity}")
    sets = ["--set", "camera.gravity.source=mount"] if gravity.startswith("wrong") else []
    res = runner.invoke(main, ["detect", str(rec), "-o", str(out), "--force", "--json", "--method", method,
                               "--set", "slam.backend=odometry", *SIZE, *sets, *extra])
    s = json.loads(res.stdout)
    if res.exit_code == 1 and "error" in s:       # refused: the recording contradicts the gravity asked for
        return {"status": "refused", "site_safe": None, "site_on_box": False, "clusters_raised": 0,
                "reason": s["error"]["message"]}
    assert res.exit_code == 0, res.output
    gt = s.get("ground_truth") or {}
    site = gt.get("site") or {}
    xy = site.get("true_xy")
    on_box = "box" in rec.stem and xy is not None and abs(xy[0]) <= BOX_HALF[0] and abs(xy[1]) <= BOX_HALF[1]
    mask = gt.get("mask") or {}
    run = json.loads((out / "run.json").read_text())
    failed = (run.get("funnel") or {}).get("clusters_failed") or {}
    row = {"status": s["status"], "site_safe": site.get("safe"), "site_true_xy": xy, "site_on_box": on_box,
           "mask_precision": mask.get("precision"), "mask_recall": mask.get("recall"),
           "gravity_source": s["gravity"]["source"], "gravity_tilt_deg": s["gravity"]["tilt_deg"],
           "clusters_raised": int(failed.get("raised", 0)), "reason": s.get("reason"),
           "site_source": s.get("site_source")}   # map points (a cluster) or the fused terrain
    if method == "fused":
        row.update(fused_cells(out, np.load(str(rec) + ".gt.npz"), "level" in rec.stem))
    shutil.rmtree(out, ignore_errors=True)
    return row


def verdict_word(r: dict[str, Any]) -> str:
    return "none" if r["status"] != "site" else ("SAFE" if r["site_safe"] else "UNSAFE")


def main() -> None:
    from click.testing import CliRunner

    ap = harness.parser(__doc__, "tilt_fused")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--tilts", default="0,15,30", help="camera pitch on the vehicle, degrees")
    ap.add_argument("--scenes", default="level,box,boxrocks")
    ap.add_argument("--gravity", default="imu,wrong", help="imu: as resolved from the IMU topic; wrong: the "
                    "straight-down camera.mount on a recording without IMU; wrong_imu: the same with the IMU topic "
                    "(tilted cameras only)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the recordings in this folder (default: a temporary one)")
    ap.add_argument("--set", dest="sets", action="append", default=[])
    args = ap.parse_args()
    extra = [a for kv in args.sets for a in ("--set", kv)]
    runner = CliRunner()
    rows = []
    with tempfile.TemporaryDirectory(prefix="tilt_fused_") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        write_scenes(folder)
        for scene in args.scenes.split(","):
            for tilt in (float(t) for t in args.tilts.split(",")):
                for seed in (int(s) for s in args.seeds.split(",")):
                    for gravity in args.gravity.split(","):
                        if gravity.startswith("wrong") and tilt == 0:
                            continue
                        rec = synth(runner, folder, scene, tilt, seed, gravity != "wrong", extra)
                        for method in ("fuzzy", "fused"):
                            row = {"scene": scene, "tilt_deg": tilt, "seed": seed, "gravity": gravity,
                                   "method": method, **detect(runner, rec, method, gravity, extra)}
                            rows.append(row)
                            print(json.dumps(row), flush=True)
    harness.write_results(args.out, {"seeds": args.seeds, "tilts": args.tilts, "scenes": args.scenes,
                                     "set": args.sets, "rows": rows}, indent=1)
    print(f"{'scene':9} {'tilt':>4} {'grav':5} {'method':6} {'seed':>4} {'site':6} {'box':5} {'maskP':>6} {'maskR':>6} "
          f"{'cellP':>6} {'cellR':>6} {'lvl_deg':>7} {'raised':>6}")
    for r in rows:
        def f(k: str, nd: int = 3, r: dict[str, Any] = r) -> str:
            v = r.get(k)
            return "-" if v is None else f"{v:.{nd}f}"
        print(f"{r['scene']:9} {r['tilt_deg']:>4g} {r['gravity']:5} {r['method']:6} {r['seed']:>4} {verdict_word(r):6} "
              f"{r['site_on_box']!s:5} {f('mask_precision')} {f('mask_recall')} {f('cell_precision')} "
              f"{f('cell_recall')} {f('height_tilt_deg', 2):>7} {r['clusters_raised']:>6}")


if __name__ == "__main__":
    main()
