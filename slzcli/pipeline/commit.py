"""The commit rule: which of a run's detected sites ``landing.json`` holds.

Every detection frame may give a site; the one written to ``landing.json`` is the site confirmed by
the most detections (other sites within ``landing.commit_radius_factor`` footprint sides of it in
plan, two by default, in the same map segment: positions in different segments are in different
frames), among those that pass the acceptance test when any do; ties go to the lower normal
variance, then to the later frame. One lucky keyframe cannot outvote a site seen again and again.
The committed site's segment is the run's world frame. ``landing.commit: latest`` (the paper's
"current keyframe") takes the last detection's site instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slzcli.config import Config


def commit_radius_m(config: Config) -> float:
    """How close (in plan, metres) two detections' site centres must be to confirm each other."""
    return config.landing.commit_radius_factor * config.uav.footprint_m[0]


def commit(sites: list[dict[str, Any]], config: Config) -> dict[str, Any] | None:
    """The committed site of a run's sites under the config's rule and radius (every run commits here)."""
    return commit_site(sites, commit_radius_m(config), config.landing.commit)


def commit_site(sites: list[dict[str, Any]], side_m: float, rule: str = "agree") -> dict[str, Any] | None:
    """The site confirmed by the most detections of its own map segment (see the module docstring).

    Adds ``support`` (agreeing detections, this one included), ``detections`` (sites of the run),
    ``segment`` and ``segment_detections`` (sites of that segment) to the chosen entry.
    ``rule`` ``latest``: the last detection's site, accepted or not; its support is still counted.
    """
    if not sites:
        return None
    pool = [s for s in sites if s["site"].accepted] or sites
    if rule == "latest":
        pool = sites
    centres = np.array([s["site"].center_world for s in pool])
    seg = np.array([s["segment"] for s in pool])
    near = np.linalg.norm(centres[:, None, :2] - centres[None, :, :2], axis=2) <= side_m
    support = (near & (seg[:, None] == seg[None, :])).sum(axis=1)
    order = sorted(range(len(pool)), key=lambda i: (-support[i], pool[i]["site"].normal_variance,
                                                      -pool[i]["frame"].index))
    if rule == "latest":
        order = [max(range(len(pool)), key=lambda i: pool[i]["frame"].index)]
    best = dict(pool[order[0]])
    best["support"] = int(support[order[0]])
    best["detections"] = len(sites)
    best["segment"] = int(seg[order[0]])
    best["segment_detections"] = sum(s["segment"] == best["segment"] for s in sites)
    return best
