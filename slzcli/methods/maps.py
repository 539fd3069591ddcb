"""fuzzy and bayes: a fusion of the four terrain maps into a score, the landing mask, and the site among
the mask-filtered SLAM map points (``landing.select``).

No state: the same frame, pose, maps and map points give the same Detection, whatever came before.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from slzcli.config import Config, LandingCfg, UavCfg
from slzcli.landing.raised import RaisedParams, surroundings
from slzcli.landing.select import SelectParams, select_site
from slzcli.scoring import SCORERS, MaskParams, Scorer, mask_score
from slzcli.types import Detection, TerrainMaps, TrackedFrame


def select_params(lc: LandingCfg, uav: UavCfg, rule: str, min_extent_factor: float) -> SelectParams:
    """The site selection's parameters: ``rule`` and the cluster's least extent (footprints) are the method's."""
    return SelectParams(
        kmeans_k=lc.kmeans_k, normal_radius_m=lc.normal_radius_m, min_cluster_points=lc.min_cluster_points,
        footprint_m=(uav.footprint_m[0], uav.footprint_m[1]), min_extent_factor=min_extent_factor, rule=rule,
        seed=lc.seed, edge_clearance_m=lc.edge_clearance_factor * max(uav.size_m[:2]),
        max_tilt_deg=uav.max_slope_deg, max_normal_pairs=lc.max_normal_pairs,
        raised=RaisedParams.of(lc.raised, (uav.footprint_m[0], uav.footprint_m[1]), uav.margin_m, uav.max_step_m))


@dataclass(frozen=True, eq=False)
class MapMethod:
    """Score the maps, mask, and (with a pose, map points and maps that vouch) select the site."""

    name: str
    mask: MaskParams
    scorer: Scorer
    params: SelectParams
    selects: str
    stride_px: int = 8        # landing.depth_points_stride_px: the depth grid the raised-surface rule reads
    reads_maps: bool = True

    def observe(self, tracked: TrackedFrame) -> None:
        """Nothing kept across frames."""

    def detect(self, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
        frame, T = tracked.frame, tracked.T_world_camera
        t: dict[str, float] = {"maps": maps_ms}
        t0 = time.perf_counter()
        raw = self.scorer(maps)
        t["score"] = _lap(t0)
        t0 = time.perf_counter()
        score = mask_score(self.scorer, raw, frame.depth_m, frame.intrinsics, self.mask, maps.work, maps.up_camera)
        t["mask"] = _lap(t0)
        edge = maps.edge_distance_m
        selection = None
        vouched = maps.work is None or maps.work.vouched
        points = tracked.points
        t0 = time.perf_counter()
        if vouched and T is not None and points is not None:
            selection = select_site(points.xyz_world, T, frame.K, score.mask, score.score, self.params,
                                    edge_distance_m=edge, around_world=surroundings(
                                        frame.depth_m, frame.intrinsics, T, self.stride_px))
        t["select"] = _lap(t0)
        return Detection(frame, T, maps, score, points, selection, edge, t, tracked.segment)


def fuzzy(config: Config) -> MapMethod:
    return MapMethod("fuzzy", MaskParams.of(config), SCORERS["fuzzy"].from_config(config.scoring, config.mask),
                     select_params(config.landing, config.uav, "min_normal_variance",
                                   config.landing.min_extent_factor),
                     "the cluster of the least normal variance among those that meet the footprint",
                     config.landing.depth_points_stride_px)


def bayes(config: Config) -> MapMethod:
    return MapMethod("bayes", MaskParams.of(config), SCORERS["bayes"].from_config(config.scoring, config.mask),
                     select_params(config.landing, config.uav, "largest", config.landing.bayes_min_extent_factor),
                     "the largest cluster that meets the footprint (BASELINE.md)",
                     config.landing.depth_points_stride_px)


def _lap(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
