"""Frames -> poses and keyframe map points (METHOD 2.2). ``get_backend(config.slam)`` picks one.

``auto``: recorded poses when the frames carry them (or a points topic is configured), else
ORB-SLAM3 when the optional pyorbslam3 wheel is installed, else the built-in odometry.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from slzcli.errors import ConfigError
from slzcli.slam.base import Keyframe, MapPoints, SlamBackend, TrackingState, TrackResult
from slzcli.slam.odometry import OdometryBackend
from slzcli.slam.orbslam3 import OrbSlam3Backend, available
from slzcli.slam.recorded import RecordedBackend

if TYPE_CHECKING:
    from slzcli.config import SlamCfg
    from slzcli.sources.recording import RecordingInfo


class BackendFactory(Protocol):
    """Makes a backend; each takes what it needs of the keywords (``get_backend``) and ignores the rest."""

    def __call__(self, slam: SlamCfg, *, clouds: bool, vocabulary: str | Path | None) -> SlamBackend: ...


def _recorded(slam: SlamCfg, *, clouds: bool, vocabulary: str | Path | None) -> SlamBackend:
    return RecordedBackend(slam, clouds)


def _orbslam3(slam: SlamCfg, *, clouds: bool, vocabulary: str | Path | None) -> SlamBackend:
    return OrbSlam3Backend(slam, vocabulary)


def _odometry(slam: SlamCfg, *, clouds: bool, vocabulary: str | Path | None) -> SlamBackend:
    return OdometryBackend(slam)


BACKENDS: dict[str, BackendFactory] = {
    "recorded": _recorded,
    "orbslam3": _orbslam3,
    "odometry": _odometry,
}


def choose_backend(slam: SlamCfg, has_recorded_poses: bool) -> str:
    """The backend name ``slam.backend`` resolves to (``auto`` decided by what is available)."""
    name = slam.backend
    if name != "auto":
        return name
    if has_recorded_poses or slam.points_topic:
        return "recorded"
    return "orbslam3" if available() else "odometry"


def uses_recorded_poses(slam: SlamCfg) -> bool:
    """Whether a run with this ``slam`` section on a recording with poses takes them as given (not rejected, not
    overridden by another backend): only then are they a source of anything else, e.g. gravity."""
    return choose_backend(slam, True) == "recorded"


def with_frame_period(slam: SlamCfg, info: RecordingInfo) -> SlamCfg:
    """``slam`` with ``slam.orbslam3.nominal_period_s: auto`` resolved to the recording's colour frame period
    (ORB-SLAM3 keeps at most Camera.fps frames between keyframes, so the cadence follows the camera's rate).
    A number set by the user stays; so does ``auto`` where the rate is unknown (one frame: the backend then
    writes ORB-SLAM3's own default, orbslam3.UNKNOWN_RATE_FPS)."""
    orb = slam.orbslam3
    period = info.frame_period_s
    if orb.nominal_period_s != "auto" or period is None:
        return slam
    return dataclasses.replace(slam, orbslam3=dataclasses.replace(orb, nominal_period_s=period))


def get_backend(slam: SlamCfg, has_recorded_poses: bool = False, *, clouds: bool = False,
                vocabulary: str | Path | None = None) -> SlamBackend:
    """A backend instance (a context manager).

    ``clouds``: the frames carry recorded map clouds (recorded); ``vocabulary``: overrides ``slam.vocabulary``
    (orbslam3).
    """
    name = choose_backend(slam, has_recorded_poses)
    if name not in BACKENDS:
        raise ConfigError("slam.backend", f"unknown backend {name!r}")
    return BACKENDS[name](slam, clouds=clouds, vocabulary=vocabulary)


__all__ = ["BACKENDS", "Keyframe", "MapPoints", "SlamBackend", "TrackResult", "TrackingState",
           "choose_backend", "get_backend", "uses_recorded_poses", "with_frame_period"]
