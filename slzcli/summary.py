"""What a detection run accumulates (``RunState``) and what it sums up to (``summarise`` -> ``RunResult``).

Computed here, written by ``outputs/run_folder.py``: the stage timings, the map segments and
the run's world frame, the no-site reason, the depth-noise summary, the ground-truth figures
(``evaluate/truth.py``) and the versions. ``slz detect`` and ``slz compare`` share the reason.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.evaluate.timing import StageTimer
from slzcli.evaluate.truth import TruthEvaluator, site_truth_of
from slzcli.landing.commit import spread_record
from slzcli.outputs.results_mcap import MAP_FRAME, map_frame_of
from slzcli.outputs.run_folder import landing_record
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import KeyframeLog, PoseLog, trajectory_files
from slzcli.slam.segments import Segment, primary_segment, segment_table
from slzcli.terrain.noise import NoiseTracker
from slzcli.types import CommittedSite, RunResult, Working
from slzcli.version import __version__

PER_FRAME_STAGES = ("maps", "score", "mask", "slam", "select")  # the per-frame total; "write" is apart
_COLUMN_CUT_NOTED = 0.5  # the column rule is named in a no-site reason when it removed at least this share


@dataclass
class RunState:
    """What accumulates over a recording: poses, detections' summaries, timings."""

    timer: StageTimer = field(default_factory=StageTimer)
    trajectory: PoseLog = field(default_factory=PoseLog)  # every frame's stamp, pose (None: not tracked), segment
    tracking: dict[str, int] = field(default_factory=dict)
    keyframes: KeyframeLog = field(default_factory=KeyframeLog)  # count only unless given a folder
    sites: SiteLog = field(default_factory=SiteLog)  # candidate rows and sites (in memory unless given a folder)
    frames: int = 0
    detections: int = 0
    detections_without_depth: int = 0
    noise: NoiseTracker | None = None  # the depth noise of the detection frames, smoothed over the run
    unvouched: int = 0                 # detection frames whose noise hides what the UAV cannot tolerate
    worst_unvouched: Working | None = None  # the highest of them, for the no-site reason
    unvouched_reason: str = ""         # limits.limit_reason of that frame
    column_cut: float | None = None    # least fraction of the safe ground a detection lost to the descent column
    method_reason: str = ""            # a method the maps do not gate (px4slp): why its latest frame gave no site


def versions() -> dict[str, str]:
    """Versions for run.json. Open3D's comes from its metadata: importing it only to read the
    version cost ~150 MiB of resident memory at the end of every run (the run's peak)."""
    try:
        o3d = version("open3d")
    except PackageNotFoundError:
        o3d = "not installed"
    return {"slz": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "opencv": cv2.__version__, "open3d": o3d}


def stage_timings(timing: dict[str, dict[str, float]], method: str) -> dict[str, float]:
    """landing.json / run.json ``timings_ms``: the median of each stage (ms), ``total`` of the per-frame ones."""
    med = {k: round(v["median_ms"], 3) for k, v in timing.items()}
    return {"maps": med.get("maps", 0.0), method: med.get("score", 0.0), "mask": med.get("mask", 0.0),
            "slam": med.get("slam", 0.0), "select": med.get("select", 0.0),
            "total": round(sum(med.get(k, 0.0) for k in PER_FRAME_STAGES), 3),
            "write": med.get("write", 0.0),  # a detection frame's files (output.level) + results.mcap; not in total
            "write_wait": med.get("write_wait", 0.0)}  # of which the main loop waited (the writer runs beside it)


def world_frame_text(slam_name: str, poses_are_recorded: bool, table: list[Segment], primary: int | None) -> str:
    """landing.json ``world_frame``: what the run's world frame is, and which map segment it belongs to."""
    if poses_are_recorded:
        return "the recording's world frame (recorded poses)"
    if len(table) <= 1 or primary is None:
        return (f"{slam_name} map, gravity-aligned: z up from camera.mount at the first tracked frame, "
                "x along that camera's x, origin at that camera")
    first = next(s for s in table if s.segment == primary).first_frame
    return (f"{slam_name} map segment {primary} (of {len(table)} maps: tracking was lost and new maps begun, "
            f"each in its own frame), gravity-aligned: z up from camera.mount at its first tracked frame "
            f"(frame {first}), x along that camera's x, origin at that camera")


def slam_summary(slam_name: str, table: list[Segment], primary: int | None,
                 tum_files: dict[int, str], map_frame: str = MAP_FRAME) -> dict[str, Any]:
    """run.json ``summary.slam``: how many maps the backend started and what each one holds."""
    return {"backend": slam_name, "maps": len(table), "segment": primary, "segments": [
        {"segment": s.segment, "frames_tracked": s.frames_tracked, "first_frame": s.first_frame,
         "last_frame": s.last_frame, "keyframes": s.keyframes, "trajectory": tum_files.get(s.segment),
         "mcap_frame": map_frame_of(s.segment, map_frame)} for s in table]}


def untracked_frames(has_pose: np.ndarray, tracking: dict[str, int], slam_name: str,
                     max_share: float) -> dict[str, Any]:
    """run.json ``summary.slam``'s count of the frames the backend gave no pose (every backend alike: a frame
    the tracker logged without a pose), their share, and a warning above ``slam.max_untracked_share``."""
    n = len(has_pose)
    lost = int(n - np.count_nonzero(has_pose))
    share = lost / n if n else 0.0
    warning = ""
    if share > max_share:
        states = ", ".join(f"{count} {state}" for state, count in sorted(tracking.items()) if state != "ok")
        warning = (f"{slam_name} could not track {lost} of {n} frames ({share:.0%}: {states or 'no pose'}), more than "
                   f"slam.max_untracked_share {max_share:.0%}: those frames have no pose and no detection, the result "
                   f"rests on the {n - lost} tracked ones (slower motion, a higher frame rate or more texture helps)")
    return {"frames_untracked": lost, "untracked_share": round(share, 4), "warning": warning}


def no_site_reason(st: RunState, slam_name: str, keyframes: int) -> str:
    """Why a run found no site, from its RunState (``slz detect`` and ``slz compare``)."""
    if st.detections == 0:
        return "no frame was due for detection (no keyframe was tracked)"
    if st.detections_without_depth == st.detections:
        return (f"no valid depth in any of the {st.detections} detection frames (all NaN or 0): check the depth "
                "topic's encoding, sources.depth_unit_16u_m and sources.max_depth_m")
    if st.method_reason:  # a method the maps do not gate says why itself (px4slp: the grid planner)
        return f"{st.method_reason} (the last of {st.detections} detection frames without a site)"
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


def noise_summary(st: RunState) -> dict[str, Any]:
    """The depth noise the maps were made with, and how many detection frames it kept from vouching."""
    out: dict[str, Any] = dict(st.noise.summary()) if st.noise is not None else {}
    out["detections_not_vouched"] = st.unvouched
    if st.worst_unvouched is not None:
        out["not_vouched"] = {**st.worst_unvouched.as_dict(), "reason": st.unvouched_reason}
    return out


def _height(center_world: list[float], st: RunState, table: list[Segment], primary: int | None,
            config: Config) -> dict[str, Any]:
    """landing.json ``site.height``: above the ground and above the start, in the site's map frame."""
    from slzcli.landing.height import site_height

    segment = primary if primary is not None else 0
    first = next((s.first_frame for s in table if s.segment == segment), 0)
    pose = st.trajectory.poses()[first] if len(st.trajectory) > first else None
    xyz = st.keyframes.map_xyz(primary if len(table) > 1 else None)
    return site_height(center_world, np.asarray(xyz)[:, 2], map_frame_of(segment, config.output.map_frame), first,
                       0.0 if pose is None else float(pose[2, 3]))


def site_truth(truth: Any | None, committed: CommittedSite | None) -> dict[str, Any] | None:
    """landing.json ``site.ground_truth`` of the committed site (None without truth or site)."""
    if truth is None or committed is None:
        return None
    return site_truth_of(truth, committed.frame, committed.site.center_camera).as_dict()


def summarise(source: Path, config: Config, method: str, info: Any, report: Any, st: RunState, slam_name: str,
              poses_are_recorded: bool, committed: CommittedSite | None, truth: TruthEvaluator | None,
              wall_s: float, key: dict[str, Any]) -> RunResult:
    """landing.json and run.json of a finished run (nothing is written here).

    ``poses_are_recorded``: the backend's capability (``slam.base.SlamBackend``), for the world frame's text.
    ``truth``: the run's ground-truth evaluator (None: no ground truth).
    ``key``: the rerun key and the digests of the files it covers (``fingerprint``), kept in run.json.
    """
    timing = st.timer.summary()
    timings = stage_timings(timing, method)
    table = segment_table(st.trajectory.segments(), st.trajectory.has_pose(), st.keyframes.per_segment)
    primary = primary_segment(table, None if committed is None else committed.segment)
    world = world_frame_text(slam_name, poses_are_recorded, table, primary)
    reason = no_site_reason(st, slam_name, len(st.keyframes))
    site_gt = site_truth(None if truth is None else truth.truth, committed)
    spread = None if committed is None else spread_record(committed.ranked, config.uav.footprint_m[0])
    landing = landing_record(source, method, committed, world, timings, reason, site_gt, primary, spread)
    if committed is not None:
        landing["site"]["height"] = _height(landing["site"]["center_world"], st, table, primary, config)
    noise = noise_summary(st)
    summary: dict[str, Any] = {
        "source": str(source), "method": method, "frames": st.frames, "detections": st.detections,
        "status": landing["status"], "site_world": landing.get("site", {}).get("center_world"),
        "site_height": landing.get("site", {}).get("height"),
        "reason": landing.get("reason"), "site_spread_m": landing.get("site_spread_m"),
        "slam_backend": slam_name, "tracking": st.tracking,
        "slam": {**slam_summary(slam_name, table, primary, trajectory_files(st.trajectory), config.output.map_frame),
                 **untracked_frames(st.trajectory.has_pose(), st.tracking, slam_name, config.slam.max_untracked_share)},
        "keyframes": len(st.keyframes), "timings_ms": timings, "wall_s": round(wall_s, 3),
        "outputs": config.output.level,
        "depth_noise": noise,
        "depth_limits": landing.get("site", {}).get("depth_limits") or noise.get("not_vouched"),
        "pairing": {"paired": report.paired, "unpaired_color": report.unpaired_color,
                    "unpaired_depth": report.unpaired_depth, "undecodable": report.undecodable,
                    "outside_window": report.outside_window, "notes": list(report.notes)},
    }
    if truth is not None:
        summary["ground_truth"] = truth.summary(st.trajectory.poses(), st.trajectory.segments().tolist(),
                                                landing.get("site"))
    run = {"summary": summary, "config_hash": config.hash(), "key": key, "versions": versions(),
           "config": config.to_dict(), "recording": info.to_dict(), "timings": timing}
    return RunResult(landing, run, committed, primary, primary if len(table) > 1 else None)
