"""Gravity in the camera frame: each source's estimate and the one resolver that chooses among them.

Sources, in the order ``camera.gravity.source: auto`` trusts them
(docs/METHOD.md "Gravity from the recording"):

1. an IMU: the specific force of a resting or steadily moving vehicle is gravity's reaction
   (``up``); it is averaged over blocks, and only blocks whose mean magnitude is near g and
   whose angular rate is small count (the vehicle's own acceleration and turns kept out);
2. recorded poses: a recording's own world frame, z up (REP 103);
3. the scene: the dominant plane (RANSAC) within ``max_prior_deg`` of the mount's up, taken
   as level ground; used only when it contradicts ``camera.mount`` (else the mount is kept:
   the scene cannot tell level ground under a tilted camera from sloping ground);
4. ``camera.mount``: the configured value.

Pure functions over arrays: reading the IMU and the frames is ``sources/imu.py`` and
``slzcli/gravity.py``. "up" is world up expressed in the camera's optical frame, a unit vector.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from slzcli.config import GravityCfg, ImuGravityCfg, Mount, SceneGravityCfg
from slzcli.terrain.geometry import back_project
from slzcli.terrain.maps import gravity_up_in_camera, mount_from_up
from slzcli.types import GravityDoc, Intrinsics

STANDARD_GRAVITY_M_S2 = 9.80665  # CGPM 1901: what an accelerometer at rest reads (magnitude)
SOURCES = ("imu", "poses", "scene", "mount")
DOWN = np.array([0.0, 0.0, -1.0])  # up of a camera looking straight down


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two directions (degrees)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def mount_rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """R_down_camera of a camera mounted ``(pitch, roll)`` away from looking straight down (``camera.mount``).

    A camera's ``R_world_camera = R_world_down @ mount_rotation(p, r)`` sees world up as
    ``gravity_up_in_camera(None, Mount(p, r))`` when the vehicle is level (Ry(r) Rx(p) in the camera frame).
    """
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), -math.sin(p)], [0.0, math.sin(p), math.cos(p)]])
    ry = np.array([[math.cos(r), 0.0, math.sin(r)], [0.0, 1.0, 0.0], [-math.sin(r), 0.0, math.cos(r)]])
    return ry @ rx


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` to direction ``b`` (Rodrigues)."""
    a, b = unit(a), unit(b)
    v = np.cross(a, b)
    s, c = float(np.linalg.norm(v)), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        axis = unit(np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0]))
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k * ((1.0 - c) / s**2)


# ----------------------------------------------------------------------------- IMU
@dataclass(frozen=True, eq=False)
class QuietBlocks:
    """The IMU's quiet blocks: their centre stamps (ns), mean specific force (camera frame, m/s^2), sample counts."""

    stamps_ns: np.ndarray
    force: np.ndarray
    samples: np.ndarray
    blocks: int                 # blocks with samples, quiet or not
    median_norm_m_s2: float     # median |mean specific force| over all blocks (a unit check: ~9.81)

    @property
    def up(self) -> np.ndarray:
        """The recording's gravity: the sample-weighted mean of the quiet blocks, normalised."""
        return unit((self.force * self.samples[:, None]).sum(axis=0))

    def spread_deg(self) -> float:
        """The 90th percentile angle of a quiet block from the mean (how much the attitude or noise varied)."""
        if len(self.force) == 0:
            return float("nan")
        cos = unit_rows(self.force) @ self.up
        return float(np.degrees(np.arccos(np.clip(np.percentile(cos, 10), -1.0, 1.0))))

    def up_at(self, stamp_ns: int, window_s: float) -> np.ndarray:
        """Gravity at a stamp: the mean of the quiet blocks within ``window_s``; the recording's mean without any."""
        near = np.abs(self.stamps_ns - stamp_ns) <= window_s * 1e9
        if not near.any():
            return self.up
        return unit((self.force[near] * self.samples[near, None]).sum(axis=0))


def unit_rows(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, np.float64) / np.linalg.norm(v, axis=1, keepdims=True)


def quiet_blocks(stamps_ns: np.ndarray, accel: np.ndarray, gyro_stamps_ns: np.ndarray | None,
                 gyro: np.ndarray | None, cfg: ImuGravityCfg) -> QuietBlocks:
    """Block means of the specific force (``block_s``) and the blocks where the vehicle was quiet.

    Quiet: the block's mean |a| within ``accel_tolerance_m_s2`` of g (no sustained acceleration
    along the force) and its mean angular rate under ``gyro_quiet_rad_s`` (no turn whose
    centripetal or tilting part would bias it); without a gyro, the first test alone.
    """
    stamps = np.asarray(stamps_ns, np.int64)
    acc = np.asarray(accel, np.float64).reshape(-1, 3)
    ok = np.all(np.isfinite(acc), axis=1)
    stamps, acc = stamps[ok], acc[ok]
    empty = QuietBlocks(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), 0, float("nan"))
    if len(stamps) == 0:
        return empty
    block_ns = int(cfg.block_s * 1e9)
    t0 = int(stamps.min())
    idx = (stamps - t0) // block_ns
    n = int(idx.max()) + 1
    count = np.bincount(idx, minlength=n).astype(np.float64)
    sums = np.stack([np.bincount(idx, acc[:, k], minlength=n) for k in range(3)], axis=1)
    has = count > 0
    mean = np.zeros_like(sums)
    mean[has] = sums[has] / count[has, None]
    norm = np.linalg.norm(mean, axis=1)
    quiet = has & (np.abs(norm - STANDARD_GRAVITY_M_S2) <= cfg.accel_tolerance_m_s2)
    if gyro is not None and gyro_stamps_ns is not None and len(gyro_stamps_ns):
        g = np.asarray(gyro, np.float64).reshape(-1, 3)
        gs = np.asarray(gyro_stamps_ns, np.int64)
        keep = np.all(np.isfinite(g), axis=1) & (gs >= t0)
        gidx = (gs[keep] - t0) // block_ns
        inside = gidx < n
        rate = np.linalg.norm(g[keep][inside], axis=1)
        gcount = np.bincount(gidx[inside], minlength=n)
        gmean = np.bincount(gidx[inside], rate, minlength=n) / np.maximum(gcount, 1)
        quiet &= (gcount == 0) | (gmean <= cfg.gyro_quiet_rad_s)
    centres = t0 + (np.arange(n) * block_ns + block_ns // 2)
    return QuietBlocks(centres[quiet], mean[quiet], count[quiet], int(has.sum()), float(np.median(norm[has])))


# ----------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class Plane:
    """A frame's dominant plane: its normal towards the camera (= up if it is level ground), inlier share."""

    up: np.ndarray
    share: float
    height_m: float  # the camera's distance from it


def dominant_plane(depth_m: np.ndarray, intrinsics: Intrinsics, prior_up: np.ndarray, max_prior_deg: float,
                   cfg: SceneGravityCfg, seed: int) -> Plane | None:
    """RANSAC over a grid of the frame's depth points: the plane with the most inliers among those whose
    normal (towards the camera) is within ``max_prior_deg`` of ``prior_up``, refined by least squares
    on its inliers; None when no such plane holds ``min_inlier_share`` of the points."""
    pts = _grid_points(depth_m, intrinsics, cfg.sample_px)
    if len(pts) < 3:
        return None
    rng = np.random.default_rng(seed)
    tol = cfg.inlier_fraction * float(np.median(pts[:, 2]))
    idx = rng.integers(0, len(pts), (cfg.hypotheses, 3))
    a, b, c = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    ok = length > 1e-9
    normal, a = normal[ok] / length[ok, None], a[ok]
    offset = -(normal * a).sum(axis=1)
    flip = np.where(offset < 0, -1.0, 1.0)  # n.p + d = 0 with d > 0: n points to the camera's side
    normal, offset = normal * flip[:, None], offset * flip
    prior = unit(prior_up)
    allowed = normal @ prior >= math.cos(math.radians(max_prior_deg))
    if not allowed.any():
        return None
    normal, offset = normal[allowed], offset[allowed]
    counts = (np.abs(pts @ normal.T + offset) < tol).sum(axis=0)
    best = int(np.argmax(counts))
    inliers = np.abs(pts @ normal[best] + offset[best]) < tol
    if inliers.sum() < max(3, cfg.min_inlier_share * len(pts)):
        return None
    on = pts[inliers]
    centre = on.mean(axis=0)
    n = np.linalg.svd(on - centre, full_matrices=False)[2][2]
    n = n if n @ centre < 0 else -n
    if angle_deg(n, prior) > max_prior_deg:
        n = normal[best]
    return Plane(n, float(inliers.mean()), float(abs(n @ centre)))


def level_share(depth_m: np.ndarray, intrinsics: Intrinsics, up: np.ndarray, cfg: SceneGravityCfg,
                spread_deg: float) -> float:
    """The largest share of the frame's grid points on one plane within ``spread_deg`` of level under ``up``.

    Heights along nine normals (``up`` and eight tilted by ``spread_deg`` around it) are binned at twice
    the inlier tolerance; the fullest bin is the plane. Tilted ground seen as level puts only a band of it in
    one bin; a level patch under a hillside puts all of it there.
    """
    pts = _grid_points(depth_m, intrinsics, cfg.sample_px)
    if len(pts) < 3:
        return 0.0
    u = unit(up)
    e1 = unit(np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0]))
    e2 = np.cross(u, e1)
    turns = np.linspace(0.0, 2 * math.pi, 8, endpoint=False)
    tilt = math.tan(math.radians(spread_deg))
    normals = unit_rows(np.vstack([u, u + tilt * (np.cos(turns)[:, None] * e1 + np.sin(turns)[:, None] * e2)]))
    heights = pts @ normals.T
    width = 2.0 * cfg.inlier_fraction * float(np.median(pts[:, 2]))
    best = 0
    for h in heights.T:
        bins = np.floor((h - h.min()) / width).astype(np.int64)
        best = max(best, int(np.bincount(bins).max()))
    return best / len(pts)


def _grid_points(depth_m: np.ndarray, intrinsics: Intrinsics, step: int) -> np.ndarray:
    """The finite back-projected points of every ``step``-th pixel (float64, (N, 3))."""
    sub = np.asarray(depth_m, np.float32)[::step, ::step]
    pts = back_project(sub, intrinsics.scaled(sub.shape[1], sub.shape[0]) if step > 1 else intrinsics)
    pts = pts.reshape(-1, 3)
    return pts[np.all(np.isfinite(pts), axis=1)].astype(np.float64)


def agreeing(ups: Sequence[np.ndarray], cluster_deg: float) -> tuple[np.ndarray, list[int]]:
    """The direction most of ``ups`` agree on (the largest group within ``cluster_deg`` of one of them; ties:
    the earliest), as their mean, and the indices in that group."""
    u = unit_rows(np.stack(ups))
    near = np.degrees(np.arccos(np.clip(u @ u.T, -1.0, 1.0))) <= cluster_deg
    best = int(np.argmax(near.sum(axis=1)))
    members = [int(i) for i in np.flatnonzero(near[best])]
    return unit(u[members].sum(axis=0)), members


# ----------------------------------------------------------------------------- resolver
@dataclass(frozen=True)
class Estimate:
    """One source's gravity (up in the camera frame) and what it rests on."""

    source: str
    up: tuple[float, float, float]
    detail: str
    spread_deg: float = 0.0  # how far its parts (IMU blocks, frames) strayed from it; 0 for the mount

    @property
    def vector(self) -> np.ndarray:
        return np.asarray(self.up, np.float64)


@dataclass(frozen=True)
class Gravity:
    """What the resolver chose: the gravity used, its source, the camera's tilt and the disagreements."""

    used: Estimate
    estimates: tuple[Estimate, ...]
    disagreements: tuple[tuple[str, str, float], ...]  # (source, source, angle deg) beyond the threshold
    warnings: tuple[str, ...] = ()
    per_frame: str = ""      # how each frame's own gravity is found ("" : the recording's, or its pose)
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def source(self) -> str:
        return self.used.source

    @property
    def up(self) -> np.ndarray:
        return self.used.vector

    @property
    def tilt_deg(self) -> float:
        """The camera's tilt away from looking straight down."""
        return angle_deg(self.up, DOWN)

    def mount(self) -> Mount:
        """The ``camera.mount`` equivalent of the gravity used."""
        pitch, roll = mount_from_up(self.up)
        return Mount(round(pitch, 3), round(roll, 3))

    def as_dict(self) -> GravityDoc:
        """JSON form (``slz info --json``, run.json)."""
        m = self.mount()
        return {"source": self.source, "detail": self.used.detail, "up_camera": [round(v, 6) for v in self.used.up],
                "tilt_deg": round(self.tilt_deg, 2), "pitch_deg": round(m.pitch_deg, 2),
                "roll_deg": round(m.roll_deg, 2), "per_frame": self.per_frame,
                "estimates": {e.source: {"up_camera": [round(v, 6) for v in e.up], "detail": e.detail,
                                         "spread_deg": round(e.spread_deg, 2),
                                         "angle_to_used_deg": round(angle_deg(e.vector, self.up), 2)}
                              for e in self.estimates},
                "disagreements": [{"sources": [a, b], "angle_deg": round(d, 2)} for a, b, d in self.disagreements],
                "warnings": list(self.warnings), "notes": list(self.notes)}

    def line(self) -> str:
        """One line for ``slz info`` and the run's summary."""
        m = self.mount()
        return (f"{self.source} ({self.used.detail}): camera tilted {self.tilt_deg:.1f} deg from straight down "
                f"(pitch {m.pitch_deg:.1f}, roll {m.roll_deg:.1f})")


def mount_estimate(mount: Mount) -> Estimate:
    up = gravity_up_in_camera(None, mount)
    return Estimate("mount", _tuple(up), f"camera.mount pitch {mount.pitch_deg:g} deg, roll {mount.roll_deg:g} deg")


def resolve(found: dict[str, Estimate], mount: Mount, cfg: GravityCfg, unavailable: dict[str, str],
            mount_level_share: float = 0.0) -> Gravity:
    """The gravity the maps run on (see the module docstring for the order) and every disagreement.

    ``found``: the estimates the recording gave (imu, poses, scene); ``unavailable``: why each
    other source gave none; ``mount_level_share``: the share of the scene's points on a plane level
    under ``camera.mount`` (``level_share``, the median frame's): a large one keeps the mount against
    the scene (the dominant plane may be a slope beside level ground). A named ``cfg.source`` is used
    alone; ValueError (the caller names the recording) when the recording lacks it, or when it is not the
    IMU and the IMU contradicts it.
    """
    limit = cfg.max_disagreement_deg
    all_est = {**found, "mount": mount_estimate(mount)}
    warnings: list[str] = []
    notes: list[str] = []
    if cfg.source != "auto":
        if cfg.source not in all_est:
            raise ValueError(f"camera.gravity.source is {cfg.source} but the recording gives none "
                             f"({unavailable.get(cfg.source, 'not found')}); set camera.gravity.source auto")
        used = all_est[cfg.source]
        imu = found.get("imu")
        if used.source != "imu" and imu is not None and angle_deg(imu.vector, used.vector) > limit:
            raise ValueError(f"camera.gravity.source {cfg.source} ({used.detail}) is "
                             f"{angle_deg(imu.vector, used.vector):.1f} deg from the IMU's gravity ({imu.detail}), "
                             f"more than camera.gravity.max_disagreement_deg {limit:g}: the recording contradicts "
                             "it; fix it or set camera.gravity.source auto (the IMU is then used)")
    elif "imu" in found:
        used = found["imu"]
    elif "poses" in found:
        used = found["poses"]
    elif "scene" in found and angle_deg(found["scene"].vector, all_est["mount"].vector) > limit and \
            mount_level_share < cfg.scene.mount_level_share:
        used = found["scene"]
    else:
        used = all_est["mount"]
        if "scene" in found and angle_deg(found["scene"].vector, all_est["mount"].vector) > limit:
            warnings.append(
                f"gravity: camera.mount is {angle_deg(found['scene'].vector, all_est['mount'].vector):.1f} deg from "
                f"the scene's {found['scene'].detail} and nothing measured gravity; camera.mount is kept, since a "
                f"plane level under it holds {mount_level_share:.0%} of the points (camera.gravity.scene."
                f"mount_level_share {cfg.scene.mount_level_share:g}): the dominant plane is taken for a slope. "
                "Record an IMU (sensor_msgs/Imu) or poses if the camera is tilted")
        elif "scene" in found:
            notes.append(f"camera.mount agrees with the scene's dominant plane within {limit:g} deg")
    ordered = [all_est[s] for s in SOURCES if s in all_est]
    disagreements = tuple((e.source, used.source, angle_deg(e.vector, used.vector)) for e in ordered
                          if e is not used and angle_deg(e.vector, used.vector) > limit)
    for other, _, deg in disagreements:
        e = all_est[other]
        if other == "scene":  # not a measurement of gravity: sloping ground is a fact about the terrain, a note
            notes.append(f"the scene's {e.detail} is {deg:.1f} deg from the gravity used ({used.source}): sloping "
                         "ground, or the dominant plane is not the ground")
            continue
        what = ("camera.mount is wrong for this recording" if other == "mount" else
                f"the {other} source is not what slz takes it for")
        warnings.append(f"gravity: {e.detail} is {deg:.1f} deg from the gravity used ({used.source}: "
                        f"{used.detail}), more than camera.gravity.max_disagreement_deg {limit:g}: {what}")
    if used.source == "scene":
        warnings.append(f"gravity from the scene alone ({used.detail}): the dominant plane is taken as level "
                        "ground; over sloping ground every slope is wrong by the ground's own. Record an IMU "
                        "(sensor_msgs/Imu) or poses, or set camera.mount and camera.gravity.source mount")
    for source, why in unavailable.items():
        notes.append(f"{source}: {why}")
    return Gravity(used, tuple(ordered), disagreements, tuple(warnings), notes=tuple(notes))


def _tuple(v: np.ndarray) -> tuple[float, float, float]:
    u = unit(v)
    return float(u[0]), float(u[1]), float(u[2])


def estimate(source: str, up: np.ndarray, detail: str, spread_deg: float = 0.0) -> Estimate:
    """An Estimate from an up vector (normalised)."""
    return Estimate(source, _tuple(up), detail, float(spread_deg))
