"""px4slp: PX4-Avoidance's grid planner (``scoring/px4slp.py``, docs/PX4SLP.md) as a detection method.

It reads no terrain map but the edge distance (reported, not tested): the ``maps`` time is 0, the grid
update from the frame's depth points and pose is the ``score`` stage. It low-passes its grid over the
frames, as upstream does: that state is its ``memory``, one per run, reset at a new map segment. Without
a pose the grid is not updated (upstream needs the vehicle's position) and nothing is land-able. slz's
noise limits do not gate it (upstream has none); its own reason says why a frame gave no site.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from slzcli.config import Config
from slzcli.landing.px4slp import grid_site
from slzcli.scoring.px4slp import NAME, Px4SlpMemory, Px4SlpPlanner
from slzcli.types import Detection, ScoreMap, TerrainMaps, TrackedFrame


@dataclass(frozen=True, eq=False)
class GridMethod:
    """The planner, its memory across the frames of one run, and the UAV footprint its site is drawn with."""

    planner: Px4SlpPlanner
    footprint_m: tuple[float, float]
    memory: Px4SlpMemory = field(default_factory=Px4SlpMemory)
    name: str = NAME
    reads_maps: bool = False
    selects: str = "the planner's land-able disk nearest the vehicle on its search rays (PX4SLP.md)"

    def observe(self, tracked: TrackedFrame) -> None:
        """The grid is updated on the frames due only, as upstream updates it per point cloud."""

    def detect(self, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
        frame, T, points, segment = tracked.frame, tracked.T_world_camera, tracked.points, tracked.segment
        t: dict[str, float] = {"maps": 0.0}
        shape = frame.depth_m.shape
        if T is None:
            empty = ScoreMap(self.name, np.zeros(shape, np.float32), np.zeros(shape, bool))
            return Detection(frame, None, maps, empty, points, None, maps.edge_distance_m,
                             {**t, "score": 0.0, "mask": 0.0, "select": 0.0}, segment)
        planner = self.planner
        t0 = time.perf_counter()
        state, cells = planner.step(self.memory, frame.depth_m, frame.intrinsics, T, segment)
        t["score"] = _lap(t0)
        t0 = time.perf_counter()
        score, mask = planner.pixels(state, cells)
        t["mask"] = _lap(t0)
        t0 = time.perf_counter()
        selection = None
        if points is not None:
            p = planner.params
            selection = grid_site(state.hysteresis, state.mean, state.position, p.cell_size_m, p.smoothing_land_cell,
                                  p.can_land_thr, points.xyz_world, T, frame.K, mask, self.footprint_m,
                                  maps.edge_distance_m)
        t["select"] = _lap(t0)
        return Detection(frame, T, maps, ScoreMap(self.name, score, mask), points, selection, maps.edge_distance_m,
                         t, segment)


def px4slp(config: Config) -> GridMethod:
    return GridMethod(Px4SlpPlanner.from_config(config.scoring.px4slp),
                      (config.uav.footprint_m[0], config.uav.footprint_m[1]))


def _lap(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
