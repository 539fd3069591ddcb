"""Frozen dataclasses that flow between stages.

Conventions (METHOD.md): metres, seconds, radians, pixels; depth float32 metres with NaN
for no measurement; poses are ``T_world_camera`` (4x4, camera -> world), camera frame is
the OpenCV/ROS optical frame (x right, y down, z forward); world frame z up.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np

from slzcli.records import (
    SITE_FROM_FUSED,
    SITE_FROM_POINTS,
    DecideAdvice,
    LandingRecord,
    RunRecord,
    RunSummary,
)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera model. ``distortion`` is recorded for the user; maps assume rectified images."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion_model: str = ""
    distortion: tuple[float, ...] = ()

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera at another resolution (used when colour and depth sizes differ)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height,
                          self.distortion_model, self.distortion)


@dataclass(frozen=True, eq=False)
class MapCloud:
    """A map-point cloud a SLAM system published in the recording (``slam.points_topic``).

    xyz: (N,3) float64 in the recorded world frame, finite points only; ids: (N,) int64
    map-point ids, -1 where the cloud has no id field.
    """

    stamp_ns: int
    xyz: np.ndarray
    ids: np.ndarray


@dataclass(frozen=True, eq=False)
class Frame:
    """One paired RGB-D frame.

    rgb: uint8 HxWx3 in RGB order. depth_m: float32 HxW metres, NaN = no data.
    T_world_camera: 4x4 float64 or None when the recording has no pose for this frame.
    map_points: the recorded map cloud nearest in stamp to this frame (read by the same
    reader in the same pass, so the recording is opened once), None for most frames.
    """

    index: int
    stamp_ns: int
    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: Intrinsics
    T_world_camera: np.ndarray | None = None
    source: str = ""
    map_points: MapCloud | None = None
    up_camera: np.ndarray | None = None  # world up in the camera frame from the recording (slzcli/gravity.py)

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth_m.shape[0], self.depth_m.shape[1]

    def ref(self) -> FrameRef:
        return FrameRef(self.index, self.stamp_ns, self.intrinsics, self.shape)


@dataclass(frozen=True)
class FrameRef:
    """What outlives a frame (a site's origin): identity and camera, not the images.

    A run keeps one per site found; holding the Frame instead kept two images per site and
    made memory grow with the length of the recording.
    """

    index: int
    stamp_ns: int
    intrinsics: Intrinsics
    shape: tuple[int, int]

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K


@dataclass(frozen=True)
class StreamInfo:
    """One topic of a recording as ``slz info`` reports it."""

    topic: str
    msgtype: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


@dataclass(frozen=True)
class StreamChoice:
    """Which topic slz uses for a role (color, depth, camera_info, pose) and why."""

    role: str
    topic: str | None
    reason: str


class GravityEstimateDoc(TypedDict):
    up_camera: list[float]
    detail: str
    spread_deg: float
    angle_to_used_deg: float


class GravityDisagreementDoc(TypedDict):
    sources: list[str]
    angle_deg: float


class GravityDoc(TypedDict):
    """Where world up came from, as JSON (``terrain.gravity.Gravity.as_dict``: ``slz info --json``, run.json)."""

    source: str
    detail: str
    up_camera: list[float]
    tilt_deg: float
    pitch_deg: float
    roll_deg: float
    per_frame: str
    estimates: dict[str, GravityEstimateDoc]
    disagreements: list[GravityDisagreementDoc]
    warnings: list[str]
    notes: list[str]


@dataclass(frozen=True)
class PairingReport:
    """How many frames paired and why the rest did not; never silently dropped."""

    paired: int = 0
    unpaired_color: int = 0
    unpaired_depth: int = 0
    without_pose: int = 0
    undecodable: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)
    outside_window: int = 0  # pairs left out by sources.window (--start/--end/--stride/--max-frames)


# ----------------------------------------------------------------------------- depth noise and the working scale
SCALES_PX = (1, 2, 4, 8, 16)            # block sides of the noise pyramid, px (each level halves the last)


@dataclass(frozen=True)
class DepthNoise:
    """``sigma_z(z, b) = a_b z^2``: the depth noise of b x b block means at range z.

    ``a_per_m[i]`` belongs to ``SCALES_PX[i]`` (1/m). ``source``: "estimated" (from this frame or
    the smoothed recent ones), "config" (``terrain.noise`` set to a number: white noise assumed,
    a_b = a / b) or "prior" (no estimate possible: ``terrain.noise_estimate.prior_a_per_m`` at
    every scale, i.e. no credit for averaging). ``residuals``: pixels the pixel-scale estimate used.
    """

    a_per_m: tuple[float, ...]
    source: str
    residuals: int = 0
    quantum_m: float = 0.0   # the depth's smallest step (16UC1 millimetres: 0.001); 0 for continuous depth

    @property
    def a1_per_m(self) -> float:
        """The pixel-scale coefficient, the one a sensor datasheet quotes."""
        return self.a_per_m[0]

    def a_at(self, block_px: float) -> float:
        """a at any block side: log-log interpolation; beyond the pyramid, no further reduction (remembered per
        noise and side: a frame's limits ask for the same few sides some 20 times, and a noise serves frames)."""
        return _a_at(self, float(block_px))

    def interpolated_a(self, block_px: float) -> float:
        """``a_at`` computed afresh."""
        b = max(1.0, float(block_px))
        logs = np.log(SCALES_PX[: len(self.a_per_m)])
        vals = np.asarray(self.a_per_m, dtype=np.float64)
        if np.any(vals <= 0):   # exact depth (or a level of it): interpolate linearly, zero stays zero
            return float(np.interp(math.log(b), logs, vals))
        return float(np.exp(np.interp(math.log(b), logs, np.log(vals))))

    def sigma_m(self, depth_m: float, block_px: float = 1.0) -> float:
        return self.a_at(block_px) * depth_m * depth_m

    @classmethod
    def white(cls, a_per_m: float, source: str) -> DepthNoise:
        """Uncorrelated noise of pixel-scale coefficient a: a_b = a / b."""
        return cls(tuple(a_per_m / b for b in SCALES_PX), source)

    @classmethod
    def flat(cls, a_per_m: float, source: str) -> DepthNoise:
        """Noise that averaging does not reduce (a_b = a): the cautious assumption without data."""
        return cls(tuple(a_per_m for _ in SCALES_PX), source)

    def as_dict(self) -> dict[str, object]:
        return {"model": "sigma_z = a_b z^2 (b x b pixel blocks)", "source": self.source,
                "a_per_m": {str(b): round(a, 7) for b, a in zip(SCALES_PX, self.a_per_m, strict=False)},
                "residuals": self.residuals, "quantum_m": self.quantum_m}


@functools.lru_cache(maxsize=1024)
def _a_at(noise: DepthNoise, block_px: float) -> float:
    return noise.interpolated_a(block_px)


@dataclass(frozen=True)
class Working:
    """How one frame's maps are computed, and what they can and cannot see (see the module doc)."""

    altitude_m: float          # the frame's median depth: the windows are sized there
    sigma_m: float             # depth noise there, in the noisiest band of the pyramid (pixel scale for white noise)
    block_px: int              # the maps run on block_px x block_px block means
    block_m: float             # a block's side on the ground at altitude_m
    slope_window_blocks: int   # odd; the steepness plane fit's window, in blocks
    metres_per_level: float    # flatness: Canny's depth scaling (``edge_scaling_m``)
    step_min_m: float          # smallest step distinguishable from the noise
    slope_min_deg: float       # smallest slope distinguishable from the noise
    vouch_depth_m: float       # the limits hold up to this depth (inf: everywhere)
    vouched: bool              # both limits within the UAV's tolerance at altitude_m
    max_step_m: float
    max_slope_deg: float
    focal_px: float            # the camera's, for the altitude at which the limits would hold
    noise: DepthNoise          # what the windows were derived from

    @property
    def slope_window_m(self) -> float:
        return self.slope_window_blocks * self.block_m

    def as_dict(self) -> dict[str, object]:
        return {"altitude_m": round(self.altitude_m, 3), "sigma_m": round(self.sigma_m, 4),
                "block_px": self.block_px, "block_m": round(self.block_m, 4),
                "slope_window_m": round(self.slope_window_m, 3), "metres_per_level": round(self.metres_per_level, 5),
                "step_min_m": round(self.step_min_m, 4), "slope_min_deg": round(self.slope_min_deg, 2),
                "vouch_depth_m": None if math.isinf(self.vouch_depth_m) else round(self.vouch_depth_m, 2),
                "vouched": self.vouched}

    def hidden(self) -> str:
        """What the noise hides, in words ("" when nothing the UAV cares about)."""
        parts = []
        if self.step_min_m > self.max_step_m:
            parts.append(f"steps below {self.step_min_m:.2f} m (the UAV tolerates {self.max_step_m:.2f} m)")
        if self.slope_min_deg > self.max_slope_deg:
            parts.append(f"slopes below {self.slope_min_deg:.0f} deg (limit {self.max_slope_deg:.0f} deg)")
        return " and ".join(parts)


@dataclass(frozen=True, eq=False)
class BlockGrid:
    """The four maps on the b x b block grid (b > 1) they were computed on, where the score is made too.

    ``maps``: float32 in [0, 1], 0 where unknown; ``valid``: the blocks with depth. With b > 1 each
    block's maps are the same for its b^2 pixels, so scoring every pixel would redo each block's work
    b^2 times: the full-resolution maps and score are this grid upsampled (bilinear), zero where the
    pixel or its nearest block has no depth.
    """

    maps: dict[str, np.ndarray]
    valid: np.ndarray
    block_px: int


@dataclass(frozen=True, eq=False)
class TerrainMaps:
    """The four terrain maps of METHOD.md 2.3, float32 HxW in [0, 1], 1 = good for landing.

    ``valid`` marks pixels with depth (invalid pixels are 0 in every map); ``slope_deg`` is
    the physical surface slope against gravity (NaN where unknown) and ``edge_distance_m`` the
    metric clearance to the nearest depth edge, kept for reporting and the acceptance test.
    """

    depth_variance: np.ndarray
    flatness: np.ndarray
    inclination: np.ndarray
    steepness: np.ndarray
    valid: np.ndarray
    slope_deg: np.ndarray
    edge_distance_m: np.ndarray | None = None  # metres to the nearest depth edge or hole (acceptance test)
    work: Working | None = None  # block size, windows and detection limits the maps were made with
    up_camera: np.ndarray | None = None  # world up in the camera frame the maps were made with (unit 3-vector)
    grid: BlockGrid | None = None  # the block grid the maps were made on, when b > 1 (scoring and mask run there)

    NAMES = ("depth_variance", "flatness", "inclination", "steepness")

    def as_dict(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.NAMES}


MASK_STEPS = ("depth", "threshold", "footprint", "column", "noise")  # the landing mask's steps (slzcli.funnel)


@dataclass(frozen=True)
class MaskFunnel:
    """The pixels each mask step left in one frame (``left``, one per ``MASK_STEPS``, non-increasing) and
    what the reason needs to say what would change it: the threshold and the best score against it (None:
    some pixel was above it), the
    footprint square's side and the column's height (m), and the frame's median depth (m, None: no depth)."""

    pixels: int
    left: tuple[int, ...]
    threshold: float
    best_score: float | None
    side_m: float
    column_m: float | None   # None: the column rule did not run (mask.clearance: image)
    depth_m: float | None
    view_m: tuple[float, float] | None  # the view's width and height at depth_m (m)

    def removed(self) -> dict[str, int]:
        """Pixels each step (but ``depth``) removed."""
        return {s: self.left[i - 1] - self.left[i] for i, s in enumerate(MASK_STEPS) if i}

    def emptied_by(self) -> str | None:
        """The step that left no pixel while the one before it left some (None: the mask is not empty, or
        no pixel had depth)."""
        return emptied_by(self.left, MASK_STEPS)


def emptied_by(left: Sequence[int], steps: Sequence[str]) -> str | None:
    """Of a funnel's counts (``left``, one per step, non-increasing): the step that left none while the one before
    it left some (None: the last step left some, or the first none)."""
    for i in range(1, len(steps)):
        if left[i] == 0:
            return steps[i] if left[i - 1] > 0 else None
    return None


@dataclass(frozen=True, eq=False)
class ScoreMap:
    """A fused landing score (float32 HxW in [0, 1]) and the binary landing mask made from it."""

    method: str
    score: np.ndarray
    mask: np.ndarray
    column_cut: float = 0.0  # fraction of the otherwise-safe pixels whose descent column was out of view
    funnel: MaskFunnel | None = None  # the pixels each mask step left (slzcli.funnel); None: not counted (px4slp)


# ----------------------------------------------------------------------------- SLAM
@dataclass(frozen=True, eq=False)
class MapPoints:
    """Map points seen in one keyframe: world XYZ (N,3) float64, their pixels (N,2) in that keyframe.

    ``ids`` are stable per backend run (int64, -1 where a backend has no identity for a point);
    ``T_world_camera`` is the keyframe's pose when the points were reported.
    """

    ids: np.ndarray
    xyz_world: np.ndarray
    pixels: np.ndarray
    keyframe_index: int
    stamp_ns: int
    T_world_camera: np.ndarray

    def __len__(self) -> int:
        return int(self.xyz_world.shape[0])

    @staticmethod
    def empty(keyframe_index: int, stamp_ns: int, T_world_camera: np.ndarray) -> MapPoints:
        return MapPoints(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2)), keyframe_index,
                         stamp_ns, T_world_camera)


@dataclass(frozen=True, eq=False)
class TrackedFrame:
    """One frame after SLAM, as every detection method sees it (``methods.base.Method``).

    ``T_world_camera``: the gravity-aligned world pose (None: not tracked); ``segment``: its SLAM map
    segment; ``points``: the latest keyframe's map points of that segment (None: none yet); ``due``:
    detection is due on this frame; ``slam_ms``: its tracking time.
    """

    frame: Frame
    T_world_camera: np.ndarray | None
    segment: int
    points: MapPoints | None
    due: bool
    slam_ms: float


# ----------------------------------------------------------------------------- sites
@dataclass(frozen=True)
class Candidate:
    """One k-means cluster and why it did or did not qualify (a row of sites.csv)."""

    cluster: int
    points: int
    centroid_world: tuple[float, float, float]
    normal_variance: float
    extent_m: tuple[float, float]
    qualifies: bool
    reason: str
    test: str = ""  # the first test it failed: points | normals | extent | centroid | raised ("" = qualifies)
    raised_cells: int | None = None  # plan cells around it with depth the raised-surface rule read (None: not run)
    raised_m: float | None = None    # its surface's height above the ground around it (None: not measured or run)
    raised_margin_m: float | None = None   # the rule's margin on that height (margin_sigma standard errors)


@dataclass(frozen=True)
class Site:
    """A landing site one detection frame chose; ``source``: what chose it (``SITE_FROM_POINTS``,
    ``SITE_FROM_FUSED`` or ``SITE_FROM_PX4SLP``)."""

    pixel: tuple[float, float]
    center_camera: tuple[float, float, float]
    center_world: tuple[float, float, float]
    corners_world: tuple[tuple[float, float, float], ...]
    normal_world: tuple[float, float, float]
    cluster_points: int
    normal_variance: float
    extent_m: tuple[float, float]
    score: float
    tilt_deg: float
    edge_clearance_m: float | None
    accepted: bool
    acceptance_reason: str
    source: str = SITE_FROM_POINTS


@dataclass(frozen=True)
class Selection:
    """The result for one keyframe: the site (or None), why not, and every candidate."""

    site: Site | None
    reason: str
    candidates: tuple[Candidate, ...]
    projected: np.ndarray  # (N, 2) pixels of all map points in the image
    kept: np.ndarray       # (N,) bool: under the mask
    labels: np.ndarray     # (N,) int: cluster of each kept point, -1 for the rest
    in_view: int = 0       # map points in front of the camera and inside the image

    def chosen_cluster(self) -> int | None:
        """The cluster whose centroid is the site (the candidate nearest its centre); None without a site, and
        for a site no cluster chose (``SITE_FROM_FUSED``)."""
        if self.site is None or self.site.source == SITE_FROM_FUSED or not self.candidates:
            return None
        centre = np.asarray(self.site.center_world)
        return min(self.candidates,
                   key=lambda c: float(np.linalg.norm(np.asarray(c.centroid_world) - centre))).cluster


@dataclass(frozen=True)
class FoundSite:
    """A site one detection frame gave, as the run's site log keeps it (``outputs.site_log.SiteLog``).

    ``id``: its place in the log (its points in the spool); ``limits``: what the frame's depth noise let
    the maps see (``Working.as_dict``); ``segment``: the SLAM map segment whose world frame it is in.
    """

    frame: FrameRef
    site: Site
    id: int
    limits: dict[str, object] | None
    segment: int


@dataclass(frozen=True, eq=False)
class RaisedReadings:
    """Every reading the raised-surface rule made of a run's clusters (``outputs.site_log.SiteLog``): plan
    centre (n, 2) in its map segment's world frame, the segment, whether the rule refused it (raised, or not
    told from raised) and its margin (m; margin_sigma standard errors of the height). Many detections read the
    same surface; the commit weighs them together, each by its precision."""

    xy: np.ndarray
    segment: np.ndarray
    refused: np.ndarray
    margin_m: np.ndarray

    @classmethod
    def empty(cls) -> RaisedReadings:
        return cls(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0))


@dataclass(frozen=True)
class Ranked:
    """How a run's found sites rank (``landing.commit``): the committed site's index into the sites given, its
    support, its equals and the spread of its pool."""

    index: int
    support: int              # detections of its segment within radius_m of it, itself included
    equals: tuple[int, ...]   # indices of the equally good sites (the committed one included)
    pool: tuple[int, ...]     # indices of the sites another run may commit: the pool in the committed segment
    spread_m: float           # largest plan distance between two of the pool (0 with one)


@dataclass(frozen=True)
class CommittedSite:
    """The site landing.json holds (``pipeline.commit``): a found site and how many detections confirm it.

    ``support``: detections of its segment within the commit radius, itself included; ``detections``:
    sites of the run; ``segment_detections``: sites of its map segment; ``ranked``: how the run's sites
    ranked (its equally good sites: the sites another run may commit, and their spread).
    """

    found: FoundSite
    support: int
    detections: int
    segment_detections: int
    ranked: Ranked

    @property
    def site(self) -> Site:
        return self.found.site

    @property
    def frame(self) -> FrameRef:
        return self.found.frame

    @property
    def segment(self) -> int:
        return self.found.segment


# ----------------------------------------------------------------------------- detection
@dataclass(frozen=True, eq=False)
class LandingGrid:
    """A landing map of world-fixed cells in one map segment's frame, as of one frame (the fused method's).

    Row j is world y, column i world x: cell (j, i) covers x in ``origin_xy[0] + [i, i + 1) resolution_m``
    (``origin_xy``: the south-west corner of cell (0, 0), metres). Float arrays are NaN where unseen.
    """

    origin_xy: tuple[float, float]
    resolution_m: float
    segment: int                  # SLAM map segment (its frame: map, map_K)
    frame_index: int              # the last frame fused into it
    stamp_ns: int                 # that frame's stamp
    verdict: np.ndarray           # uint8 codes; ``verdict_names[code]`` names them
    verdict_names: tuple[str, ...]
    score: np.ndarray             # float32 fused score in [0, 1]
    height_m: np.ndarray          # float32 fused height (map frame z)
    variance_m2: np.ndarray       # float32 its variance
    looks: np.ndarray             # float32 independent looks

    @property
    def shape(self) -> tuple[int, int]:
        return self.verdict.shape[0], self.verdict.shape[1]


@dataclass(frozen=True, eq=False)
class Detection:
    """Everything computed for one detection frame (nothing written yet): what the sinks consume."""

    frame: Frame
    T_world_camera: np.ndarray | None
    maps: TerrainMaps
    score: ScoreMap
    points: MapPoints | None
    selection: Selection | None
    edge_m: np.ndarray | None  # TerrainMaps.edge_distance_m
    timings_ms: dict[str, float]
    segment: int = 0  # SLAM map segment of the pose and points
    advice: DecideAdvice | None = None  # a method that can tell: what would decide the ground it could not
    landing_grid: Callable[[], LandingGrid] | None = None  # a method's landing map as of this frame (fused: the
    # cells in view), built when a sink writes it
    cells: dict[str, int] | None = None  # a method with a verdict per cell: the cells in view each of its tests
    # left, in order (fused: fusion/funnel.py CELL_STEPS)


# ----------------------------------------------------------------------------- slz land simulate
@dataclass(frozen=True)
class Target:
    """The landing square in the world (ENU, z up): centre and the four Eq. 10 corners."""

    center_world: np.ndarray     # (3,)
    corners_world: np.ndarray    # (4, 3)


@dataclass(frozen=True, eq=False)
class SimResult:
    """Per-run outcomes (arrays of length N) and, when asked, the per-step log of every run."""

    reason: np.ndarray           # (N,) str
    success: np.ndarray          # (N,) bool
    stabilisation_time_s: np.ndarray
    settling_time_s: np.ndarray  # true error last above settling_fraction of its start value (IBVS phase)
    switch_time_s: np.ndarray
    final_feature_error_px: np.ndarray
    final_yaw_error_deg: np.ndarray
    touchdown_error_m: np.ndarray
    touchdown_speed_m_s: np.ndarray
    max_tilt_deg: np.ndarray
    landing_time_s: np.ndarray
    starts_world: np.ndarray     # (N, 4) x, y, z, yaw_deg (ENU)
    sim_time_s: float
    log: dict[str, np.ndarray] | None
    handover_time_s: np.ndarray  # first hand-over to IBVS (0: the square was in view at the start)
    approach_time_s: np.ndarray  # time spent in each phase: approach, IBVS, touch-down descent
    ibvs_time_s: np.ndarray
    descent_time_s: np.ndarray
    recoveries: np.ndarray       # (N,) int: corners lost during IBVS and found again by the approach

    def metrics(self, i: int = 0) -> dict[str, Any]:
        """One run's metrics as plain JSON values (NaN -> None)."""
        def num(a: np.ndarray) -> float | None:
            v = float(a[i])
            return None if math.isnan(v) else round(v, 6)
        return {
            "success": bool(self.success[i]), "reason": str(self.reason[i]),
            "stabilisation_time_s": num(self.stabilisation_time_s), "settling_time_s": num(self.settling_time_s),
            "switch_time_s": num(self.switch_time_s),
            "final_feature_error_px": num(self.final_feature_error_px),
            "final_yaw_error_deg": num(self.final_yaw_error_deg),
            "touchdown_error_m": num(self.touchdown_error_m), "touchdown_speed_m_s": num(self.touchdown_speed_m_s),
            "max_tilt_deg": num(self.max_tilt_deg), "landing_time_s": num(self.landing_time_s),
            "start_world": [round(float(v), 6) for v in self.starts_world[i]],
            "handover_time_s": num(self.handover_time_s), "recoveries": int(self.recoveries[i]),
            "phases_s": {"approach": num(self.approach_time_s), "ibvs": num(self.ibvs_time_s),
                         "descent": num(self.descent_time_s)},
        }


# ----------------------------------------------------------------------------- slz detect
@dataclass(frozen=True, eq=False)
class RunResult:
    """What one detection run sums up to (``summary.summarise``), as the run folder writes it
    (``outputs/run_folder.py``).

    ``landing``: landing.json's record; ``run``: run.json's (its ``summary`` is what ``slz detect`` returns);
    ``committed``: the committed site entry (``pipeline.commit.commit_site``) or None; ``primary_segment``:
    the run's map segment (trajectory.tum); ``points_segment``: the segment whose map points
    points.ply holds (None: all, a run of one segment).
    """

    landing: LandingRecord
    run: RunRecord
    committed: CommittedSite | None
    primary_segment: int | None
    points_segment: int | None

    @property
    def summary(self) -> RunSummary:
        return self.run.summary


# ----------------------------------------------------------------------------- frame ids of a recording
@dataclass(frozen=True, eq=False)
class RecordedFrames:
    """The recording's own frame ids that results.mcap ties slz's frames to (``sources.tf``).

    camera: the colour image's ``header.frame_id`` (its optical frame), "" when the recording has none
    (TUM folders). camera_root, T_root_camera: the top of the camera's chain in ``/tf_static``
    (e.g. ``camera_link``) and the transform to it; "" and None when the camera is in no static
    chain. pose_frame: the frame the recorded camera poses are in (a PoseStamped's or Odometry's
    ``header.frame_id``, the root of the /tf chain), "" without recorded poses. tf_places_camera:
    the recorded poses come from ``/tf``, so the recording's own tree places the camera.
    static_chain: the /tf_static edges (parent, child, T_parent_child) from the camera up to camera_root.
    """

    camera: str = ""
    camera_root: str = ""
    T_root_camera: np.ndarray | None = None
    static_chain: tuple[tuple[str, str, np.ndarray], ...] = ()
    pose_frame: str = ""
    tf_places_camera: bool = False
