"""The commit rule: which of a run's detected sites ``landing.json`` holds (every run commits here).

The ranking is ``slzcli.landing.commit``'s: by what the ground gives each site (confirmed by
another detection of the same map segment within ``landing.commit_radius_factor`` footprint
sides, within ``landing.commit_score_band`` of the best score, the plan medoid of those), never
by the order detections arrived, which ORB-SLAM3's threads change from run to run. The committed
site's segment is the run's world frame. ``landing.commit: latest`` (the paper's "current
keyframe") takes the last detection's site instead.
"""

from __future__ import annotations

from typing import Any

from slzcli.config import Config
from slzcli.landing.commit import commit as rank_sites


def commit_radius_m(config: Config) -> float:
    """How close (in plan, metres) two detections' site centres must be to confirm each other."""
    return config.landing.commit_radius_factor * config.uav.footprint_m[0]


def commit(sites: list[dict[str, Any]], config: Config) -> dict[str, Any] | None:
    """The committed site of a run's sites under the config's rule, radius and score band."""
    return commit_site(sites, commit_radius_m(config), config.landing.commit, config.landing.commit_score_band)


def commit_site(sites: list[dict[str, Any]], side_m: float, rule: str = "agree",
                score_band: float = 0.0) -> dict[str, Any] | None:
    """The committed site (``slzcli.landing.commit``; ``score_band``: ``landing.commit_score_band``).

    Adds ``support`` (agreeing detections, this one included), ``detections`` (sites of the run),
    ``segment``, ``segment_detections`` (sites of that segment) and ``ranked`` (its equally good sites,
    the sites another run may commit and their spread) to the chosen entry.
    """
    found = rank_sites(sites, side_m, score_band, rule)
    if found is None:
        return None
    best, ranked = found
    best.update(support=ranked.support, detections=len(sites), segment=int(best["segment"]), ranked=ranked,
                segment_detections=sum(s["segment"] == best["segment"] for s in sites))
    return best
