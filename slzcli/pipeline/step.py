"""The per-frame method step: a frame due gets its terrain maps once, then every method's detection on
them; each detection is added to its method's run accumulators (``tally``).

Compute first, write after: every frame's stages are timed on their own (maps, score, mask, slam,
select); what the sinks do with a detection (writing it) is timed apart.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from slzcli.config import Config, TerrainCfg, UavCfg
from slzcli.funnel import frame_funnel
from slzcli.methods.base import Method
from slzcli.outputs.site_log import SiteLog
from slzcli.summary import RunState
from slzcli.terrain.limits import would_vouch
from slzcli.terrain.maps import MapParams, frame_maps
from slzcli.terrain.noise import NoiseTracker
from slzcli.types import DepthNoise, Detection, Frame, TerrainMaps, TrackedFrame


def posed_maps(frame: Frame, T_world_camera: np.ndarray | None, params: MapParams,
               noise: DepthNoise | None = None) -> tuple[TerrainMaps, float]:
    """The four terrain maps of a frame (with its SLAM pose, when there is one) and their time in ms.

    ``noise``: the run's depth noise (``NoiseTracker.update``); None measures it on this frame alone.
    Only the tracked pose counts: a frame the tracker gave none keeps no pose of its own (recorded poses that
    were rejected still ride on the frames), so its gravity is its own or the mount's.
    """
    posed = replace(frame, T_world_camera=T_world_camera)
    t0 = time.perf_counter()
    maps = frame_maps(posed, params, noise)
    return maps, (time.perf_counter() - t0) * 1e3


def step(tracked: TrackedFrame, methods: Sequence[Method], config: Config,
         noise: NoiseTracker) -> tuple[TerrainMaps, list[Detection]]:
    """A frame due: its maps (with the run's depth noise), then each method's detection on them, in order."""
    maps, maps_ms = posed_maps(tracked.frame, tracked.T_world_camera, MapParams.of(config),
                               noise.update(tracked.frame.depth_m))
    return maps, [detect_one(m, tracked, maps, maps_ms) for m in methods]


def detect_one(method: Method, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
    """One method's detection of a frame due (the one call every detection goes through)."""
    return method.detect(tracked, maps, maps_ms)


def tally(state: RunState, det: Detection, method: Method, terrain: TerrainCfg, uav: UavCfg) -> None:
    """Add one detection to a run's accumulators: stage times, counts, the no-site evidence (the limits of
    ``terrain`` and ``uav`` a frame that does not vouch failed), sites."""
    score, work = det.score, det.maps.work
    if score.column_cut > 0 or score.mask.any():
        cut = state.column_cut
        state.column_cut = score.column_cut if cut is None else min(cut, score.column_cut)
    if not method.reads_maps and det.selection is not None and det.selection.site is None:
        state.method_reason = det.selection.reason  # a method the maps do not gate says why itself
    if method.reads_maps and work is not None and not work.vouched:
        state.unvouched += 1
        worst = state.worst_unvouched
        if worst is None or work.altitude_m > worst.altitude_m:
            state.worst_unvouched = work
            state.would_vouch = would_vouch(work, terrain, uav)
    if method.reads_maps and work is not None and (state.highest is None or work.altitude_m > state.highest.altitude_m):
        state.highest = work
    state.advice = det.advice  # the latest detection frame's (None: it had nothing to advise)
    for name, ms in det.timings_ms.items():
        state.timer.add(name, ms)
    state.funnel.add(frame_funnel(det))
    state.detections += 1
    state.detections_without_depth += not det.maps.valid.any()
    record(state.sites, det)


def record(sites: SiteLog, det: Detection) -> None:
    """Add a detection's site and candidates to the run's tables."""
    sel = det.selection
    if sel is None:
        return
    chosen = sel.chosen_cluster()   # None for a site no cluster chose (the fused terrain's own)
    sites.add_rows([{
        "frame": det.frame.index, "stamp_ns": det.frame.stamp_ns, "cluster": c.cluster, "points": c.points,
        "x": c.centroid_world[0], "y": c.centroid_world[1], "z": c.centroid_world[2],
        "normal_variance": c.normal_variance, "extent_x_m": c.extent_m[0], "extent_y_m": c.extent_m[1],
        "qualifies": c.qualifies, "reason": c.reason, "chosen": c.cluster == chosen, "segment": det.segment,
        "raised_m": c.raised_m, "raised_cells": c.raised_cells}
        for c in sel.candidates])
    if sel.site is not None and chosen is None:   # no cluster chose it: its own row, cluster -1
        st = sel.site
        sites.add_rows([{
            "frame": det.frame.index, "stamp_ns": det.frame.stamp_ns, "cluster": -1, "points": st.cluster_points,
            "x": st.center_world[0], "y": st.center_world[1], "z": st.center_world[2],
            "normal_variance": st.normal_variance, "extent_x_m": st.extent_m[0], "extent_y_m": st.extent_m[1],
            "qualifies": True, "reason": f"chosen by the {st.source}: too few map points on it to cluster",
            "chosen": True, "segment": det.segment, "raised_m": None, "raised_cells": None}])
    measured = [c for c in sel.candidates if c.raised_m is not None]
    sites.add_raised(np.array([c.centroid_world[:2] for c in measured]).reshape(-1, 2), det.segment,
                     np.array([c.test == "raised" for c in measured], bool),
                     np.array([c.raised_margin_m or 0.0 for c in measured], np.float64))
    if sel.site is not None:
        assert det.points is not None  # a site is chosen among the map points
        pts = det.points.xyz_world
        limits = det.maps.work.as_dict() if det.maps.work is not None else None
        sites.add_site(det.frame.ref(), sel.site, pts[sel.kept], pts[sel.labels == chosen] if chosen is not None
                       else pts[:0], limits, det.segment,
                       kept_cluster=sel.labels[sel.kept])
