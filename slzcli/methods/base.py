"""What the run machinery asks of a detection method (``Method``), and nothing else.

A method is built from the config, once per run (``registry.build``). It sees every tracked frame in
order (``observe``: the frame, its gravity-aligned pose, its SLAM map segment and the latest keyframe's
map points), so it may keep state across frames and map segments; on the frames due for detection it
makes a ``Detection`` (``detect``) from that frame and the frame's terrain maps, which the run computes
once and shares among the methods it runs. It says what it reads (``reads_maps``: whether the terrain
maps' noise limits gate it; a method that reads no map says itself why a frame gave no site, in its
``Selection.reason``) and how its sites are selected (``selects``, one line for the reports).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, cast

from slzcli.errors import ConfigError
from slzcli.methods import registry

if TYPE_CHECKING:
    from collections.abc import Mapping

    from slzcli.config import Config
    from slzcli.types import Detection, TerrainMaps, TrackedFrame


class Method(Protocol):
    """One detection method of one run (see the module docstring)."""

    name: str
    reads_maps: bool  # the terrain maps' noise limits gate it (else it reads depth points and poses only)
    selects: str      # how its site is chosen, one line

    def observe(self, tracked: TrackedFrame) -> Mapping[str, float] | None:
        """Every tracked frame, in order, before ``detect`` on the frames due (a stateless method ignores it);
        returns the time (ms) of its own stages on that frame, added to the run's timings (or None)."""

    def detect(self, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
        """The detection of a frame due: score, mask and (when the inputs vouch) the site; ``maps_ms``: the
        maps' time, reported as the ``maps`` stage."""


def build(name: str, config: Config) -> Method:
    """A fresh method ``name`` (``registry.METHODS``) for one run: its state, if any, starts empty."""
    if name not in registry.METHODS:
        raise ConfigError("method", f"unknown method {name!r}; known: {', '.join(registry.names())}")
    return cast("Method", registry.factory(name)(config))
