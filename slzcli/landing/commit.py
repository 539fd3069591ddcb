"""The committed site: which of a run's detections' sites landing.json names, and how far another run may differ.

ORB-SLAM3 tracks in threads, so which frames become keyframes, and so which detections a run
makes and in what order, changes from run to run of the same recording. The rule therefore
uses only what the ground gives a site, never the order detections arrived:

1. the pool: the sites that pass the acceptance test; when none does, no site is committed (a site too close to
   an edge or on a slope steeper than the UAV takes is not vouched for by the run that found it; the reason
   names the best one's failure);
2. confirmed: sites that another detection of the same map segment confirms (a site within
   ``radius_m`` in plan), when any is; one lucky keyframe does not commit a site alone;
3. equally good: confirmed sites of the best-scoring confirmed site's map segment whose score
   is within ``score_band`` of its score (the score is the landing score of the cluster's
   points, a property of the ground; positions in different segments are in different frames);
4. of those, the medoid in plan: the site with the least summed distance to the others, the
   middle of the good ground seen, whichever detections happened to see it. Ties go to the
   higher score, then the larger edge clearance, then the position (x, then y): never to a frame.

Before any of that, a site the raised-surface rule's readings around it refute is left out: each detection
reads the clusters it measures (landing/raised.py), so a surface seen from many frames is read many times, and
where within ``radius_m`` of a site (same map segment) the readings that refused a cluster (raised, or not told
from raised) outweigh those that passed one, each weighed by its precision (1 / margin^2), the frame that chose
it read the surface by luck (a D435 over a 0.12 m box top from 5 m, seeds 1-2: 57 of 60 readings on the top
refused it, at margins like those of the 3 frames that chose it). By count alone, two readings of noisy level
ground whose margins hid the tolerance by 0.4 m outvoted the 0.03 m reading that chose the site.

The spread: another run sees other keyframes, so it may commit any site of this run's pool in
the committed site's map segment (its equals change with the score's run-to-run noise). The
largest plan distance between two of them is how far apart runs may land (``site_spread_m``
in landing.json), an estimate from one run: with fewer than ``MIN_SITES_FOR_SPREAD`` sites
there is too little to estimate it from, and the record says so. Over two sets of 8 ORB-SLAM3
runs of the demo flight the committed sites lay 1.13 m and 2.13 m apart; each run of the second
set estimated 1.31-2.98 m (docs/DESIGN.md, "The committed site"). ``latest`` (``landing.commit``, the paper's current
keyframe) commits the last detection's site, accepted or not.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from slzcli.types import FoundSite, RaisedReadings, Ranked

if TYPE_CHECKING:
    from slzcli.config import LandingCfg, UavCfg

MIN_SITES_FOR_SPREAD = 3  # equally good sites needed to estimate the spread (two give one distance, no spread)
_MIN_MARGIN_M = 1e-3      # a reading's margin is floored here before it weighs (exact depth reads margins of ~0)


def commit_radius_m(landing: LandingCfg, uav: UavCfg) -> float:
    """How close (in plan, metres) two detections' site centres must be to confirm each other (and a raised-surface
    reading to bear on a site)."""
    return landing.commit_radius_factor * uav.footprint_m[0]


def support_counts(xy: np.ndarray, segment: np.ndarray, radius_m: float) -> np.ndarray:
    """Per site: the sites of its own map segment within ``radius_m`` in plan, itself included."""
    near = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2) <= radius_m
    return (near & (segment[:, None] == segment[None, :])).sum(axis=1)


def refuted(xy: np.ndarray, segment: np.ndarray, readings: RaisedReadings,
            radius_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per site (plan centres (n, 2), map segments): whether the raised-surface readings within ``radius_m`` of it
    in its segment refuse it, each weighed by its precision (1 / margin^2: a reading whose noise hides the
    tolerance by far says little either way), and how many refused and passed."""
    n = len(xy)
    if n == 0 or len(readings.xy) == 0:
        zero = np.zeros(n, np.int64)
        return np.zeros(n, bool), zero, zero
    # the pairs within the radius only (a long run holds thousands of sites and tens of thousands of readings)
    lists = cKDTree(xy).query_ball_tree(cKDTree(readings.xy), radius_m)
    counts = np.fromiter((len(near) for near in lists), np.int64, count=n)
    i = np.repeat(np.arange(n), counts)
    j = np.fromiter(itertools.chain.from_iterable(lists), np.int64, count=int(counts.sum()))
    keep = segment[i] == readings.segment[j]
    i, j = i[keep], j[keep]
    no = readings.refused[j]
    weight = 1.0 / np.maximum(readings.margin_m[j], _MIN_MARGIN_M) ** 2
    against = np.bincount(i, weights=np.where(no, weight, 0.0), minlength=n)
    for_ = np.bincount(i, weights=np.where(no, 0.0, weight), minlength=n)
    refused = np.bincount(i, weights=no.astype(np.float64), minlength=n).astype(np.int64)
    passed = np.bincount(i, weights=(~no).astype(np.float64), minlength=n).astype(np.int64)
    return against > for_, refused, passed


def _plan(sites: Sequence[FoundSite]) -> tuple[np.ndarray, np.ndarray]:
    """The sites' plan centres (n, 2) and map segments."""
    return (np.array([s.site.center_world[:2] for s in sites], dtype=np.float64).reshape(-1, 2),
            np.array([s.segment for s in sites], dtype=np.int64))


def no_commit_reason(sites: Sequence[FoundSite], readings: RaisedReadings, radius_m: float) -> str:
    """Why a run whose detections found sites commits none (``commit``): the raised-surface readings refute every
    one, or every one they leave failed its acceptance test."""
    out, refused, passed = refuted(*_plan(sites), readings, radius_m)
    if out.all():
        best = int(np.argmax(passed / np.maximum(refused + passed, 1))) if len(sites) else 0
        return (f"the raised-surface rule refutes every site the detection frames chose ({len(sites)}): around "
                f"each, the clusters it read within {radius_m:.2f} m (landing.commit_radius_factor) on a surface it "
                "could not tell from one above the UAV's step tolerance, uav.max_step_m, outweigh those it passed, "
                f"each reading weighed by its precision (the best: {int(refused[best])} refused, "
                f"{int(passed[best])} passed); fly lower over it, or longer with --method fused")
    kept = [s for s, o in zip(sites, out, strict=True) if not o]
    best_site = max(kept, key=lambda s: (np.nan_to_num(s.site.score, nan=-np.inf), -s.frame.index))
    x, y = best_site.site.center_world[:2]
    gone = f", after {int(out.sum())} refuted by the raised-surface rule" if out.any() else ""
    return (f"every site the detection frames chose failed its acceptance test ({len(kept)}{gone}); the best, at "
            f"({x:.1f}, {y:.1f}) m: {best_site.site.acceptance_reason}")


def rank(xy: np.ndarray, segment: np.ndarray, score: np.ndarray, clearance: np.ndarray, accepted: np.ndarray,
         radius_m: float, score_band: float) -> Ranked:
    """The committed site (module docstring) among sites given as arrays: plan centres (n, 2), map segment,
    score, edge clearance (NaN: not measured) and whether each passed the acceptance test."""
    n = len(xy)
    pool = np.flatnonzero(accepted) if accepted.any() else np.arange(n)
    sup = np.zeros(n, np.int64)
    sup[pool] = support_counts(xy[pool], segment[pool], radius_m)
    confirmed = pool[sup[pool] >= 2] if (sup[pool] >= 2).any() else pool
    top = confirmed[np.lexsort((segment[confirmed], -score[confirmed]))[0]]   # best score; a tie: lower segment
    same = confirmed[segment[confirmed] == segment[top]]
    equals = same[score[same] >= score[top] - score_band]
    total = np.linalg.norm(xy[equals, None, :] - xy[None, equals, :], axis=2).sum(axis=1)
    clear = np.nan_to_num(clearance[equals], nan=-1.0)
    # np.lexsort sorts by the last key first: least summed distance, then higher score, larger clearance, x, y
    order = np.lexsort((xy[equals, 1], xy[equals, 0], -clear, -score[equals], np.round(total, 9)))
    chosen = int(equals[order[0]])
    alike = pool[segment[pool] == segment[chosen]]
    spread = float(np.linalg.norm(xy[alike, None, :] - xy[None, alike, :], axis=2).max(initial=0.0))
    return Ranked(chosen, int(sup[chosen]), tuple(int(i) for i in equals), tuple(int(i) for i in alike), spread)


def commit(sites: Sequence[FoundSite], radius_m: float, score_band: float, rule: str = "agree",
           readings: RaisedReadings | None = None) -> tuple[FoundSite, Ranked] | None:
    """The committed one of a run's found sites and its ranking (indices into the sites ``readings`` do not
    refute; None: no site, or every site refuted).

    ``rule`` ``latest``: the last detection's site (by frame index), its support still counted."""
    if sites and readings is not None:
        out, _, _ = refuted(*_plan(sites), readings, radius_m)
        sites = [s for s, o in zip(sites, out, strict=True) if not o]
    if not sites or (rule != "latest" and not any(s.site.accepted for s in sites)):
        return None
    xy, segment = _plan(sites)
    score = np.array([s.site.score for s in sites], dtype=np.float64)
    clearance = np.array([np.nan if s.site.edge_clearance_m is None else s.site.edge_clearance_m
                          for s in sites], dtype=np.float64)
    accepted = np.array([bool(s.site.accepted) for s in sites])
    ranked = rank(xy, segment, np.nan_to_num(score, nan=-np.inf), clearance, accepted, radius_m, score_band)
    if rule == "latest":
        last = max(range(len(sites)), key=lambda i: sites[i].frame.index)
        ranked = Ranked(last, int(support_counts(xy, segment, radius_m)[last]), (last,), (last,), 0.0)
    return sites[ranked.index], ranked


def spread_record(ranked: Ranked, footprint_side_m: float) -> dict[str, Any]:
    """landing.json's ``site_spread_m`` and what it means for this run (``stable``: runs stay within a footprint)."""
    n = len(ranked.pool)
    if n < MIN_SITES_FOR_SPREAD:
        note = (f"{n} site(s) this run could commit: too few to estimate how far another run (ORB-SLAM3's "
                "threads) may commit from this one; it may commit elsewhere")
        return {"site_spread_m": None, "site_spread": {"sites": n, "stable": False, "note": note}}
    stable = ranked.spread_m <= footprint_side_m
    note = (f"another run may commit any of the {n} sites this one could, at most {ranked.spread_m:.2f} m apart: "
            + ("within" if stable else "more than") + f" one footprint side ({footprint_side_m:.3f} m)")
    return {"site_spread_m": ranked.spread_m, "site_spread": {"sites": n, "stable": stable, "note": note}}
