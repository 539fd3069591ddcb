"""The run folder of ``slz detect`` (DESIGN.md "Run folder") and the ``landing.json`` contract.

Files: run.json, landing.json, sites.csv, points.ply, trajectory.tum, keyframes.npz,
frames/NNNNNN/{depth_variance,flatness,inclination,steepness,score,mask,overlay}.png + maps.npz.
Everything here writes into the temporary run folder the pipeline hands it; the folder is
put in place only when all of it is written (``output_dir.build``: only the names a run
writes, ``output_dir.DETECT_NAMES``, are ever replaced; ``ibvs/`` and a user's files stay).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slzcli.config import Config
from slzcli.evaluate.safety import site_truth, total, visible_cells
from slzcli.outputs import files, images
from slzcli.outputs.points import write_points_ply
from slzcli.outputs.trajectory import write_tum



def write_detection(run_dir: Path, det: Any, config: Config) -> None:
    """One detection frame: the maps as heat maps, score, mask, overlay (Figure 6 style), maps.npz."""
    if not config.output.frame_images:
        return
    folder = run_dir / "frames" / f"{det.frame.index:06d}"
    reverse = config.output.reverse_colormap
    valid = det.maps.valid
    for name, values in det.maps.as_dict().items():
        images.write_png(folder / f"{name}.png", images.heatmap_bgr(values, reverse=reverse, valid=valid))
    images.write_png(folder / "score.png", images.heatmap_bgr(det.score.score, reverse=reverse, valid=valid))
    images.write_png(folder / "mask.png", images.mask_png(det.score.mask))
    images.write_png(folder / "overlay.png", detection_overlay_bgr(det))
    files.write_npz(folder / "maps.npz", score=det.score.score, mask=det.score.mask, valid=valid,
                    slope_deg=det.maps.slope_deg, edge_distance_m=det.edge_m, **det.maps.as_dict())


def detection_overlay_bgr(det: Any) -> np.ndarray:
    """The Figure 6 overlay of one detection: mask tint, SLAM points, chosen cluster, Eq. 10 square."""
    sel = det.selection
    chosen = corners_px = None
    if sel is not None and sel.site is not None:
        centre = np.asarray(sel.site.center_world)
        nearest = min(sel.candidates, key=lambda c: float(np.linalg.norm(np.asarray(c.centroid_world) - centre)))
        chosen = sel.labels == nearest.cluster
        from slzcli.landing.select import project

        corners_px, _ = project(np.asarray(sel.site.corners_world), det.T_world_camera, det.frame.K,
                                det.score.mask.shape)
    return images.site_overlay_bgr(det.frame.rgb, det.score.mask, None if sel is None else sel.projected,
                                   None if sel is None else sel.kept, chosen, corners_px)


def landing_record(source: Path, method: str, committed: dict[str, Any] | None, world_frame: str,
                   timings: dict[str, float], reason: str, truth: Any | None) -> dict[str, Any]:
    """landing.json: the contract in DESIGN.md, plus the acceptance test and ground-truth check."""
    rec: dict[str, Any] = {"status": "site" if committed else "no_safe_site", "method": method,
                           "source": str(source)}
    if committed is None:
        rec["reason"] = reason
    else:
        s, frame = committed["site"], committed["frame"]
        rec["frame"] = {"index": frame.index, "stamp_ns": frame.stamp_ns}
        rec["site"] = {
            "pixel": list(s.pixel), "center_camera": list(s.center_camera), "center_world": list(s.center_world),
            "corners_world": [list(c) for c in s.corners_world], "normal_world": list(s.normal_world),
            "cluster": {"points": s.cluster_points, "normal_variance": s.normal_variance,
                        "extent_m": list(s.extent_m)},
            "score": s.score,
            "acceptance": {"passed": s.accepted, "reason": s.acceptance_reason, "tilt_deg": s.tilt_deg,
                           "edge_clearance_m": s.edge_clearance_m},
            "support": {"detections_agreeing": committed["support"], "detections_with_site": committed["detections"]},
        }
        if truth is not None:
            rec["site"]["ground_truth"] = _site_truth(truth, frame, s.center_camera).as_dict()
    rec["world_frame"] = world_frame
    rec["timings_ms"] = timings
    return rec


def _site_truth(truth: Any, frame: Any, center_camera: tuple[float, float, float]) -> Any:
    """The site in the ground-truth world: through the TRUE pose of its frame (not SLAM's)."""
    T = truth.T_world_camera[truth.index_of(frame.stamp_ns, tolerance_ns=1_000_000)]
    p = T[:3, :3] @ np.asarray(center_camera) + T[:3, 3]
    visible = visible_cells(truth.raster, T, frame.K, frame.shape)
    return site_truth(truth.raster, (float(p[0]), float(p[1])), visible)


def write_run(run_dir: Path, source: Path, config: Config, method: str, info: Any, report: Any, det: Any,
              committed: dict[str, Any] | None, truth: Any | None, wall_s: float,
              key: dict[str, Any]) -> dict[str, Any]:
    """Everything but the per-frame folders; returns the summary that run.json holds.

    ``key``: the rerun key and the digests of the files it covers (``fingerprint``), kept in run.json.
    """
    from slzcli.pipeline import versions

    st = det.state
    timing = st.timer.summary()
    med = {k: round(v["median_ms"], 3) for k, v in timing.items()}
    per_frame = ("maps", "score", "mask", "slam", "select")
    timings = {"maps": med.get("maps", 0.0), method: med.get("score", 0.0), "mask": med.get("mask", 0.0),
               "slam": med.get("slam", 0.0), "select": med.get("select", 0.0),
               "total": round(sum(med.get(k, 0.0) for k in per_frame), 3)}
    world = ("the recording's world frame (recorded poses)" if det.slam_name == "recorded" else
             f"{det.slam_name} map, gravity-aligned: z up from camera.mount at the first tracked frame, "
             "x along that camera's x, origin at that camera")
    reason = no_site_reason(st, det.slam_name, len(st.keyframes))
    landing = landing_record(source, method, committed, world, timings, reason, truth)
    files.write_json(run_dir / "landing.json", landing)
    st.sites.write_csv(run_dir / "sites.csv")
    write_tum(run_dir / "trajectory.tum", st.trajectory.stamps, st.trajectory.poses())
    st.keyframes.write_npz(run_dir / "keyframes.npz")
    write_points_ply(run_dir / "points.ply", _points_by_role(st, committed))

    summary: dict[str, Any] = {
        "source": str(source), "method": method, "frames": st.frames, "detections": st.detections,
        "status": landing["status"], "site_world": landing.get("site", {}).get("center_world"),
        "reason": landing.get("reason"), "slam_backend": det.slam_name, "tracking": st.tracking,
        "keyframes": len(st.keyframes), "timings_ms": timings, "wall_s": round(wall_s, 3),
        "pairing": {"paired": report.paired, "unpaired_color": report.unpaired_color,
                    "unpaired_depth": report.unpaired_depth, "undecodable": report.undecodable,
                    "notes": list(report.notes)},
    }
    if truth is not None:
        summary["ground_truth"] = _truth_summary(st, landing)
    files.write_json(run_dir / "run.json", {
        "summary": summary, "config_hash": config.hash(), "key": key, "versions": versions(),
        "config": config.to_dict(), "recording": info.to_dict(), "timings": timing})
    return summary


def no_site_reason(st: Any, slam_name: str, keyframes: int) -> str:
    """Why a run found no site, from its RunState (``slz detect`` and ``slz compare``)."""
    if st.detections == 0:
        return "no frame was due for detection (no keyframe was tracked)"
    if st.detections_without_depth == st.detections:
        return (f"no valid depth in any of the {st.detections} detection frames (all NaN or 0): check the depth "
                "topic's encoding, sources.depth_unit_16u_m and sources.max_depth_m")
    if not keyframes:
        return f"the {slam_name} backend gave no keyframe with map points"
    if not st.sites.rows:
        return "no SLAM map point of any keyframe fell on the landing mask"
    return "no cluster of mask-filtered map points met the footprint in any detection frame"


def _truth_summary(st: Any, landing: dict[str, Any]) -> dict[str, Any]:
    from slzcli.evaluate.slam import ate, rpe

    out: dict[str, Any] = {"mask": total(st.truth).as_dict() if st.truth else None}
    est, true = st.trajectory.poses(), st.truth_trajectory.poses()
    pairs = [(e, t) for e, t in zip(est, true) if e is not None and t is not None]
    if len(pairs) >= 3:
        res = ate([e for e, _ in pairs], [t for _, t in pairs])
        out["slam_ate_rmse_m"] = res.rmse_m
        rel = rpe(est, true)  # consecutive frames; lost frames are skipped, not interpolated
        out["slam_rpe"] = {"trans_rmse_m": rel.trans_rmse_m, "rot_rmse_deg": rel.rot_rmse_deg, "pairs": rel.n}
    if "site" in landing:
        out["site"] = landing["site"].get("ground_truth")
    return out


def _points_by_role(st: Any, committed: dict[str, Any] | None) -> dict[str, np.ndarray]:
    roles: dict[str, np.ndarray] = {"map": st.keyframes.map_xyz()}
    if committed is not None:
        roles["kept"], roles["chosen"] = st.sites.points(committed)
        roles["corner"] = np.asarray(committed["site"].corners_world)
    return roles
