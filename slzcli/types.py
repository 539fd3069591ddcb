"""Frozen dataclasses that flow between stages.

Conventions (METHOD.md): metres, seconds, radians, pixels; depth float32 metres with NaN
for no measurement; poses are ``T_world_camera`` (4x4, camera -> world), camera frame is
the OpenCV/ROS optical frame (x right, y down, z forward); world frame z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # types only: terrain and landing import types, not the other way round
    from slzcli.landing.select import Selection
    from slzcli.terrain.limits import Working


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


@dataclass(frozen=True, eq=False)
class ScoreMap:
    """A fused landing score (float32 HxW in [0, 1]) and the binary landing mask made from it."""

    method: str
    score: np.ndarray
    mask: np.ndarray
    column_cut: float = 0.0  # fraction of the otherwise-safe pixels whose descent column was out of view


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


# ----------------------------------------------------------------------------- detection
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


@dataclass(frozen=True, eq=False)
class FigureFrame:
    """The arrays of one detection frame for the Figure 6 panel."""

    index: int
    rgb: np.ndarray
    per_method: dict[str, dict[str, Any]]


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
    """What one detection run sums up to (``summary.summarise``), as the run folder writes it.

    ``landing``: landing.json; ``run``: run.json (its ``summary`` is what ``slz detect`` returns);
    ``committed``: the committed site entry (``pipeline.commit.commit_site``) or None; ``primary_segment``:
    the run's map segment (trajectory.tum); ``points_segment``: the segment whose map points
    points.ply holds (None: all, a run of one segment).
    """

    landing: dict[str, Any]
    run: dict[str, Any]
    committed: dict[str, Any] | None
    primary_segment: int | None
    points_segment: int | None

    @property
    def summary(self) -> dict[str, Any]:
        return self.run["summary"]


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
