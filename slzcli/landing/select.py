"""The best point to land (METHOD 2.5): SLAM map points through the landing mask, clustered.

Steps, each a pure function: project the keyframe's map points into its image, keep those
under the mask, k-means them, estimate a normal per point from its 0.5 m neighbourhood,
and pick the cluster that qualifies (extent at least the footprint) by the method's rule:
the paper's *minimum normal variance* for fuzzy, the baseline's *largest cluster* for
Bayes (BASELINE.md). No cluster qualifies: a ``NoSite`` with the reason, never a guess.

Decisions (the paper is silent):
- Extent is measured along the world x and y axes, the axes of the Eq. 10 square.
- Normal variance of unit normals is ``1 - |mean(n)|^2`` (the trace of their covariance).
- A cluster whose centroid projects onto a pixel the mask rejects (a ring around an
  obstacle) does not qualify: the site never lies where the mask says unsafe.
- k-means is seeded from config, so a run is reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import cKDTree

from slzcli.errors import ConfigError
from slzcli.geometry import project, transform_points
from slzcli.landing.corners import square_corners
from slzcli.landing.raised import Raised, RaisedParams, above_ground, fitted_normal
from slzcli.records import SITE_FROM_POINTS
from slzcli.types import Candidate, Selection, Site

WORLD_UP = np.array([0.0, 0.0, 1.0])  # world up when the caller names none: +z


@dataclass(frozen=True)
class SelectParams:
    """What selection needs from config, resolved per method by the pipeline."""

    kmeans_k: int
    normal_radius_m: float
    min_cluster_points: int
    footprint_m: tuple[float, float]
    min_extent_factor: float
    rule: str  # "min_normal_variance" (fuzzy, METHOD 2.5) | "largest" (bayes, BASELINE)
    seed: int
    edge_clearance_m: float  # acceptance test: clearance to the nearest depth edge must exceed this
    max_tilt_deg: float      # acceptance test: surface tilt at most this (uav.max_slope_deg)
    max_normal_pairs: int = 0  # neighbour pairs point_normals may build (0 = no bound; landing.max_normal_pairs)
    raised: RaisedParams | None = None  # the raised-surface rule (landing/raised.py; None: not applied)


def point_normals(xyz: np.ndarray, radius_m: float, up: np.ndarray, max_pairs: int = 0) -> np.ndarray:
    """Per-point normals from the PCA of all points within ``radius_m``, oriented along ``up``.

    Vectorised: neighbour pairs from a k-d tree, covariance sums by ``np.add.at``, batched
    ``eigh``. Points with fewer than 3 neighbours (themselves included) get NaN. The pairs cost
    ~180 B each; ``max_pairs`` > 0 counts them first (the tree counts whole nodes, nothing is
    built) and refuses more, naming ``landing.normal_radius_m``: a radius as large as the view
    makes every pair of points one (n^2 / 2).
    """
    n = xyz.shape[0]
    if n == 0:
        return np.zeros((0, 3))
    tree = cKDTree(xyz)
    if max_pairs > 0:
        count = (int(tree.count_neighbors(tree, radius_m)) - n) // 2
        if count > max_pairs:
            raise ConfigError("landing.normal_radius_m",
                              f"{radius_m:g} m joins {count:.3g} pairs of the {n} map points under the mask, "
                              f"more than landing.max_normal_pairs {max_pairs:.3g} (~180 B a pair); "
                              "use a smaller radius (or raise the bound)")
    pairs = tree.query_pairs(radius_m, output_type="ndarray")
    i = np.concatenate([np.arange(n), pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([np.arange(n), pairs[:, 1], pairs[:, 0]])
    counts = np.bincount(i, minlength=n).astype(np.float64)
    centred = xyz - xyz.mean(axis=0)  # keeps the second moments well conditioned far from the origin
    s1 = np.zeros((n, 3))
    np.add.at(s1, i, centred[j])
    outer = centred[:, :, None] * centred[:, None, :]
    s2 = np.zeros((n, 3, 3))
    np.add.at(s2, i, outer[j])
    mean = s1 / counts[:, None]
    cov = s2 / counts[:, None, None] - mean[:, :, None] * mean[:, None, :]
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    normals *= np.where(normals @ up < 0, -1.0, 1.0)[:, None]
    normals[counts < 3] = np.nan
    return normals


def select_site(xyz_world: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray, mask: np.ndarray,
                score: np.ndarray, params: SelectParams, *, up_world: np.ndarray = WORLD_UP,
                edge_distance_m: np.ndarray | None = None, around_world: np.ndarray | None = None) -> Selection:
    """Choose the landing site among the map points of one keyframe (METHOD 2.5); ``around_world``: the points
    the raised-surface rule reads the ground around a cluster from (``raised.surroundings``; None: the map
    points)."""
    n = xyz_world.shape[0]
    pixels, inside = project(xyz_world, T_world_camera, K, mask.shape)
    kept = np.zeros(n, bool)
    iu = np.round(pixels[inside]).astype(int)
    kept[np.flatnonzero(inside)] = mask[iu[:, 1], iu[:, 0]]
    labels = np.full(n, -1)
    empty = Selection(None, "", (), pixels, kept, labels, int(np.count_nonzero(inside)))
    n_kept = int(kept.sum())
    if n_kept < params.min_cluster_points:
        why = (f"only {n_kept} of {n} SLAM map points lie on the landing mask "
               f"(at least {params.min_cluster_points} needed)")
        return replace(empty, reason=why)

    pts = xyz_world[kept]
    k = max(1, min(params.kmeans_k, n_kept // params.min_cluster_points))
    _, lab = kmeans2(pts, k, minit="++", seed=params.seed)
    labels[kept] = lab
    up = up_world / np.linalg.norm(up_world)
    normals = point_normals(pts, params.normal_radius_m, up, params.max_normal_pairs)
    min_extent = np.asarray(params.footprint_m) * params.min_extent_factor

    candidates = []
    for c in range(k):  # k is a handful of clusters: not a per-point loop
        member = lab == c
        candidates.append(_candidate(c, pts[member], normals[member], min_extent, params, T_world_camera, K, mask,
                                     xyz_world if around_world is None else around_world, up))
    good = [c for c in candidates if c.qualifies]
    if not good:
        reasons = "; ".join(f"cluster {c.cluster}: {c.reason}" for c in candidates)
        return replace(empty, reason=raised_lead(candidates, params) + f"no cluster qualifies ({reasons})",
                       candidates=tuple(candidates))
    if params.rule == "largest":
        best = max(good, key=lambda c: (c.points, -c.normal_variance))
    else:
        best = min(good, key=lambda c: (c.normal_variance, -c.points))
    member = lab == best.cluster
    site = _site(best, pts[member], normals[member], T_world_camera, K, score, params, up, edge_distance_m)
    return replace(empty, site=site, candidates=tuple(candidates))


def raised_lead(candidates: list[Candidate], params: SelectParams) -> str:
    """The no-site reason's lead when the cluster the rule would have chosen was refused as raised only: what
    the user must hear first (the rest of the reason lists every cluster)."""
    raised = [c for c in candidates if c.test == "raised"]
    if not raised:
        return ""
    best = max(raised, key=lambda c: (c.points, -c.normal_variance)) if params.rule == "largest" else \
        min(raised, key=lambda c: (c.normal_variance, -c.points))
    return f"the best site is {best.reason}; "


def _candidate(c: int, pts: np.ndarray, normals: np.ndarray, min_extent: np.ndarray, params: SelectParams,
               T_world_camera: np.ndarray, K: np.ndarray, mask: np.ndarray, around: np.ndarray,
               up: np.ndarray) -> Candidate:
    centroid = pts.mean(axis=0) if len(pts) else np.full(3, np.nan)
    extent = np.ptp(pts[:, :2], axis=0) if len(pts) else np.zeros(2)
    good_n = normals[np.all(np.isfinite(normals), axis=1)]
    variance = float(1.0 - np.sum(good_n.mean(axis=0) ** 2)) if len(good_n) >= 3 else float("nan")
    reason = test = ""
    found: Raised | None = None
    if len(pts) < params.min_cluster_points:
        reason, test = f"{len(pts)} points (< {params.min_cluster_points})", "points"
    elif not np.isfinite(variance):
        reason, test = f"fewer than 3 points with a normal within {params.normal_radius_m} m", "normals"
    elif np.any(extent < min_extent):
        reason = f"extent {extent[0]:.2f} x {extent[1]:.2f} m below {min_extent[0]:.2f} x {min_extent[1]:.2f} m"
        test = "extent"
    else:
        (uv,), (inside,) = project(centroid[None], T_world_camera, K, mask.shape)
        if not inside or not mask[round(float(uv[1])), round(float(uv[0]))]:
            reason, test = "centroid falls on a pixel the mask rejects", "centroid"
        elif params.raised is not None:
            found = raised_site(centroid, good_n, pts, around, params.raised, up)
            if params.raised.defers(found):
                found = None   # it cannot tell: left to the method's own evidence (RaisedParams.defer_untold)
            elif found.refused:
                reason, test = found.reason(), "raised"
    return Candidate(c, len(pts), _vec3(centroid), variance, (float(extent[0]), float(extent[1])),
                     reason == "", reason or "qualifies", test, None if found is None else found.points,
                     None if found is None else found.height_m,
                     None if found is None or found.height_m is None else found.margin_m)


def raised_site(centroid: np.ndarray, normals: np.ndarray, pts: np.ndarray, around: np.ndarray,
                params: RaisedParams, up: np.ndarray) -> Raised:
    """The raised-surface rule for a cluster: its centroid, the plane fitted to its points, the frame's depth
    around it. The rule's noise is the points' scatter about that plane: about their mean normal instead (each
    point's normal from its neighbours within ``normal_radius_m``, a few degrees off at range) level ground read
    within 0.06 m carried margins of 0.1-1.4 m, and sites on it were refused as not told from raised."""
    normal = fitted_normal(pts, normals.mean(axis=0))
    return above_ground(centroid, normal, pts, around, params, up)


def _site(best: Candidate, pts: np.ndarray, normals: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray,
          score: np.ndarray, params: SelectParams, up: np.ndarray, edge_distance_m: np.ndarray | None) -> Site:
    centroid = np.asarray(best.centroid_world)
    good_n = normals[np.all(np.isfinite(normals), axis=1)]
    mean_n = good_n.mean(axis=0)
    # the surface's tilt from the plane through the cluster, not the mean of its points' normals: each of those
    # comes from the few neighbours within normal_radius_m, and from ORB-SLAM3's sparse points at 10 m (8-61 a
    # cluster, ~0.25 m of depth noise each) their mean read level ground as 19-72 deg (benchmarks/fused_detect.py)
    normal = fitted_normal(pts, mean_n / np.linalg.norm(mean_n))
    notes = []
    if params.raised is not None and best.raised_cells is not None and best.raised_m is None:
        notes.append(unmeasured_note(best.raised_cells, params.raised))
    px_pts, inside = project(pts, T_world_camera, K, score.shape)
    ip = np.round(px_pts[inside]).astype(int)
    site_score = float(score[ip[:, 1], ip[:, 0]].mean()) if len(ip) else float("nan")
    site = accepted_site(centroid, normal, T_world_camera, K, score.shape, params, up, edge_distance_m, notes)
    assert site is not None  # the cluster's centroid lies on the mask, inside the image
    return replace(site, cluster_points=best.points, normal_variance=best.normal_variance, extent_m=best.extent_m,
                   score=site_score)


def accepted_site(centre: np.ndarray, normal: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray,
                  shape: tuple[int, int], params: SelectParams, up: np.ndarray, edge_distance_m: np.ndarray | None,
                  notes: list[str], source: str = SITE_FROM_POINTS) -> Site | None:
    """A site at ``centre`` (world) on the surface of ``normal``, with the acceptance test every site passes
    whatever chose it: the edge clearance at its pixel above ``params.edge_clearance_m`` and the tilt within
    ``params.max_tilt_deg``. None when its centre is outside the image. The cluster's fields are left empty
    (no points, variance NaN, the footprint's extent, score NaN): a cluster's site fills them."""
    (uv,), (inside,) = project(centre[None], T_world_camera, K, shape)
    if not inside:
        return None
    normal = normal if normal @ up >= 0.0 else -normal
    tilt = float(np.degrees(np.arccos(np.clip(normal @ up / np.linalg.norm(normal), -1.0, 1.0))))
    iu, iv = round(float(uv[0])), round(float(uv[1]))
    clearance = None if edge_distance_m is None else float(edge_distance_m[iv, iu])
    failures = []
    if clearance is not None and not clearance > params.edge_clearance_m:
        failures.append(f"edge clearance {clearance:.2f} m <= {params.edge_clearance_m:.2f} m")
    if tilt > params.max_tilt_deg:
        failures.append(f"tilt {tilt:.1f} deg > {params.max_tilt_deg:.1f} deg")
    notes = ([] if failures or clearance is not None else ["tilt only: edge clearance not measured"]) + notes
    return Site(
        pixel=(float(uv[0]), float(uv[1])), center_camera=_vec3(transform_points(np.linalg.inv(T_world_camera),
                                                                                centre)),
        center_world=_vec3(centre), corners_world=tuple(_vec3(c) for c in square_corners(centre, params.footprint_m)),
        normal_world=_vec3(normal / np.linalg.norm(normal)), cluster_points=0, normal_variance=float("nan"),
        extent_m=(float(params.footprint_m[0]), float(params.footprint_m[1])), score=float("nan"), tilt_deg=tilt,
        edge_clearance_m=clearance, accepted=not failures,
        acceptance_reason=("; ".join(failures) or "passed") + (f" ({'; '.join(notes)})" if notes else ""),
        source=source)


def unmeasured_note(cells: int, params: RaisedParams) -> str:
    """What an accepted site's reason says when the raised-surface rule could not read the ground around it: the
    site was not tested for standing on a box top or a roof."""
    return (f"raised-surface rule not measured: {cells} cells around it with depth, fewer than "
            f"landing.raised.min_cells {params.min_points}")


def _vec3(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
