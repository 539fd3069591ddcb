"""Frozen dataclasses that flow between stages.

Conventions (METHOD.md): metres, seconds, radians, pixels; depth float32 metres with NaN
for no measurement; poses are ``T_world_camera`` (4x4, camera -> world), camera frame is
the OpenCV/ROS optical frame (x right, y down, z forward); world frame z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # a type only: terrain imports types, not the other way round
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
class Frame:
    """One paired RGB-D frame.

    rgb: uint8 HxWx3 in RGB order. depth_m: float32 HxW metres, NaN = no data.
    T_world_camera: 4x4 float64 or None when the recording has no pose for this frame.
    """

    index: int
    stamp_ns: int
    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: Intrinsics
    T_world_camera: np.ndarray | None = None
    source: str = ""

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
