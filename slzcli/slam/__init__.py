"""Frames -> poses and keyframe map points (METHOD 2.2). ``get_backend(config)`` picks one.

``auto``: recorded poses when the frames carry them (or a points topic is configured), else
ORB-SLAM3 when the optional pyorbslam3 wheel is installed, else the built-in odometry.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from slzcli.errors import ConfigError
from slzcli.slam.base import Keyframe, MapPoints, SlamBackend, TrackingState, TrackResult

if TYPE_CHECKING:
    from slzcli.config import Config
    from slzcli.sources.recording import RecordingInfo


def _recorded(config: Config, **kw: Any) -> SlamBackend:
    from slzcli.slam.recorded import RecordedBackend
    return RecordedBackend(config, bool(kw.get("clouds", False)))


def _orbslam3(config: Config, **kw: Any) -> SlamBackend:
    from slzcli.slam.orbslam3 import OrbSlam3Backend
    return OrbSlam3Backend(config, kw.get("vocabulary"))


def _odometry(config: Config, **kw: Any) -> SlamBackend:
    from slzcli.slam.odometry import OdometryBackend
    return OdometryBackend(config)


BACKENDS: dict[str, Callable[..., SlamBackend]] = {
    "recorded": _recorded,
    "orbslam3": _orbslam3,
    "odometry": _odometry,
}


def choose_backend(config: Config, has_recorded_poses: bool) -> str:
    """The backend name ``slam.backend`` resolves to (``auto`` decided by what is available)."""
    name = config.slam.backend
    if name != "auto":
        return name
    if has_recorded_poses or config.slam.points_topic:
        return "recorded"
    from slzcli.slam.orbslam3 import available
    return "orbslam3" if available() else "odometry"


def uses_recorded_poses(config: Config) -> bool:
    """Whether a run of ``config`` on a recording with poses takes them as given (not rejected, not overridden
    by another backend): only then are they a source of anything else, e.g. gravity."""
    return choose_backend(config, True) == "recorded"


def with_frame_period(config: Config, info: RecordingInfo) -> Config:
    """``config`` with ``slam.orbslam3.nominal_period_s: auto`` resolved to the recording's colour frame period
    (ORB-SLAM3 keeps at most Camera.fps frames between keyframes, so the cadence follows the camera's rate).
    A number set by the user stays; so does ``auto`` where the rate is unknown (one frame: the backend then
    writes ORB-SLAM3's own default, orbslam3.UNKNOWN_RATE_FPS)."""
    orb = config.slam.orbslam3
    period = info.frame_period_s
    if orb.nominal_period_s != "auto" or period is None:
        return config
    slam = dataclasses.replace(config.slam, orbslam3=dataclasses.replace(orb, nominal_period_s=period))
    return dataclasses.replace(config, slam=slam)


def get_backend(config: Config, has_recorded_poses: bool = False, **kw: Any) -> SlamBackend:
    """A backend instance (a context manager).

    ``kw``: clouds= (bool: the frames carry recorded map clouds) for recorded, vocabulary= for orbslam3.
    """
    name = choose_backend(config, has_recorded_poses)
    if name not in BACKENDS:
        raise ConfigError("slam.backend", f"unknown backend {name!r}")
    return BACKENDS[name](config, **kw)


__all__ = ["BACKENDS", "Keyframe", "MapPoints", "SlamBackend", "TrackResult", "TrackingState",
           "choose_backend", "get_backend", "uses_recorded_poses", "with_frame_period"]
