"""What a detection run accumulates (``RunState``) and what it sums up to (``summarise`` -> ``RunResult``).

Computed here, written by ``outputs/run_folder.py``: the stage timings, the map segments and
the run's world frame, the no-site reason, the depth-noise summary, the ground-truth figures
(``evaluate/truth.py``) and the versions. ``slz detect`` and ``slz compare`` share the reason.
"""

from __future__ import annotations

import platform
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.evaluate.timing import StageTimer
from slzcli.evaluate.truth import TruthEvaluator, site_truth_of
from slzcli.funnel import FunnelLog
from slzcli.landing.commit import commit_radius_m, no_commit_reason, spread_record
from slzcli.outputs.records_json import to_json_object
from slzcli.outputs.results_mcap import MAP_FRAME, map_frame_of
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import KeyframeLog, PoseLog, trajectory_files
from slzcli.records import (
    AcceptanceRecord,
    ClusterRecord,
    DecideAdvice,
    FrameStamp,
    JsonObject,
    LandingRecord,
    PairingRecord,
    RunRecord,
    RunSummary,
    SegmentRecord,
    SiteHeight,
    SiteRecord,
    SlamRecord,
    SpreadNote,
    SpreadRecord,
    SupportRecord,
    UntrackedRecord,
)
from slzcli.slam.segments import Segment, primary_segment, segment_table
from slzcli.sources.recording import RecordingInfo
from slzcli.synth.groundtruth import GroundTruth
from slzcli.terrain.limits import WouldVouch
from slzcli.terrain.noise import NoiseTracker
from slzcli.types import CommittedSite, PairingReport, RunResult, Working
from slzcli.version import __version__

PER_FRAME_STAGES = ("maps", "score", "mask", "slam", "select", "fuse")  # the per-frame total; "write" is apart
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
    would_vouch: WouldVouch | None = None   # what that frame hides and below which altitude it would vouch
    highest: Working | None = None     # the highest detection frame's working scale (depth_limits without a site)
    column_cut: float | None = None    # least fraction of the safe ground a detection lost to the descent column
    advice: DecideAdvice | None = None  # the method's own advice of the latest detection frame (fused)
    method_reason: str = ""            # a method the maps do not gate (px4slp): why its latest frame gave no site
    funnel: FunnelLog = field(default_factory=FunnelLog)  # what each filter left in each detection frame

    @property
    def unvouched_reason(self) -> str:
        """The no-site reason of the highest frame that could not vouch ("" without one)."""
        return "" if self.would_vouch is None else self.would_vouch.reason()


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
    # a method that keeps state fuses every frame (``fuse``, its CPU time): a detection frame pays it too, so
    # it is in the total; methods without that stage have no key
    fuse = {"fuse": med["fuse"]} if "fuse" in med else {}
    return {"maps": med.get("maps", 0.0), method: med.get("score", 0.0), "mask": med.get("mask", 0.0),
            "slam": med.get("slam", 0.0), "select": med.get("select", 0.0), **fuse,
            "total": round(sum(med.get(k, 0.0) for k in PER_FRAME_STAGES), 3),
            "write": med.get("write", 0.0),  # a detection frame's files (output.level) + results.mcap; not in total
            "write_wait": med.get("write_wait", 0.0)}  # of which the main loop waited (the writer runs beside it)


def world_frame_text(slam_name: str, poses_are_recorded: bool, table: list[Segment], primary: int | None) -> str:
    """landing.json ``world_frame``: what the run's world frame is, and which map segment it belongs to."""
    if poses_are_recorded:
        return "the recording's world frame (recorded poses)"
    if len(table) <= 1 or primary is None:
        return (f"{slam_name} map, gravity-aligned: z up from the recording's gravity (summary.gravity) at the first "
                "tracked frame, x along that camera's x, origin at that camera")
    first = next(s for s in table if s.segment == primary).first_frame
    return (f"{slam_name} map segment {primary} (of {len(table)} maps: tracking was lost and new maps begun, "
            "each in its own frame), gravity-aligned: z up from the recording's gravity (summary.gravity) at its "
            f"first tracked frame (frame {first}), x along that camera's x, origin at that camera")


def slam_summary(slam_name: str, table: list[Segment], primary: int | None, tum_files: dict[int, str],
                 untracked: UntrackedRecord, map_frame: str = MAP_FRAME) -> SlamRecord:
    """run.json ``summary.slam``: how many maps the backend started, what each one holds, and ``untracked``
    (``untracked_frames``)."""
    return SlamRecord(slam_name, len(table), primary, tuple(
        SegmentRecord(s.segment, s.frames_tracked, s.first_frame, s.last_frame, s.keyframes, tum_files.get(s.segment),
                      map_frame_of(s.segment, map_frame)) for s in table), untracked)


def untracked_frames(has_pose: np.ndarray, tracking: Mapping[str, int], slam_name: str,
                     max_share: float) -> UntrackedRecord:
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
    return UntrackedRecord(lost, round(share, 4), warning)


def no_site_reason(st: RunState, slam_name: str, keyframes: int, radius_m: float) -> str:
    """Why a run found no site, from its RunState (``slz detect`` and ``slz compare``); ``radius_m``: the commit
    radius (``landing.commit.commit_radius_m``)."""
    if st.sites.sites:   # sites were found and none committed: refuted, or none passed its acceptance test
        return no_commit_reason(st.sites.sites, st.sites.raised_readings(), radius_m)
    if st.detections == 0:
        return "no frame was due for detection (no keyframe was tracked)"
    if st.detections_without_depth == st.detections:
        return (f"no valid depth in any of the {st.detections} detection frames (all NaN or 0): check the depth "
                "topic's encoding, sources.depth_unit_16u_m and sources.max_depth_m")
    if st.method_reason:  # a method the maps do not gate says why itself (px4slp: the grid planner)
        return f"{st.method_reason} (the last of {st.detections} detection frames without a site)"
    if st.unvouched and st.unvouched == st.detections:
        return st.unvouched_reason
    funnel = st.funnel.reason(st.unvouched_reason)   # the step that removed the most, what would change it
    if funnel is not None and st.funnel.mask_always_empty():
        return funnel
    if not keyframes:
        reason = f"the {slam_name} backend gave no keyframe with map points"
    elif funnel is not None:
        reason = funnel
    elif not st.sites.rows:
        reason = "no SLAM map point of any keyframe fell on the landing mask"
    else:
        reason = "no cluster of mask-filtered map points met the footprint in any detection frame"
    cut = st.column_cut
    if keyframes and cut is not None and cut >= _COLUMN_CUT_NOTED and "final descent's column" not in reason:
        reason += (f"; the final descent's column (control.desired_depth_m above the ground) was out of view "
                   f"over {cut:.0%} or more of the ground the maps called safe: close to the ground the view is "
                   "too narrow to see what may overhang a site, a higher frame sees more")
    if st.unvouched:
        reason += (f"; {st.unvouched} of {st.detections} detection frames could not vouch for any site: "
                   f"{st.unvouched_reason}")
    return reason


def decide_advice(st: RunState) -> DecideAdvice | None:
    """What would decide the ground of a run without a site: the method's own advice of its latest detection
    frame (fused), else, when depth noise kept detection frames from vouching, the altitude below which the
    highest of them would have vouched (the per-frame limits, ``limits.would_vouch``); else None."""
    if st.advice is not None:
        return st.advice
    v = st.would_vouch
    if v is None:
        return None
    hides = v.hides(with_sigma=False)
    if v.below_m is None:
        return DecideAdvice("depth_limits", f"{hides}, and at no altitude would it not with this sensor")
    return DecideAdvice("depth_limits", f"descend below {v.below_m:.1f} m ({hides})", descend_to_m=round(v.below_m, 2))


def noise_summary(st: RunState) -> dict[str, object]:
    """The depth noise the maps were made with, and how many detection frames it kept from vouching."""
    out: dict[str, object] = dict(st.noise.summary()) if st.noise is not None else {}
    out["detections_not_vouched"] = st.unvouched
    if st.worst_unvouched is not None:
        out["not_vouched"] = {**st.worst_unvouched.as_dict(), "reason": st.unvouched_reason}
    return out


def _height(center_world: tuple[float, float, float], st: RunState, table: list[Segment], primary: int | None,
            config: Config) -> SiteHeight:
    """landing.json ``site.height``: above the ground and above the start, in the site's map frame."""
    from slzcli.landing.height import site_height

    segment = primary if primary is not None else 0
    first = next((s.first_frame for s in table if s.segment == segment), 0)
    pose = st.trajectory.poses()[first] if len(st.trajectory) > first else None
    xyz = st.keyframes.map_xyz(primary if len(table) > 1 else None)
    return SiteHeight(**site_height(list(center_world), np.asarray(xyz)[:, 2],
                                    map_frame_of(segment, config.output.map_frame), first,
                                    0.0 if pose is None else float(pose[2, 3])))


def site_truth(truth: GroundTruth | None, committed: CommittedSite | None) -> JsonObject | None:
    """landing.json ``site.ground_truth`` of the committed site (None without truth or site)."""
    if truth is None or committed is None:
        return None
    return site_truth_of(truth, committed.frame, committed.site.center_camera).as_dict()


def spread_of(committed: CommittedSite, footprint_side_m: float) -> SpreadRecord:
    """landing.json ``site_spread_m`` and ``site_spread`` (``landing.commit.spread_record``)."""
    rec = spread_record(committed.ranked, footprint_side_m)
    return SpreadRecord(rec["site_spread_m"], SpreadNote(**rec["site_spread"]))


def site_record(committed: CommittedSite, site_truth: JsonObject | None = None,
                height: SiteHeight | None = None) -> SiteRecord:
    """landing.json ``site``: the committed site, its acceptance test, support, depth limits and truth."""
    s = committed.site
    return SiteRecord(
        pixel=s.pixel, center_camera=s.center_camera, center_world=s.center_world, corners_world=s.corners_world,
        normal_world=s.normal_world, cluster=ClusterRecord(s.cluster_points, s.normal_variance, s.extent_m),
        score=s.score,
        acceptance=AcceptanceRecord(s.accepted, s.acceptance_reason, s.tilt_deg, s.edge_clearance_m),
        support=SupportRecord(committed.support, committed.detections, committed.segment_detections),
        depth_limits=committed.found.limits, ground_truth=site_truth, height=height, source=s.source)


def landing_record(source: Path, method: str, committed: CommittedSite | None, world_frame: str,
                   timings: Mapping[str, float], reason: str, site: SiteRecord | None = None,
                   map_segment: int | None = None, spread: SpreadRecord | None = None,
                   advice: DecideAdvice | None = None) -> LandingRecord:
    """landing.json (the contract in DESIGN.md): the committed site (``site``: its record, built from
    ``committed`` when None) or why there is none, the world frame, the map segment, the timings."""
    if committed is None:
        return LandingRecord("no_safe_site", method, str(source), reason=reason, advice=advice,
                             world_frame=world_frame, map_segment=map_segment, timings_ms=timings)
    return LandingRecord("site", method, str(source), frame=FrameStamp(committed.frame.index, committed.frame.stamp_ns),
                         site=site or site_record(committed), spread=spread, world_frame=world_frame,
                         map_segment=map_segment, timings_ms=timings)


@dataclass(frozen=True)
class RunFacts:
    """What a finished run knows beside its accumulators: where it read, what ran and how long.

    ``poses_are_recorded``: the backend's capability (``slam.base.SlamBackend``), for the world frame's text;
    ``key``: the rerun key and the digests of the files it covers (``fingerprint``), kept in run.json.
    """

    source: Path
    method: str
    slam_name: str
    poses_are_recorded: bool
    info: RecordingInfo
    report: PairingReport
    wall_s: float
    key: JsonObject


def summarise(facts: RunFacts, config: Config, st: RunState, committed: CommittedSite | None,
              truth: TruthEvaluator | None) -> RunResult:
    """landing.json and run.json of a finished run (nothing is written here); ``truth``: the run's
    ground-truth evaluator (None: no ground truth)."""
    timing = st.timer.summary()
    timings = stage_timings(timing, facts.method)
    table = segment_table(st.trajectory.segments(), st.trajectory.has_pose(), st.keyframes.per_segment)
    primary = primary_segment(table, None if committed is None else committed.segment)
    world = world_frame_text(facts.slam_name, facts.poses_are_recorded, table, primary)
    reason = "" if committed is not None else no_site_reason(st, facts.slam_name, len(st.keyframes),
                                                             commit_radius_m(config.landing, config.uav))
    site: SiteRecord | None = None
    spread: SpreadRecord | None = None
    advice = decide_advice(st) if committed is None else None
    if committed is not None:
        site = site_record(committed, site_truth(None if truth is None else truth.truth, committed),
                           _height(committed.site.center_world, st, table, primary, config))
        spread = spread_of(committed, config.uav.footprint_m[0])
    landing = landing_record(facts.source, facts.method, committed, world, timings, reason, site, primary, spread,
                             advice)
    noise = noise_summary(st)
    not_vouched = noise.get("not_vouched")
    depth_limits = (None if site is None else site.depth_limits) or (
        not_vouched if isinstance(not_vouched, Mapping) and not_vouched else None) or (
        None if st.highest is None else st.highest.as_dict())
    r = facts.report
    ground_truth = None if truth is None else truth.summary(
        st.trajectory.poses(), st.trajectory.segments().tolist(), None if site is None else to_json_object(site))
    summary = RunSummary(
        source=str(facts.source), method=facts.method, frames=st.frames, detections=st.detections,
        status=landing.status, site_world=None if site is None else site.center_world,
        site_height=None if site is None else site.height, reason=landing.reason,
        site_source=None if site is None else site.source,
        site_spread_m=None if spread is None else spread.site_spread_m, advice=advice,
        slam_backend=facts.slam_name, tracking=st.tracking,
        slam=slam_summary(facts.slam_name, table, primary, trajectory_files(st.trajectory),
                          untracked_frames(st.trajectory.has_pose(), st.tracking, facts.slam_name,
                                           config.slam.max_untracked_share), config.output.map_frame),
        keyframes=len(st.keyframes), timings_ms=timings, wall_s=round(facts.wall_s, 3), outputs=config.output.level,
        gravity=facts.info.gravity,  # source, camera tilt, disagreements (slzcli/gravity.py)
        depth_noise=noise, depth_limits=depth_limits,
        pairing=PairingRecord(r.paired, r.unpaired_color, r.unpaired_depth, r.undecodable, r.outside_window,
                              tuple(r.notes)),
        ground_truth=ground_truth)
    run = RunRecord(summary, config.hash(), facts.key, versions(), config.to_dict(), facts.info.to_dict(), timing,
                    st.funnel.as_dict())
    return RunResult(landing, run, committed, primary, primary if len(table) > 1 else None)
