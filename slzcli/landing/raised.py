"""Is a site on a raised surface? Its surface height against the ground around it (METHOD 2.5.1).

A flat box top or a car roof passes every test of the maps (flat, level, clear of edges by more than the
edge clearance) and yet is no place to land: a UAV that misses it by its landing error drops off an
edge, and the ground truth counts only the ground as landable. The rule, with heights along gravity (``up``):

1. the site's own surface: its points' scatter about the plane through its centre with its normal (per frame
   the plane fitted to its points, ``fitted_normal``; fused, the cells' own fit) (1.4826 MAD, at its one-sided
   95 % upper bound for the number of points: five points may under-read it by half) is the points' noise
   ``sigma``, measured at this range on this sensor; its level: the points' median height;
2. the ground around it: the frame's depth on a pixel grid (``surroundings``; the SLAM map points crowd on
   texture), the samples whose plan distance from the centre lies in the annulus from the landing
   square's corner radius (the site's own square left out) to ``ground_radius_m``, averaged per plan cell
   of ``ground_cell_m`` (the annulus weighed by area, not by how many samples each surface gives);
3. the lowest large surface: the lowest ``ground_share`` of the cells (a lower surface covering that share
   of the annulus, not a ditch or a strip beside the site, which are the edge clearance's and the flatness
   map's business), a plane fitted through them (free slope: a gentle slope's own ground is its plane, and
   the site's noisy normal is not extrapolated 3 m), its height at the site, with the noise share that
   choosing the lowest cells picks removed (``phi(z) / share`` sigma, sigma the cells' own scatter about that
   plane over the lowest share's std, 0.53 at a third; per frame at most a point's sigma, which bounds a cell
   mean's: relief among the lowest cells is not noise). A point's sigma there lifted the ground by up to
   ~0.05 m where depth noise is independent per pixel and passed a 0.2 m box top. The plane's standard error
   takes per frame the smaller of the two, on fused cells (``around_var`` given) the largest of the site's
   sigma, the cells' stated one and their scatter: ground noisier than the site, or errors correlated into
   stripes, must not read as a lower surface;
4. ground only when the site's level above that stays within the UAV's step tolerance (``uav.max_step_m``)
   by ``margin_sigma`` standard errors (the plane's at the site, which grows when the low cells lie to one
   side, and the site level's): beyond the tolerance by that margin it is raised; within the margin of it,
   not told from raised, and refused as well (a wrong site is worse than none). A terrace or a kerb within
   the tolerance is ground.

Fewer than ``min_cells`` plan cells with a point in the annulus (the view holds too little around the
site): not measured, the site is not refused by this rule (``Raised.measured`` False says so).
Where a site is selected at all, the depth noise at the footprint's scale is already within the step
tolerance (the frame vouches, or the fused cells are decided), so the margin covers the points' own
scatter only.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import gammaincinv, ndtri

from slzcli.geometry import back_project, transform_points

if TYPE_CHECKING:
    from slzcli.config import Config, RaisedCfg
    from slzcli.types import Intrinsics

_MAD_TO_SIGMA = 1.4826  # a normal's std over its median absolute deviation
_MAD_EFFICIENCY = 0.37  # the MAD's variance efficiency against the std for normal noise: its effective dof share
_SIGMA_BOUND = 0.05     # the noise is taken at its one-sided 95 % upper bound: a few points under-read it
_PLANE_REFIT = 3.0      # sigmas: points beyond it from a first plane fit are left out of the second
NOT_TOLD = "not told from one"   # a refusal's words when the height is within the margin of the tolerance


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
    # a "not told" reading whose margin is at least the tolerance itself cannot tell level ground from a step the
    # UAV cannot take: True drops it (no refusal, no reading) for a method whose own cells decided the ground (fused)
    defer_untold: bool = False

    def defers(self, found: Raised) -> bool:
        """Whether ``found`` is dropped (neither a refusal nor a reading): ``defer_untold`` and a "not told" whose
        margin is at least the tolerance."""
        return self.defer_untold and found.refused and not found.raised and found.margin_m >= self.max_height_m

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


def fitted_normal(points: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """The normal of the least-squares plane through ``points`` (n, 3), refitted once without the points beyond
    ``_PLANE_REFIT`` sigma of the first fit (a stray map point off the surface would tilt it); ``fallback`` for
    fewer than three points or a degenerate set."""
    good = points[np.all(np.isfinite(points), axis=1)]
    for _ in range(2):
        if good.shape[0] < 3:
            return fallback
        q = good - good.mean(axis=0)
        _, s, vt = np.linalg.svd(q, full_matrices=False)
        if s[1] <= 0.0:
            return fallback
        n = vt[-1]
        d = q @ n
        scale = _MAD_TO_SIGMA * float(np.median(np.abs(d - np.median(d))))
        keep = np.abs(d - np.median(d)) <= _PLANE_REFIT * scale
        if scale <= 0.0 or keep.all():
            break
        good = good[keep]
    return n


@dataclass(frozen=True)
class Raised:
    """What the rule found for one site."""

    height_m: float | None   # the site's surface above the ground around it (None: not measured)
    threshold_m: float       # the height above which it is raised beyond doubt (tolerance + margin)
    points: int              # plan cells of the annulus with a point
    refused: bool            # raised, or not told from raised: height + margin above the tolerance
    margin_m: float = 0.0    # margin_sigma standard errors of the height

    @property
    def measured(self) -> bool:
        return self.height_m is not None

    @property
    def raised(self) -> bool:
        """Raised beyond doubt (else a refusal says the height cannot be told from the tolerance)."""
        return self.height_m is not None and self.height_m > self.threshold_m

    def reason(self) -> str:
        """The words of a refusal (a Candidate's reason)."""
        h = self.height_m or 0.0
        tol = self.threshold_m - self.margin_m
        if self.raised:
            return (f"on a surface {h:.1f} m above the ground around it (more than the UAV's step tolerance, "
                    f"uav.max_step_m, by the noise margin: {self.threshold_m:.2f} m)")
        return (f"on a surface {h:.2f} +- {self.margin_m:.2f} m above the ground around it: {NOT_TOLD} "
                f"higher than the UAV's step tolerance, uav.max_step_m {tol:.2f} m, at this noise (from lower, "
                "or fused over more looks, the margin shrinks)")


def _cell_means(rel: np.ndarray, up: np.ndarray, cell_m: float,
                var: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Per plan cell of ``cell_m`` with a point: the mean plan position (n, 2) and the mean height along ``up``
    of the points ``rel`` (relative to the site): the annulus weighed by area, not by point count (a near box
    top holds more depth samples per square metre than the ground beyond it, and SLAM points crowd on
    texture); with ``var`` (each point's height variance), its mean per cell."""
    if rel.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros(0), None if var is None else np.zeros(0)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    xy = np.stack([rel @ e1, rel @ e2], axis=1)
    ij = np.floor(xy / cell_m).astype(np.int64)
    ij -= ij.min(axis=0)
    # one key per cell, in the order of its (column, row) pair: a 1-d sort, not a sort of rows (~10x faster)
    _, inv = np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1], return_inverse=True)
    count = np.bincount(inv)
    mean_xy = np.stack([np.bincount(inv, weights=xy[:, k]) / count for k in (0, 1)], axis=1)
    return (mean_xy, np.bincount(inv, weights=rel @ up) / count,
            None if var is None else np.bincount(inv, weights=var) / count)


@functools.lru_cache(maxsize=256)
def _sigma_bound(n_site: int) -> float:
    """The MAD's one-sided 95 % upper bound factor for ``n_site`` points (scipy's quantiles cost ~0.2 ms a call,
    and the fused verdict asks once per patch per frame)."""
    dof = max(1.0, _MAD_EFFICIENCY * (n_site - 1))
    return math.sqrt(dof / float(2.0 * gammaincinv(dof / 2.0, _SIGMA_BOUND)))   # chi2's quantile


def _normal_pdf(z: float) -> float:
    """The standard normal density, as scipy.stats computes it (whose import costs a run ~0.4 s of start-up)."""
    return float(np.exp(-z ** 2 / 2.0) / np.sqrt(2.0 * np.pi))


@functools.lru_cache(maxsize=8)
def _lowest_share_bias(share: float) -> float:
    """How far below the mean the lowest ``share`` of normal noise lies on average, in sigmas: phi(z) / share."""
    return _normal_pdf(float(ndtri(share))) / share


@functools.lru_cache(maxsize=8)
def _lowest_share_std(share: float) -> float:
    """The std of the lowest ``share`` of normal noise, in sigmas (a normal truncated above at its ``share``
    quantile): the scatter the lowest cells of level ground show."""
    z = float(ndtri(share))
    m = _normal_pdf(z) / share
    return math.sqrt(1.0 - z * m - m * m)


def above_ground(centre: np.ndarray, normal: np.ndarray, site_xyz: np.ndarray, around_xyz: np.ndarray,
                 params: RaisedParams, up: np.ndarray, around_var: np.ndarray | None = None) -> Raised:
    """The rule (module docstring) for a site at ``centre`` with surface ``normal``; ``site_xyz``: the site's
    own points (their scatter about its plane is the noise), ``around_xyz``: every point that may be its
    surroundings; ``around_var``: their stated height variance where known (fused cells: the ground around a
    site may be noisier than the site, seen by fewer or farther looks, and smoothed cells scatter less about
    their plane than they err), which the ground's noise then takes when larger."""
    up = up / np.linalg.norm(up)
    n = normal / np.linalg.norm(normal)
    if float(n @ up) < 0:
        n = -n
    rel_site = site_xyz - centre
    d_site = rel_site @ n                                    # the site's points about its own plane
    d_site = d_site[np.isfinite(d_site)]
    rel = around_xyz - centre
    h_all = rel @ up
    r = np.linalg.norm(rel - h_all[:, None] * up[None, :], axis=1)
    ring = (r >= params.inner_radius_m) & (r <= params.radius_m) & np.isfinite(h_all)
    xy, h, var_h = _cell_means(rel[ring], up, params.cell_m, None if around_var is None else around_var[ring])
    n_ring, n_site = int(h.size), int(d_site.size)
    tol = params.max_height_m
    if n_ring < params.min_points or n_site < 3:
        return Raised(None, tol, n_ring, False)
    sigma = _MAD_TO_SIGMA * float(np.median(np.abs(d_site - np.median(d_site)))) * _sigma_bound(n_site)
    level = float(np.median(rel_site @ up))                  # the site's surface height at its centre
    # the lowest large surface: the lowest ground_share of the cells, a plane through them (gravity-aligned
    # heights, free slope: the ground of a gentle slope is its own plane), its height at the site
    share = params.ground_share
    low = h <= np.quantile(h, share)
    # the ground cells' noise: the site's; with their stated noise (fused cells), also that (a cell mean's
    # variance taken as its points' mean variance: correlated within a cell, as depth noise is over many pixels)
    # and their scatter about their plane over a share's truncated-normal std, whichever is largest
    sigma_g = sigma if var_h is None else max(sigma, math.sqrt(float(np.mean(var_h[low]))))
    a = np.column_stack([np.ones(int(low.sum())), xy[low]])
    gram = a.T @ a
    sigma_pick = sigma_g
    if low.sum() >= 4 and np.linalg.cond(gram) < 1e12:
        coef = np.linalg.solve(gram, a.T @ h[low])
        resid = h[low] - a @ coef
        scatter = float(np.sqrt(np.sum(resid * resid) / (low.sum() - 3))) / _lowest_share_std(share)
        # per frame, the plane goes through cell means, whose noise a point's sigma bounds from above (relief
        # among the lowest cells, a wall or a rock, makes their scatter larger: not noise)
        sigma_g = min(sigma_g, scatter) if var_h is None else max(sigma_g, scatter)
        sigma_pick = sigma_g if var_h is None else scatter
        ground_h, se_ground = float(coef[0]), sigma_g * math.sqrt(float(np.linalg.inv(gram)[0, 0]))
    else:
        ground_h, se_ground = float(np.median(h[low])), sigma_g * math.sqrt(math.pi / 2 / max(int(low.sum()), 1))
    # choosing the lowest cells picks their noise too: level ground's lowest share lies phi(z)/share sigma low,
    # sigma the noise that picked them, the cells' own scatter (a point's sigma, or a stated std that errors the
    # cells share make larger, would lift the ground by more than the choice lowered it and pass a low box top)
    ground_h += _lowest_share_bias(share) * sigma_pick
    height = level - ground_h
    se = se_ground + sigma * math.sqrt(math.pi / 2 / n_site)
    margin = params.confidence_sigma * se
    # a site is ground only when its height is within the tolerance beyond doubt: a surface read within the
    # margin of it may be a box top a few centimetres too high (a D435 from 5 m read a 0.2 m top at 0.09-0.16 m)
    return Raised(height, tol + margin, n_ring, height + margin > tol, margin)
