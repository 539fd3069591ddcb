"""Is a site on a raised surface? Its surface height against the ground around it (METHOD 2.5.1).

A flat box top or a car roof passes every test of the maps (flat, level, clear of edges by more than the
edge clearance) and yet is no place to land: a UAV that misses it by its landing error drops off an
edge, and the ground truth counts only the ground as landable. The rule, on points with heights along
gravity (``up``):

1. the site's own surface: the plane through the site's centre with its normal; the site's points'
   scatter about it (1.4826 MAD, at its one-sided 95 % upper bound for the number of points: five points
   may under-read it by half) is the points' noise ``sigma``, measured at this range on this sensor;
2. the ground around it: the frame's depth on a pixel grid (``surroundings``; the SLAM map points crowd on
   texture), the points whose plan distance from the centre lies in the annulus from the
   landing square's corner radius (the site's own square left out) to ``ground_radius_m``; per point its depth
   ``d`` below the site's plane, averaged per plan cell of ``ground_cell_m`` (the annulus weighed by area, not by
   how many samples each surface gives), so a site on a uniform slope sees the slope's ground at d ~ 0 and a
   level box top on sloping ground sees the ground's mean depth;
3. the lowest large surface: the ``1 - ground_share`` quantile of ``d`` (the level that at least
   ``ground_share`` of the annulus lies at or below: a lower surface covering that share of it, not a
   ditch or a strip beside the site, which are the edge clearance's and the flatness map's business),
   with the quantile's noise share removed (``z_q sigma``, a point's noise: a cell mean's is smaller, so this
   errs low; level ground's own noise lifts a high quantile);
4. raised: that height exceeds the UAV's step tolerance (``uav.max_step_m``) by ``confidence_sigma``
   standard errors of the quantile (and of the site's mean level). A terrace or a kerb within the
   tolerance is ground.

Fewer than ``min_cells`` plan cells with a point in the annulus (the view or the map holds too little around the site):
not measured, the site is not refused by this rule (``Raised.measured`` False says so).
Where a site is selected at all, the depth noise at the footprint's scale is already within the step
tolerance (the frame vouches, or the fused cells are decided), so the margin covers the points' own
scatter only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.stats import chi2, norm

from slzcli.geometry import back_project, transform_points

if TYPE_CHECKING:
    from slzcli.config import Config, RaisedCfg
    from slzcli.types import Intrinsics

_MAD_TO_SIGMA = 1.4826  # a normal's std over its median absolute deviation
_MAD_EFFICIENCY = 0.37  # the MAD's variance efficiency against the std for normal noise: its effective dof share
_SIGMA_BOUND = 0.05     # the noise is taken at its one-sided 95 % upper bound: a few points under-read it


@dataclass(frozen=True)
class RaisedParams:
    """The rule's parameters (``landing.raised`` and the UAV's tolerances)."""

    max_height_m: float       # uav.max_step_m: the highest surface the UAV may land beside
    inner_radius_m: float     # the landing square's corner radius: the site's own ground is not its surroundings
    radius_m: float           # landing.raised.ground_radius_m
    ground_share: float       # landing.raised.ground_share
    confidence_sigma: float   # landing.raised.margin_sigma
    min_points: int           # landing.raised.min_cells (plan cells of the annulus with a point)
    cell_m: float = 0.25      # landing.raised.ground_cell_m

    @classmethod
    def of(cls, raised: RaisedCfg, footprint_m: tuple[float, float], margin_m: float,
           max_step_m: float) -> RaisedParams:
        """From ``landing.raised`` and the UAV's footprint, margin and step tolerance."""
        inner = 0.5 * math.hypot(footprint_m[0] + 2 * margin_m, footprint_m[1] + 2 * margin_m)
        return cls(max_step_m, inner, raised.ground_radius_m, raised.ground_share, raised.margin_sigma,
                   raised.min_cells, raised.ground_cell_m)


def raised_params(config: Config) -> RaisedParams:
    """The rule's parameters of a run's config."""
    uav = config.uav
    return RaisedParams.of(config.landing.raised, (uav.footprint_m[0], uav.footprint_m[1]), uav.margin_m,
                           uav.max_step_m)


def surroundings(depth_m: np.ndarray, intrinsics: Intrinsics, T_world_camera: np.ndarray, stride_px: int) -> np.ndarray:
    """The frame's depth on a pixel grid, in the world: what surrounds a site. Not the SLAM map points, which
    crowd on texture (ORB-SLAM3 put 722 of 801 points on a concrete box top and 79 on the rocky ground
    around it): the depth samples every surface in view alike."""
    sub = depth_m[::stride_px, ::stride_px]
    xyz = back_project(sub, intrinsics.scaled(sub.shape[1], sub.shape[0]))
    pts = xyz[np.all(np.isfinite(xyz), axis=2)]
    return transform_points(T_world_camera, pts)


@dataclass(frozen=True)
class Raised:
    """What the rule found for one site."""

    height_m: float | None   # the site's surface above the ground around it (None: not measured)
    threshold_m: float       # the height it had to exceed to be refused (tolerance + margin)
    points: int              # plan cells of the annulus with a point
    refused: bool

    @property
    def measured(self) -> bool:
        return self.height_m is not None

    def reason(self) -> str:
        """The words of a refusal (a Candidate's reason)."""
        return (f"on a surface {self.height_m or 0.0:.1f} m above the ground around it (more than the UAV's "
                f"step tolerance, uav.max_step_m, by the noise margin: {self.threshold_m:.2f} m)")


def _cell_means(rel: np.ndarray, d: np.ndarray, up: np.ndarray, cell_m: float) -> np.ndarray:
    """The mean of ``d`` per plan cell of ``cell_m`` (cells with a point): the annulus weighed by area, not by
    point count (a near box top holds more depth samples per square metre than the ground beyond it, and SLAM
    points crowd on texture)."""
    if d.size == 0:
        return d
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    ij = np.floor(np.stack([rel @ e1, rel @ e2], axis=1) / cell_m).astype(np.int64)
    _, inv = np.unique(ij, axis=0, return_inverse=True)
    inv = inv.ravel()
    return np.bincount(inv, weights=d) / np.bincount(inv)


def above_ground(centre: np.ndarray, normal: np.ndarray, site_xyz: np.ndarray, around_xyz: np.ndarray,
                 params: RaisedParams, up: np.ndarray) -> Raised:
    """The rule (module docstring) for a site at ``centre`` with surface ``normal``; ``site_xyz``: the site's
    own points (their scatter is the noise), ``around_xyz``: every point that may be its surroundings."""
    up = up / np.linalg.norm(up)
    n = normal / np.linalg.norm(normal)
    if float(n @ up) < 0:
        n = -n

    def depth_below(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = p - centre
        h = rel @ up
        plan = rel - h[:, None] * up[None, :]
        plane_h = -(plan @ n) / max(float(n @ up), 1e-6)   # the site plane's height above each point's plan position
        return plane_h - h, np.linalg.norm(plan, axis=1)

    d_site, _ = depth_below(site_xyz)
    d_all, r = depth_below(around_xyz)
    ring = (r >= params.inner_radius_m) & (r <= params.radius_m) & np.isfinite(d_all)
    d = _cell_means(around_xyz[ring] - centre, d_all[ring], up, params.cell_m)
    n_ring, n_site = int(d.size), int(np.count_nonzero(np.isfinite(d_site)))
    tol = params.max_height_m
    if n_ring < params.min_points or n_site < 3:
        return Raised(None, tol, n_ring, False)
    d_site = d_site[np.isfinite(d_site)]
    level = float(np.median(d_site))
    dof = max(1.0, _MAD_EFFICIENCY * (n_site - 1))
    bound = math.sqrt(dof / float(chi2.ppf(_SIGMA_BOUND, dof)))
    sigma = _MAD_TO_SIGMA * float(np.median(np.abs(d_site - level))) * bound
    q = 1.0 - params.ground_share
    z_q = float(norm.ppf(q))
    ground = float(np.quantile(d, q)) - z_q * sigma - level
    # standard error of a sample quantile of normal noise, and of the site's median level
    se = sigma * math.sqrt(q * (1 - q) / n_ring) / float(norm.pdf(z_q)) + sigma * math.sqrt(math.pi / 2 / n_site)
    threshold = tol + params.confidence_sigma * se
    return Raised(ground, threshold, n_ring, ground > threshold)
