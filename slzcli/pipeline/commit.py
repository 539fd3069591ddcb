"""The commit rule: which of a run's detected sites ``landing.json`` holds (every run commits here).

The ranking is ``slzcli.landing.commit``'s: by what the ground gives each site (confirmed by
another detection of the same map segment within ``landing.commit_radius_factor`` footprint
sides, within ``landing.commit_score_band`` of the best score, the plan medoid of those), never
by the order detections arrived, which ORB-SLAM3's threads change from run to run. The committed
site's segment is the run's world frame. ``landing.commit: latest`` (the paper's "current
keyframe") takes the last detection's site instead, accepted or not. Either way a site the raised-surface rule's
readings around it refute (within that radius, its refusals outweigh its passes, each by its precision) is not
committed; under the default rule neither is one that failed its acceptance test (edge clearance, tilt).
"""

from __future__ import annotations

from slzcli.config import LandingCfg, UavCfg
from slzcli.landing.commit import commit as rank_sites
from slzcli.landing.commit import commit_radius_m
from slzcli.outputs.site_log import SiteLog
from slzcli.types import CommittedSite, FoundSite, RaisedReadings


def commit(log: SiteLog, landing: LandingCfg, uav: UavCfg) -> CommittedSite | None:
    """The committed site of a run's site log under ``landing``'s rule, radius (in ``uav`` footprints) and score
    band, none where the log's raised-surface readings refute it."""
    return commit_site(log.sites, commit_radius_m(landing, uav), landing.commit, landing.commit_score_band,
                       log.raised_readings())


def commit_site(sites: list[FoundSite], side_m: float, rule: str = "agree", score_band: float = 0.0,
                readings: RaisedReadings | None = None) -> CommittedSite | None:
    """The committed site (``slzcli.landing.commit``; ``score_band``: ``landing.commit_score_band``; ``readings``:
    the raised-surface rule's, which may refute a site), with its support, the run's and its segment's site counts
    and the ranking (its equally good sites and their spread)."""
    found = rank_sites(sites, side_m, score_band, rule, readings)
    if found is None:
        return None
    best, ranked = found
    return CommittedSite(best, ranked.support, len(sites), sum(s.segment == best.segment for s in sites), ranked)
