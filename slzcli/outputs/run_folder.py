"""The run folder of ``slz detect`` (DESIGN.md "Run folder") and the ``landing.json`` contract.

Files: run.json, landing.json, sites.csv, points.ply, trajectory.tum (and trajectory.seg<K>.tum
after a SLAM map reset), keyframes.npz,
frames/NNNNNN/ by ``output.level``: nothing (summary), maps.npz + overlay.png (maps, the default),
+ {depth_variance,flatness,inclination,steepness,score,mask}.png (all).
Everything here writes into the temporary run folder the pipeline hands it; the folder is
put in place only when all of it is written (``output_dir.build``: only the names a run
writes, ``output_dir.DETECT_NAMES``, are ever replaced; ``ibvs/`` and a user's files stay).

SLAM map segments (``slzcli.slam.segments``): landing.json, trajectory.tum and the map points
of points.ply are in the world frame of one segment, the run's (``map_segment`` in
landing.json, ``summary.slam.segment`` in run.json); run.json ``summary.slam`` lists every
segment with its frames, keyframes, TUM file and results.mcap frame id.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slzcli.config import Config
from slzcli.evaluate.safety import site_truth, total, visible_cells
from slzcli.outputs import files, images
from slzcli.outputs.points import write_points_ply
from slzcli.outputs.results_mcap import frame_ids
from slzcli.outputs.trajectory import write_trajectories
from slzcli.slam.segments import Segment, primary_segment, segment_table

# maps.npz: members stored, not deflated (deflating ~5.9 MB of float32 took ~0.35-0.46 s a frame against ~6 ms
# stored: benchmarks/writes.py). The maps are float16 (relative error <= 2**-11: +-0.00025 on the [0, 1] maps,
# +-0.03 deg on slope_deg, +-2 mm at 4 m on edge_distance_m, NaN kept); score stays float32 so that
# score >= mask.threshold gives back the mask exactly, mask and valid stay bool.
MAPS_DTYPE = np.float16
LEVELS = ("summary", "maps", "all")  # output.level, each writing what the one before it writes and more


def detection_arrays(det: Any) -> dict[str, np.ndarray]:
    """The members of one detection's maps.npz (precision: ``MAPS_DTYPE`` above)."""
    maps = {k: np.asarray(v).astype(MAPS_DTYPE) for k, v in det.maps.as_dict().items()}
    out = {"score": np.asarray(det.score.score, np.float32), "mask": det.score.mask, "valid": det.maps.valid,
           "slope_deg": np.asarray(det.maps.slope_deg).astype(MAPS_DTYPE)}
    if det.edge_m is not None:
        out["edge_distance_m"] = np.asarray(det.edge_m).astype(MAPS_DTYPE)
    return {**out, **maps}


def write_detection(run_dir: Path, det: Any, config: Config) -> None:
    """One detection frame's folder at ``output.level``: maps.npz and the overlay (Figure 6 style) at
    ``maps``, the maps, score and mask as heat maps too at ``all``, no folder at ``summary``."""
    level = config.output.level
    if level == "summary":
        return
    folder = run_dir / "frames" / f"{det.frame.index:06d}"
    arrays = detection_arrays(det)
    files.write_npz_streamed(folder / "maps.npz", arrays, stored=frozenset(arrays))
    images.write_png(folder / "overlay.png", detection_overlay_bgr(det))
    if level != "all":
        return
    reverse = config.output.reverse_colormap
    valid = det.maps.valid
    for name, values in det.maps.as_dict().items():
        images.write_png(folder / f"{name}.png", images.heatmap_bgr(values, reverse=reverse, valid=valid))
    images.write_png(folder / "score.png", images.heatmap_bgr(det.score.score, reverse=reverse, valid=valid))
    images.write_png(folder / "mask.png", images.mask_png(det.score.mask))


def detection_overlay_bgr(det: Any) -> np.ndarray:
    """The Figure 6 overlay of one detection: mask tint, SLAM points, chosen cluster, Eq. 10 square."""
    sel = det.selection
    chosen = corners_px = None
    if sel is not None and sel.site is not None:
        centre = np.asarray(sel.site.center_world)
        nearest = min(sel.candidates, key=lambda c: float(np.linalg.norm(np.asarray(c.centroid_world) - centre)))
        chosen = sel.labels == nearest.cluster
        from slzcli.geometry import project

        corners_px, _ = project(np.asarray(sel.site.corners_world), det.T_world_camera, det.frame.K,
                                det.score.mask.shape)
    return images.site_overlay_bgr(det.frame.rgb, det.score.mask, None if sel is None else sel.projected,
                                   None if sel is None else sel.kept, chosen, corners_px)


def landing_record(source: Path, method: str, committed: dict[str, Any] | None, world_frame: str,
                   timings: dict[str, float], reason: str, truth: Any | None,
                   map_segment: int | None = None) -> dict[str, Any]:
    """landing.json: the contract in DESIGN.md, plus the acceptance test, ground-truth check and map segment."""
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
            "support": {"detections_agreeing": committed["support"], "detections_with_site": committed["detections"],
                        "detections_with_site_in_map_segment": committed["segment_detections"]},
            "depth_limits": committed.get("limits"),
        }
        if truth is not None:
            rec["site"]["ground_truth"] = _site_truth(truth, frame, s.center_camera).as_dict()
    rec["world_frame"] = world_frame
    rec["map_segment"] = map_segment
    rec["timings_ms"] = timings
    return rec


def _site_truth(truth: Any, frame: Any, center_camera: tuple[float, float, float]) -> Any:
    """The site in the ground-truth world: through the TRUE pose of its frame (not SLAM's)."""
    T = truth.T_world_camera[truth.index_of(frame.stamp_ns)]
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
               "total": round(sum(med.get(k, 0.0) for k in per_frame), 3),
               "write": med.get("write", 0.0)}  # a detection frame's files (output.level) + results.mcap; not in total
    table = segment_table(st.trajectory.segments(), st.trajectory.has_pose(), st.keyframes.per_segment)
    primary = primary_segment(table, None if committed is None else committed["segment"])
    world = world_frame_text(det.slam_name, table, primary)
    reason = no_site_reason(st, det.slam_name, len(st.keyframes))
    landing = landing_record(source, method, committed, world, timings, reason, truth, primary)
    files.write_json(run_dir / "landing.json", landing)
    st.sites.write_csv(run_dir / "sites.csv")
    tum_files = write_trajectories(run_dir, st.trajectory, primary)
    st.keyframes.write_npz(run_dir / "keyframes.npz")
    write_points_ply(run_dir / "points.ply", _points_by_role(st, committed, primary if len(table) > 1 else None))

    summary: dict[str, Any] = {
        "source": str(source), "method": method, "frames": st.frames, "detections": st.detections,
        "status": landing["status"], "site_world": landing.get("site", {}).get("center_world"),
        "reason": landing.get("reason"), "slam_backend": det.slam_name, "tracking": st.tracking,
        "slam": slam_summary(det.slam_name, table, primary, tum_files),
        "keyframes": len(st.keyframes), "timings_ms": timings, "wall_s": round(wall_s, 3),
        "outputs": config.output.level,
        "depth_noise": _noise_summary(st),
        "depth_limits": landing.get("site", {}).get("depth_limits") or _noise_summary(st).get("not_vouched"),
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


def world_frame_text(slam_name: str, table: list[Segment], primary: int | None) -> str:
    """landing.json ``world_frame``: what the run's world frame is, and which map segment it belongs to."""
    if slam_name == "recorded":
        return "the recording's world frame (recorded poses)"
    if len(table) <= 1 or primary is None:
        return (f"{slam_name} map, gravity-aligned: z up from camera.mount at the first tracked frame, "
                "x along that camera's x, origin at that camera")
    first = next(s for s in table if s.segment == primary).first_frame
    return (f"{slam_name} map segment {primary} (of {len(table)} maps: tracking was lost and new maps begun, "
            f"each in its own frame), gravity-aligned: z up from camera.mount at its first tracked frame "
            f"(frame {first}), x along that camera's x, origin at that camera")


def slam_summary(slam_name: str, table: list[Segment], primary: int | None,
                 tum_files: dict[int, str]) -> dict[str, Any]:
    """run.json ``summary.slam``: how many maps the backend started and what each one holds."""
    return {"backend": slam_name, "maps": len(table), "segment": primary, "segments": [
        {"segment": s.segment, "frames_tracked": s.frames_tracked, "first_frame": s.first_frame,
         "last_frame": s.last_frame, "keyframes": s.keyframes, "trajectory": tum_files.get(s.segment),
         "mcap_frame": frame_ids(s.segment)[0]} for s in table]}


_COLUMN_CUT_NOTED = 0.5  # the column rule is named in a no-site reason when it removed at least this share


def no_site_reason(st: Any, slam_name: str, keyframes: int) -> str:
    """Why a run found no site, from its RunState (``slz detect`` and ``slz compare``)."""
    if st.detections == 0:
        return "no frame was due for detection (no keyframe was tracked)"
    if st.detections_without_depth == st.detections:
        return (f"no valid depth in any of the {st.detections} detection frames (all NaN or 0): check the depth "
                "topic's encoding, sources.depth_unit_16u_m and sources.max_depth_m")
    if st.unvouched and st.unvouched == st.detections:
        return st.unvouched_reason
    if not keyframes:
        reason = f"the {slam_name} backend gave no keyframe with map points"
    elif not st.sites.rows:
        reason = "no SLAM map point of any keyframe fell on the landing mask"
    else:
        reason = "no cluster of mask-filtered map points met the footprint in any detection frame"
    cut = st.column_cut
    if keyframes and cut is not None and cut >= _COLUMN_CUT_NOTED:
        reason += (f"; the final descent's column (control.desired_depth_m above the ground) was out of view "
                   f"over {cut:.0%} or more of the ground the maps called safe: close to the ground the view is "
                   "too narrow to see what may overhang a site, a higher frame sees more")
    if st.unvouched:
        reason += (f"; {st.unvouched} of {st.detections} detection frames could not vouch for any site: "
                   f"{st.unvouched_reason}")
    return reason


def _noise_summary(st: Any) -> dict[str, Any]:
    """The depth noise the maps were made with, and how many detection frames it kept from vouching."""
    out: dict[str, Any] = dict(st.noise.summary()) if st.noise is not None else {}
    out["detections_not_vouched"] = st.unvouched
    if st.worst_unvouched is not None:
        out["not_vouched"] = {**st.worst_unvouched.as_dict(), "reason": st.unvouched_reason}
    return out


def _truth_summary(st: Any, landing: dict[str, Any]) -> dict[str, Any]:
    from slzcli.evaluate.slam import ate_by_segment, rpe

    out: dict[str, Any] = {"mask": total(st.truth).as_dict() if st.truth else None}
    est, true, segs = st.trajectory.poses(), st.truth_trajectory.poses(), st.trajectory.segments().tolist()
    try:
        res = ate_by_segment(est, true, segs)  # each map segment aligned on its own
    except ValueError:  # fewer than 3 frames with both poses in every segment
        res = None
    if res is not None:
        out["slam_ate_rmse_m"] = res.rmse_m
        out["slam_ate_segments"] = [{"segment": k, "rmse_m": r.rmse_m, "frames": r.n}
                                    for k, r in res.per_segment.items()]
        try:
            rel = rpe(est, true, segments=segs)  # consecutive frames of one segment; lost frames are skipped
            out["slam_rpe"] = {"trans_rmse_m": rel.trans_rmse_m, "rot_rmse_deg": rel.rot_rmse_deg, "pairs": rel.n}
        except ValueError:  # no two consecutive frames with all four poses
            out["slam_rpe"] = None
    if "site" in landing:
        out["site"] = landing["site"].get("ground_truth")
    return out


def _points_by_role(st: Any, committed: dict[str, Any] | None, segment: int | None) -> dict[str, np.ndarray]:
    """points.ply roles; ``segment``: only that map segment's map points (None: all, a run of one segment)."""
    roles: dict[str, np.ndarray] = {"map": st.keyframes.map_xyz(segment)}
    if committed is not None:
        roles["kept"], roles["chosen"] = st.sites.points(committed)
        roles["corner"] = np.asarray(committed["site"].corners_world)
    return roles
