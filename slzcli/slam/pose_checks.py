"""Recorded poses checked against what the frames show, before any of them is used.

A recorded pose is taken as given (REP 103: metres, z up, the camera's optical frame), so a
pose in millimetres, one of another frame convention, an upside-down one or one a second off
the frames gives a site that looks as good as a right one. The first ``slam.pose_check.frames``
frames are read once ahead of the run and each property is checked against the depth:

- stamps: most of those frames must have a pose within ``sources.pose_tolerance_ms``; when they
  do not, the offset to the nearest recorded pose is reported;
- the ground: in the pose's world frame what the camera measures (its depth points) must lie
  below it: an upside-down camera pose puts the ground overhead;
- recorded map points (``slam.points_topic``): through the pose, their depth in the camera must be
  the depth measured at their pixel (the scale even when the camera does not move);
- scale, rotation and direction of motion: between frame pairs far enough apart, the camera
  motion the depth implies (ORB matches, 3D points from the first frame's depth, PnP in the
  second) is compared with the recorded relative pose.

A pair whose motion is below ``min_baseline_fraction`` of the scene's depth proves nothing about
the scale and is skipped; with no such pair the scale is reported as unchecked. Rejected poses
are an error under ``slam.backend: recorded`` and a warning naming the fallback under ``auto``
(``vet_recorded_poses``).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Generator, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np

from slzcli.errors import DatasetError
from slzcli.geometry import invert_pose, transform_points
from slzcli.slam import choose_backend
from slzcli.slam.features import detect, make_orb, ratio_matches
from slzcli.sources.sync import stamp_offset_ns
from slzcli.types import Frame

if TYPE_CHECKING:
    from slzcli.config import SlamCfg
    from slzcli.sources import RecordingInfo

log = logging.getLogger(__name__)
NS_PER_S = 1_000_000_000
DEPTH_STRIDE_PX = 8  # depth pixels sampled per axis for the ground test; a few thousand points suffice


@dataclass(frozen=True, eq=False)
class Seen:
    """What the check keeps of one frame (the images are dropped): stamp, pose, features with their depth."""

    index: int
    stamp_ns: int
    T_world_camera: np.ndarray | None
    px: np.ndarray          # (N, 2) keypoints
    desc: np.ndarray        # (N, 32) ORB descriptors
    xyz: np.ndarray         # (N, 3) camera-frame points of the keypoints (NaN: no depth)
    K: np.ndarray
    ground_above_m: float   # median height of the depth points above the camera, in the pose's world (NaN: none)
    median_depth_m: float
    cloud_ratios: np.ndarray  # recorded map points in view: their depth by the pose / the depth image's there


@dataclass(frozen=True)
class Verdict:
    """``problem``: why the poses cannot be used ("" when they can); ``unchecked``: what could not be tested."""

    problem: str = ""
    unchecked: tuple[str, ...] = ()
    scale_ratio: float | None = None  # median recorded / depth-implied translation over the pairs tested
    pairs: int = 0
    rotation_deg: float | None = None   # median recorded vs depth-implied rotation difference
    direction_deg: float | None = None  # median angle between the recorded and depth-implied motion


def seen(frame: Frame, orb: cv2.ORB, min_depth_m: float, max_depth_m: float) -> Seen:
    """The features and the ground test of one frame."""
    px, desc = detect(orb, frame.rgb)
    K = frame.K
    h, w = frame.depth_m.shape
    ui = np.clip(np.round(px[:, 0]).astype(int), 0, w - 1)
    vi = np.clip(np.round(px[:, 1]).astype(int), 0, h - 1)
    z = frame.depth_m[vi, ui].astype(np.float64)
    z[~((z >= min_depth_m) & (z <= max_depth_m))] = np.nan
    xyz = np.stack([(px[:, 0] - K[0, 2]) * z / K[0, 0], (px[:, 1] - K[1, 2]) * z / K[1, 1], z], axis=1)
    d = frame.depth_m[::DEPTH_STRIDE_PX, ::DEPTH_STRIDE_PX].astype(np.float64)
    v, u = np.mgrid[0:h:DEPTH_STRIDE_PX, 0:w:DEPTH_STRIDE_PX]
    ok = np.isfinite(d) & (d >= min_depth_m) & (d <= max_depth_m)
    above = median_depth = float("nan")
    if ok.any():
        dz = d[ok]
        median_depth = float(np.median(dz))
        if frame.T_world_camera is not None:
            rays = np.stack([(u[ok] - K[0, 2]) / K[0, 0], (v[ok] - K[1, 2]) / K[1, 1], np.ones(dz.size)], axis=1)
            up = np.asarray(frame.T_world_camera, np.float64)[2, :3]  # world z of camera axes
            above = float(np.median((rays @ up) * dz))
    T = None if frame.T_world_camera is None else np.asarray(frame.T_world_camera, np.float64)
    return Seen(frame.index, frame.stamp_ns, T, px, desc, xyz, K, above, median_depth,
                _cloud_ratios(frame, T, min_depth_m, max_depth_m))


def _cloud_ratios(frame: Frame, T: np.ndarray | None, min_depth_m: float, max_depth_m: float) -> np.ndarray:
    """Per recorded map point in view: its depth in the camera by the pose, over the measured depth at its pixel."""
    cloud = frame.map_points
    if cloud is None or T is None or not len(cloud.xyz):
        return np.zeros(0)
    pc = transform_points(invert_pose(T), np.asarray(cloud.xyz, np.float64))
    K, (h, w) = frame.K, frame.depth_m.shape
    z = pc[:, 2]
    ok = z > 0
    u = np.full(len(z), -1.0)
    v = np.full(len(z), -1.0)
    u[ok] = K[0, 0] * pc[ok, 0] / z[ok] + K[0, 2]
    v[ok] = K[1, 1] * pc[ok, 1] / z[ok] + K[1, 2]
    ok &= (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    d = frame.depth_m[np.rint(v[ok]).astype(int), np.rint(u[ok]).astype(int)].astype(np.float64)
    good = np.isfinite(d) & (d >= min_depth_m) & (d <= max_depth_m)
    return z[ok][good] / d[good]


@dataclass(frozen=True, eq=False)
class Motion:
    """The motion between two frames the depth implies: PnP's T_b_a and its inlier correspondences."""

    T_b_a: np.ndarray
    xyz_a: np.ndarray   # (N, 3) points in a's camera
    px_b: np.ndarray    # (N, 2) their pixels in b
    K: np.ndarray       # b's camera


def depth_motion(a: Seen, b: Seen, ratio: float, reprojection_px: float, min_inliers: int) -> Motion | None:
    """T_b_a the depth implies (a's 3D points, PnP in b's pixels); None when too few features agree."""
    q, t = ratio_matches(a.desc, b.desc, ratio)
    ok = np.isfinite(a.xyz[q, 2])
    q, t = q[ok], t[ok]
    if len(q) < min_inliers:
        return None
    found, rvec, tvec, inl = cv2.solvePnPRansac(a.xyz[q], b.px[t].astype(np.float64), b.K, None,
                                                iterationsCount=500, reprojectionError=reprojection_px,
                                                confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not found or inl is None or len(inl) < min_inliers:
        return None
    inl = inl[:, 0]
    xyz, px = a.xyz[q[inl]], b.px[t[inl]].astype(np.float64)
    rvec, tvec = cv2.solvePnPRefineLM(xyz, px, b.K, None, rvec, tvec)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec[:, 0]
    return Motion(T, xyz, px, b.K)


def translation_given(m: Motion, R_b_a: np.ndarray) -> np.ndarray:
    """The translation of T_b_a that best fits the inliers when its rotation is ``R_b_a`` (linear least squares).

    A small sideways move and a small tilt look alike to a narrow camera over flat ground, so PnP on
    noisy depth trades one for the other (0.5 deg is 9 cm at 10 m); with the rotation fixed to the
    recorded one (its scale does not depend on the units) the translation is well determined.
    """
    X = m.xyz_a @ R_b_a.T
    xn = (m.px_b[:, 0] - m.K[0, 2]) / m.K[0, 0]
    yn = (m.px_b[:, 1] - m.K[1, 2]) / m.K[1, 1]
    zeros, ones = np.zeros_like(xn), np.ones_like(xn)
    A = np.concatenate([np.stack([ones, zeros, -xn], axis=1), np.stack([zeros, ones, -yn], axis=1)])
    rhs = np.concatenate([xn * X[:, 2] - X[:, 0], yn * X[:, 2] - X[:, 1]])
    return np.linalg.lstsq(A, rhs, rcond=None)[0]


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _pairs(n: int) -> Iterator[tuple[int, int]]:
    """Frame pairs tested: from three anchors, steps doubling (near pairs match well, far ones move more)."""
    for a in sorted({0, n // 3, (2 * n) // 3}):
        step = 1
        while a + step < n:
            yield a, a + step
            step *= 2


def check(frames: Sequence[Seen], pose_stamps: Sequence[int], slam: SlamCfg, tol_ms: float, topic: str) -> Verdict:
    """The verdict on the recorded poses of ``frames`` (see the module docstring); ``tol_ms``: how far apart a
    frame and its pose may be stamped (``sources.pose_tolerance_ms``)."""
    pc = slam.pose_check
    posed = [f for f in frames if f.T_world_camera is not None]
    if not frames:
        return Verdict(unchecked=("no frame to check the recorded poses against",))
    unchecked: list[str] = []
    late = _late_start(frames, posed, pose_stamps, tol_ms)
    if late:  # the pose stream starts on time but after the first frames (a SLAM initialising): check from there
        unchecked.append(f"the first {late} frames (the poses start after them)")
        frames = frames[late:]
    if len(posed) < pc.min_posed_fraction * len(frames):
        return Verdict(problem=_stamp_problem(frames, posed, pose_stamps, tol_ms, topic))
    above = np.array([f.ground_above_m for f in posed])
    finite = np.isfinite(above)
    down = np.array([_angle_deg_vec(f.T_world_camera[:3, 2], np.array([0.0, 0.0, -1.0]))
                     for f in posed if f.T_world_camera is not None])
    above, down = above[finite], down[finite]
    # Overhead ground with the optical axis above the horizon: a level forward camera seeing buildings is not it.
    if above.size and np.median(above) > 0 and np.median(down) > 90:
        down_deg = float(np.median(down))
        return Verdict(problem=f"the poses on {topic} put what the camera sees {float(np.median(above)):.2f} m above "
                               f"it (median over {above.size} frames; the optical axis is {down_deg:.0f} deg from "
                               "straight down in the pose's world): an upside-down pose, or a pose of another "
                               "frame than the camera's optical frame (REP 103: world z up; camera z forward)")
    if not above.size:
        unchecked.append("the ground (no valid depth)")
    cloud = np.concatenate([f.cloud_ratios for f in posed])
    if cloud.size >= pc.min_matches:
        r = float(np.exp(np.median(np.log(cloud))))
        if not 1 / pc.max_scale_ratio <= r <= pc.max_scale_ratio:
            return Verdict(problem=f"the recorded map points put what the camera sees {_times(r)} as far as the depth "
                                   f"measures (median of {cloud.size} points in view of the first {len(frames)} "
                                   f"frames, through the poses on {topic}): map points or poses in another unit "
                                   "than metres, or of another frame", scale_ratio=r)
    ratios, rot_err, dir_err, tested = [], [], [], []
    for i, j in _pairs(len(frames)):
        a, b = frames[i], frames[j]
        if a.T_world_camera is None or b.T_world_camera is None or not np.isfinite(a.median_depth_m):
            continue
        motion = depth_motion(a, b, slam.odometry.ratio_test, slam.odometry.pnp_reprojection_px,
                              pc.min_matches)
        if motion is None:
            continue
        T_rec = invert_pose(b.T_world_camera) @ a.T_world_camera  # T_b_a by the poses
        rot_err.append(_angle_deg(T_rec[:3, :3].T @ motion.T_b_a[:3, :3]))
        T_depth = np.eye(4)  # the depth's translation under the recorded rotation (checked on its own above)
        T_depth[:3, :3] = T_rec[:3, :3]
        T_depth[:3, 3] = translation_given(motion, T_rec[:3, :3])
        t_rec = float(np.linalg.norm(T_rec[:3, 3]))
        t_dep = float(np.linalg.norm(T_depth[:3, 3]))
        baseline = pc.min_baseline_fraction * a.median_depth_m
        tested.append((a.index, b.index, t_rec, t_dep))
        if max(t_rec, t_dep) < baseline:
            continue  # too little motion to say anything about the scale
        floor = baseline / 4  # a translation below this is "none" (PnP noise)
        ratios.append(max(t_rec, floor) / max(t_dep, floor))
        if min(t_rec, t_dep) >= baseline:
            # directions of the camera's motion in a's frame: -R^T t of T_b_a
            c_rec = -T_rec[:3, :3].T @ T_rec[:3, 3]
            c_dep = -T_depth[:3, :3].T @ T_depth[:3, 3]
            dir_err.append(_angle_deg_vec(c_rec, c_dep))
    if not tested:
        what = "motion" if cloud.size >= pc.min_matches else "scale and motion"
        return Verdict(unchecked=(*unchecked, f"{what} (no two of the first {len(frames)} frames share "
                                              f"{pc.min_matches} features with depth)"))
    rot = float(np.median(rot_err))
    if rot > pc.max_rotation_deg:
        return Verdict(problem=f"the poses on {topic} rotate the camera {rot:.0f} deg away from what the images show "
                               f"between frames (median of {len(rot_err)} pairs; allowed "
                               f"slam.pose_check.max_rotation_deg {pc.max_rotation_deg:g}): poses of another frame "
                               "than the camera's optical frame, or of another camera", pairs=len(rot_err))
    if not ratios:
        if cloud.size >= pc.min_matches:  # the map points' depth gave the scale
            return Verdict(unchecked=tuple(unchecked), pairs=len(tested), rotation_deg=rot)
        moved = max(max(t[2], t[3]) for t in tested)
        return Verdict(unchecked=(*unchecked, f"scale (the camera moved at most {moved:.3g} m over the first "
                                              f"{len(frames)} frames, below slam.pose_check.min_baseline_fraction "
                                              "of the depth)"), pairs=len(tested))
    ratio = float(np.exp(np.median(np.log(ratios))))
    if not 1 / pc.max_scale_ratio <= ratio <= pc.max_scale_ratio:
        a_i, b_i, t_rec, t_dep = max(tested, key=lambda t: max(t[2], t[3]))
        seen_as = f"frames {a_i} to {b_i}: {t_rec:.3g} m by the poses, {t_dep:.3g} m by the depth; median of " \
                  f"{len(ratios)} pairs"
        floor = pc.min_baseline_fraction * float(np.nanmedian([f.median_depth_m for f in posed])) / 4
        if min(t_rec, t_dep) < floor:  # one of them does not move at all: not a unit
            still, moving = ("poses", "images") if t_rec < t_dep else ("images", "poses")
            why = f"the {still} show no motion while the {moving} show the camera moving ({seen_as})"
        else:
            factor = _times(max(ratio, 1 / ratio))
            why = (f"their scale disagrees with the depth by {factor} (the poses move the camera "
                   f"{'farther' if ratio > 1 else 'less far'} than the depth shows; {seen_as}): poses in another "
                   "unit than metres?")
        return Verdict(problem=f"the poses on {topic}: {why}", scale_ratio=ratio, pairs=len(ratios))
    if dir_err and float(np.median(dir_err)) > pc.max_direction_deg:
        return Verdict(problem=f"the poses on {topic} move the camera {float(np.median(dir_err)):.0f} deg away from "
                               f"the direction the images show (median of {len(dir_err)} pairs; allowed "
                               f"slam.pose_check.max_direction_deg {pc.max_direction_deg:g}): poses of another frame "
                               "than the camera's optical frame", scale_ratio=ratio, pairs=len(ratios))
    return Verdict(unchecked=tuple(unchecked), scale_ratio=ratio, pairs=len(ratios), rotation_deg=rot,
                   direction_deg=float(np.median(dir_err)) if dir_err else None)


def _times(r: float) -> str:
    """A factor for a message: 3.28x, 92.4x, 1000x (never 1e+03x)."""
    return f"{r:.0f}x" if r >= 100 else f"{r:.3g}x"


def _angle_deg_vec(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _late_start(frames: Sequence[Seen], posed: Sequence[Seen], pose_stamps: Sequence[int], tol_ms: float) -> int:
    """How many leading frames come before an on-time pose stream starts (0: none, or the poses are off).

    Every frame from the first pose on has a pose, every frame before it none, and the stamps line up
    (``stamp_offset_ns`` within the tolerance)."""
    if not posed or not pose_stamps or frames[0].T_world_camera is not None:
        return 0
    first = next(i for i, f in enumerate(frames) if f.T_world_camera is not None)
    if any(f.T_world_camera is None for f in frames[first:]):
        return 0
    tol_ns = max(1, round(tol_ms * 1e6))
    f = np.array([s.stamp_ns for s in frames], np.int64)
    off = stamp_offset_ns(f, np.sort(np.asarray(pose_stamps, np.int64)), tol_ns)
    return first if abs(off) <= tol_ns and min(pose_stamps) > frames[first - 1].stamp_ns else 0


def _stamp_problem(frames: Sequence[Seen], posed: Sequence[Seen], pose_stamps: Sequence[int], tol_ms: float,
                   topic: str) -> str:
    head = (f"only {len(posed)} of the first {len(frames)} frames have a pose on {topic} within "
            f"sources.pose_tolerance_ms {tol_ms:g} ms")
    if not pose_stamps:
        return f"{head}, and no pose on it could be read"
    stamps = np.sort(np.asarray(pose_stamps, np.int64))
    f = np.array([s.stamp_ns for s in frames], np.int64)
    distinct = np.unique(stamps)
    if len(distinct) < len(stamps) / 2:  # a stuck clock: many poses, few stamps
        return (f"{head}: {len(stamps)} recorded poses carry only {len(distinct)} distinct stamp(s) (a stuck or "
                "unset clock in the pose publisher); fix its header stamps")
    tol_ns = max(1, round(tol_ms * 1e6))
    off = stamp_offset_ns(f, stamps, tol_ns) / NS_PER_S
    inside = stamps[(stamps >= f.min() - tol_ns) & (stamps <= f.max() + tol_ns)]
    if abs(off) * NS_PER_S <= tol_ns and len(inside) > 1:  # on time, but too few of them
        gap = float(np.median(np.diff(inside))) / NS_PER_S
        return (f"{head}: the poses are {gap:.3g} s apart, more than twice the tolerance; raise "
                "sources.pose_tolerance_ms to interpolate between them, or record the poses at the frame rate")
    where = "after" if off > 0 else "before"
    unit = ""
    pose_mag, frame_mag = float(np.median(np.abs(stamps))), float(np.median(np.abs(f)))
    if pose_mag > 0 and frame_mag > 0 and not 1e-3 < pose_mag / frame_mag < 1e3:
        unit = f" (pose stamps ~{pose_mag:.3g}, frame stamps ~{frame_mag:.3g} ns: stamps in another unit?)"
    return (f"{head}: the recorded poses are {abs(off):.6g} s {where} the frames (the offset at which most "
            f"frames would find a pose){unit}; fix the "
            "recording's clocks, or raise sources.pose_tolerance_ms if that offset is how the poses are stamped")


def seen_frames(frames: Iterable[Frame], slam: SlamCfg) -> list[Seen]:
    """The first ``slam.pose_check.frames`` frames as the check keeps them (one frame's images at a time)."""
    o, od = slam.orb, slam.odometry
    orb = make_orb(o.n_features, o.n_levels, o.scale_factor, o.fast_threshold)
    out = []
    for frame in frames:
        out.append(seen(frame, orb, od.min_depth_m, od.max_depth_m))
        if len(out) >= slam.pose_check.frames:
            break
    return out


class PosedRecording(Protocol):
    """What the check reads of an opened recording (``sources.Recording``)."""

    quiet_frames: bool

    def frames(self) -> Iterator[Frame]: ...

    def pose_stamps(self, limit: int) -> list[int]: ...


def vet_recorded_poses(path: Path, rec: PosedRecording, info: RecordingInfo, slam: SlamCfg,
                       tol_ms: float) -> tuple[SlamCfg, RecordingInfo]:
    """The ``slam`` section and ``info`` for a run whose recorded poses have been checked (``tol_ms``:
    ``sources.pose_tolerance_ms``).

    Nothing changes when the poses are not to be used (no pose stream, or another backend chosen) or
    pass. Rejected poses: DatasetError under ``slam.backend: recorded``; under ``auto`` the backend
    becomes the one a recording without poses gets, and ``info.warnings`` says why (run.json).
    What could not be checked is a warning too.
    """
    topic = next((c.topic for c in info.choices if c.role == "pose" and c.topic), None)
    if topic is None or choose_backend(slam, True) != "recorded" or not slam.pose_check.frames:
        return slam, info
    rec.quiet_frames = True  # the run's own pass gives the per-frame warnings
    frames = rec.frames()
    try:
        kept = seen_frames(frames, slam)
    finally:
        if isinstance(frames, Generator):  # ends the reader's pass (closes what it opened)
            frames.close()
        rec.quiet_frames = False
    verdict = check(kept, rec.pose_stamps(slam.pose_check.max_pose_stamps), slam, tol_ms, topic)
    notes: list[str] = [f"recorded poses not checked for {what}" for what in verdict.unchecked]
    if verdict.problem:
        if slam.backend == "recorded":
            raise DatasetError(path, f"recorded poses rejected: {verdict.problem} (slam.backend: recorded; set "
                                     "it to auto to track the frames instead)")
        fallback = choose_backend(dataclasses.replace(slam, points_topic=""), False)
        notes.insert(0, f"recorded poses rejected: {verdict.problem}; tracking with {_NAMES.get(fallback, fallback)} "
                        f"instead (slam.backend {fallback})")
        slam = dataclasses.replace(slam, backend=fallback, points_topic="")  # type: ignore[arg-type]
    for note in notes:
        log.warning("%s: %s", path, note)
    if notes:
        info = dataclasses.replace(info, warnings=(*info.warnings, *notes))
    return slam, info


_NAMES = {"orbslam3": "ORB-SLAM3", "odometry": "the built-in odometry"}
