"""fused: the fuzzy rules on the terrain fused over the flight (``slzcli/fusion``, METHOD 2.3.6).

It keeps state across frames: every tracked frame with a pose goes into the fused grid of its map segment
(``observe``); on a frame due, the verdict of the cells in view is rendered into the frame's pixels as its
mask (SAFE cells only) and its score, and the site is chosen among the SLAM map points on that mask as the
paper's clustering does (``landing.select``: a confirmation by the map points of what the fused map calls
safe); where the map points are too few or too sparse to form a cluster there, the site is the fused map's
own safest square (``_fused_site``), through the same acceptance test. The per-frame maps are not what gates
it (their noise limits are the fused map's business, per cell); when nothing in view is safe its reason says
what would decide the best undecided ground.

The depth noise of a frame that is not due is the last one the run measured on a frame due (the maps'
``work.noise``); before any, the method's own estimate of that frame.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from slzcli.config import Config
from slzcli.fusion.advice import Advice, GroundTrack
from slzcli.fusion.grid import region, seen_bounds
from slzcli.fusion.output import Judged, landing_grid, write_landing_map
from slzcli.fusion.session import FusedTerrain, cells_in_frame, pixel_cells
from slzcli.fusion.verdict import SAFE, FusedMaps, FusedSite, fused_maps, site_surface
from slzcli.landing.raised import above_ground, surroundings
from slzcli.landing.select import WORLD_UP, Selection, SelectParams, accepted_site, select_site, unmeasured_note
from slzcli.methods.maps import select_params
from slzcli.records import SITE_FROM_FUSED
from slzcli.scoring import SCORERS
from slzcli.terrain.noise import DepthNoise, NoiseTracker
from slzcli.types import Detection, LandingGrid, ScoreMap, TerrainMaps, TrackedFrame

NAME = "fused"


# the clusters' tests more map points can pass (landing/select.py ``Candidate.test``); "raised" is a finding
SPARSE = frozenset({"points", "normals", "extent", "centroid"})


@dataclass(eq=False)
class FusedMethod:
    """The run's fused terrain and the site selection on its verdict."""

    config: Config
    terrain: FusedTerrain
    params: SelectParams
    tracker: NoiseTracker
    noise: DepthNoise | None = None
    name: str = NAME
    reads_maps: bool = False
    selects: str = ("the cluster of the least normal variance among the map points on cells the fused map calls "
                    "safe; where they are too few or too sparse to cluster, the fused map's own safest square "
                    "(METHOD 2.3.6)")
    last_fused: tuple[int, int] = (-1, 0)   # (index, stamp_ns) of the last frame fused: the landing map's time
    track: GroundTrack = field(default_factory=GroundTrack)   # the camera's recent positions: hover or flight

    def observe(self, tracked: TrackedFrame) -> dict[str, float]:
        """Fuse the frame; its ``fuse`` stage is the CPU time of this thread (``time.thread_time``: one core's
        work, neither the SLAM worker's threads nor the wait for a loaded machine), noise estimate included."""
        t0 = time.thread_time()
        frame = tracked.frame
        noise = self.noise if self.noise is not None else self.tracker.update(frame.depth_m)
        self.terrain.add(frame.depth_m, frame.intrinsics, tracked.T_world_camera, noise, tracked.segment,
                         frame.index)
        if tracked.T_world_camera is not None:
            self.last_fused = (frame.index, frame.stamp_ns)
            self.track.add(tracked.segment, frame.stamp_ns, tracked.T_world_camera)
        return {"fuse": (time.thread_time() - t0) * 1e3}

    def detect(self, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
        frame, T, points = tracked.frame, tracked.T_world_camera, tracked.points
        if maps.work is not None:
            self.noise = maps.work.noise
        t: dict[str, float] = {"maps": maps_ms}
        shape = frame.depth_m.shape
        t0 = time.perf_counter()
        fm = self.terrain.maps_in_view() if T is not None else None
        t["score"] = _lap(t0)
        t0 = time.perf_counter()
        if fm is None or T is None:
            score = ScoreMap(self.name, np.zeros(shape, np.float32), np.zeros(shape, bool))
        else:
            index = pixel_cells(fm, frame.depth_m, frame.intrinsics, T)   # once for the score and the mask
            score = ScoreMap(self.name, cells_in_frame(fm.score.astype(np.float32), index),
                             cells_in_frame(fm.verdict == SAFE, index))
        t["mask"] = _lap(t0)
        t0 = time.perf_counter()
        selection: Selection | None = None
        advice: Advice | None = None
        if T is not None and points is not None:
            around = surroundings(frame.depth_m, frame.intrinsics, T, self.config.landing.depth_points_stride_px)
            selection = select_site(points.xyz_world, T, frame.K, score.mask, score.score, self.params,
                                    edge_distance_m=maps.edge_distance_m, around_world=around)
            if selection.site is None and fm is not None and not score.mask.any():
                advice = self.terrain.advice(fm, self.track.hovering(self.config.terrain.fusion.hover_speed_m_s))
                why = (fm.raised_lead() + "nothing in view is decided safe by the fused terrain: "
                       + fm.why_none(self.terrain.depth_m))
                selection = replace(selection, reason=f"{why}; {advice.text()}" if advice is not None else why)
            elif (selection.site is None and fm is not None and {c.test for c in selection.candidates} <= SPARSE
                  and (best := self.terrain.site(fm)) is not None):
                # the map points are too few or too sparse to confirm a site: the fused verdict's own (METHOD 2.5)
                selection = self._fused_site(selection, fm, best, T, frame.K, shape, maps.edge_distance_m, around)
        t["select"] = _lap(t0)
        # the cells judged, built when a sink writes them (results.mcap, in its writer), not on the compute path
        grid = None if fm is None or not fm.region.seen.any() else \
            functools.partial(landing_grid, Judged.of(fm), tracked.segment, *self.last_fused, crop=True)
        cells = None if fm is None or fm.funnel is None else fm.funnel.as_dict()
        return Detection(frame, T, maps, score, points, selection, maps.edge_distance_m, t, tracked.segment,
                         None if advice is None else advice.record(), grid, cells)


    def _fused_site(self, sel: Selection, fm: FusedMaps, best: FusedSite, T: np.ndarray, K: np.ndarray,
                    shape: tuple[int, int], edge_distance_m: np.ndarray | None, around: np.ndarray) -> Selection:
        """The fused verdict's best site as the frame's site, where the SLAM map points are too few or too sparse
        to form a cluster on the safe cells (``SPARSE``): the centre of its landing square on the plane of the
        square's fused heights, through the tests a cluster's site passes: the raised-surface rule on this frame's
        depth (the depth points in its square as the site's, those around as the ground: a cluster's reading, with
        its map points replaced by depth; one that cannot tell is left to the fused verdict, which read the patch
        with every frame's evidence), then the acceptance test (edge clearance, tilt). Its square was decided safe
        whole (METHOD 2.3.6); the clusters add nothing there but their count. Out of the frame, or refused: the
        reason says so."""
        centre, normal = site_surface(fm, best, self.terrain.params.square_m)
        where = f"the best at ({best.x_m:.1f}, {best.y_m:.1f}) m"
        head = f"the fused terrain calls {fm.counts()['safe']} cells in view safe ({where}"
        rp = self.params.raised
        if rp is not None:
            # the site's own depth points: those of its square, as the fused patch test takes its cells
            own = np.all(np.abs(around[:, :2] - centre[:2]) <= rp.inner_radius_m, axis=1)
            found = above_ground(centre, normal, around[own], around, rp, WORLD_UP)
            if found.refused and not rp.defers(found):
                return replace(sel, reason=(f"{head}), but on this frame's depth its square is {found.reason()}; "
                                            f"the SLAM map points confirm no site: {sel.reason}"))
        raised = best.raised
        notes = [unmeasured_note(raised.points, rp)] if raised is not None and not raised.measured and rp else []
        site = accepted_site(centre, normal, T, K, shape, self.params, WORLD_UP, edge_distance_m, notes,
                             SITE_FROM_FUSED)
        if site is None:
            return replace(sel, reason=(f"{head}, out of this frame's image), and the SLAM map points confirm no "
                                        f"site in it: {sel.reason}"))
        return replace(sel, site=replace(site, score=best.score), reason="")

    def write_outputs(self, folder: Path) -> LandingGrid | None:
        """The flight-wide landing map of the run's last map segment (``fusion/output.py``), when it has one;
        returned for results.mcap."""
        grid = self.terrain.grid
        if grid is None:
            return None
        bounds = seen_bounds(grid)
        if bounds is None:
            return None
        fm = fused_maps(region(grid, *bounds), self.config, self.terrain.params, self.terrain.scorer)
        return write_landing_map(folder, fm, self.terrain.segment or 0, *self.last_fused,
                                 self.config.output.map_frame)


def fused(config: Config) -> FusedMethod:
    """The method; its site selection keeps the per-frame raised-surface rule's refusals only where a reading can
    tell (``RaisedParams.defer_untold``): the fused verdict already ran that rule on its cells with every frame's
    evidence, and the per-frame rule on a keyframe's SLAM map points (8-61 a cluster from ORB-SLAM3 at 10 m,
    ~0.25 m each, margins 0.12-0.62 m) refused every level cluster the fused map had decided as "not told"
    (benchmarks/fused_detect.py), while at 5 m (margins of centimetres) it kept a D435's 0.12 m box top, which
    the fused mask partly calls safe, from being chosen (benchmarks/raised_low.py)."""
    scorer = SCORERS["fuzzy"].from_config(config.scoring, config.mask)
    params = select_params(config.landing, config.uav, "min_normal_variance", config.landing.min_extent_factor)
    raised = None if params.raised is None else replace(params.raised, defer_untold=True)
    return FusedMethod(config, FusedTerrain(config, scorer), replace(params, raised=raised),
                       NoiseTracker(config.terrain.noise, config.terrain.noise_estimate))


def _lap(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
