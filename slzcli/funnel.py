"""The funnel of a detection frame: what each filter between the depth image and a landing site left.

Mask steps, in full-resolution pixels of the frame, each counted after the ones before it:

- ``depth``: pixels with a depth measurement;
- ``threshold``: of those, the pixels whose score is above the method's threshold (``mask.threshold``,
  ``scoring.bayes.threshold``);
- ``footprint``: the pixels whose footprint square (``uav.footprint_m`` x ``mask.margin_factor`` plus the
  clearance on every side, in plan or in the image: ``mask.clearance``; after ``mask.smooth_m``) is
  observed and above the threshold everywhere;
- ``column``: of those, the pixels whose final descent's column (``control.desired_depth_m``) was in view
  (plan clearance only);
- ``noise``: of those, the pixels the frame's noise limits vouch for (the frame vouches, the pixel lies
  within ``vouch_depth_m``): the landing mask.

Then the site selection: the keyframe's SLAM map points, those in the view and those on the mask; the
k-means clusters and the first test each failed; the site and its acceptance test.

The counts are a handful of ``count_nonzero`` on masks the mask stage makes anyway (``scoring.mask_score``);
the run keeps one small row per detection frame (run.json ``funnel``). ``FunnelLog.reason`` turns the rows
into the run's no-site reason: the step that removed the most, and what would change it.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from slzcli.landing.raised import NOT_TOLD
from slzcli.types import MASK_STEPS, Detection, MaskFunnel, TerrainMaps

STEP_TEXT = {"threshold": "the score threshold", "footprint": "the footprint clearance",
             "column": "the descent column", "noise": "the noise limits"}
# The clusters' tests (landing/select.py ``Candidate.test``), in the order they are applied.
CLUSTER_TESTS = {"points": "too few points (landing.min_cluster_points)",
                 "normals": "too few points with a normal (landing.normal_radius_m)",
                 "extent": "extent below the footprint (uav.footprint_m x landing.min_extent_factor)",
                 "centroid": "centroid on a pixel the mask rejects",
                 "raised": "on a surface raised above the ground around it (landing.raised)"}
BENCH_COLUMN_M = 0.5  # control.desired_depth_m of configs/profiles/bench.yaml (tests check they agree)
_SAMPLE_PX = 8  # grid step (px) of the sample the weakest map's median is taken on: display only


def mask_funnel(pixels: int, counts: tuple[int, ...], threshold: float, best_score: float | None, side_m: float,
                column_m: float | None, depth_m: float | None, view_m: tuple[float, float] | None) -> MaskFunnel:
    """A MaskFunnel from the raw counts of each step, made non-increasing: the threshold is counted on the
    score as scored, the footprint on the score as filtered (smoothed), so a smoothed pixel may pass the
    second and not the first; it is counted once, where it was lost."""
    left: list[int] = []
    for c in counts:
        left.append(min(int(c), left[-1]) if left else int(c))
    return MaskFunnel(pixels, tuple(left), threshold, best_score, side_m, column_m, depth_m, view_m)


class ClusterRow(TypedDict):
    points: int
    failed: str | None   # the first test it failed (None: it qualifies)


class FrameRow(TypedDict, total=False):
    """A frame's row in run.json ``funnel.frames`` (``mask_px`` ... ``emptied_by`` only with mask counts,
    ``weakest_map`` only when the threshold emptied the mask, ``note`` only when no selection ran, ``cells`` only
    from a method with a verdict per cell: ``fusion/funnel.py``)."""

    frame: int
    mask_px: dict[str, int]
    best_score: float | None
    emptied_by: str | None
    weakest_map: dict[str, object]
    map_points: dict[str, int] | None
    clusters: list[ClusterRow]
    site: dict[str, object] | None
    note: str
    cells: dict[str, int]


class FunnelDoc(TypedDict):
    """run.json ``funnel``."""

    steps: tuple[str, ...]
    mask_px: dict[str, int]
    frames_emptied_by: dict[str, int]
    map_points: dict[str, int]
    clusters: int
    clusters_failed: dict[str, int]
    frames: list[FrameRow]


@dataclass(frozen=True)
class FrameFunnel:
    """One detection frame's funnel: the mask steps, then the map points, clusters and site."""

    frame: int
    mask: MaskFunnel | None                      # None: px4slp (its grid has its own steps, docs/PX4SLP.md)
    points: tuple[int, int, int] | None = None   # map points of the keyframe, in the view, on the mask
    clusters: tuple[tuple[int, str], ...] = ()   # per cluster: points, first test failed ("" = qualifies)
    site: tuple[bool, str] | None = None         # the site's acceptance test: passed, reason
    weakest: tuple[str, float, float] | None = None  # the lowest map's name and median, the median slope (deg)
    note: str = ""                               # why no selection ran (no pose, no map points, not vouched)
    raised: str = ""                             # the largest cluster refused as raised: its reason
    cells: dict[str, int] | None = None          # a verdict per cell (fused): the cells each of its tests left

    def as_dict(self) -> FrameRow:
        """The frame's row in run.json ``funnel.frames``."""
        m = self.mask
        out: FrameRow = {"frame": self.frame}
        if m is not None:
            out["mask_px"] = dict(zip(MASK_STEPS, m.left, strict=True))
            out["best_score"] = None if m.best_score is None else round(m.best_score, 4)
            out["emptied_by"] = m.emptied_by()
        if self.weakest is not None:
            out["weakest_map"] = {"name": self.weakest[0], "median": round(self.weakest[1], 4),
                                  "median_slope_deg": _round(self.weakest[2], 2)}
        out["map_points"] = None if self.points is None else dict(zip(("keyframe", "in_view", "on_mask"),
                                                                      self.points, strict=True))
        out["clusters"] = [{"points": p, "failed": t or None} for p, t in self.clusters]
        out["site"] = None if self.site is None else {"accepted": self.site[0], "reason": self.site[1]}
        if self.note:
            out["note"] = self.note
        if self.cells is not None:
            out["cells"] = dict(self.cells)
        return out


def frame_funnel(det: Detection) -> FrameFunnel:
    """The funnel of a ``types.Detection`` (its ScoreMap's mask counts, its selection)."""
    mask: MaskFunnel | None = det.score.funnel
    weakest = None
    if mask is not None and mask.left[1] == 0 and mask.left[0] > 0:   # the threshold emptied it: which map
        weakest = weakest_map(det.maps)
    sel = det.selection
    if sel is None:
        note = ("no pose (SLAM lost)" if det.T_world_camera is None else
                "no map points yet (no keyframe in this map segment)" if det.points is None else
                "the frame cannot vouch (noise limits): no selection")
        return FrameFunnel(det.frame.index, mask, None, (), None, weakest, note, cells=det.cells)
    n = int(sel.kept.shape[0])
    on_mask = int(np.count_nonzero(sel.kept))
    clusters = tuple((c.points, c.test) for c in sel.candidates)
    site = None if sel.site is None else (sel.site.accepted, sel.site.acceptance_reason)
    raised = [c for c in sel.candidates if c.test == "raised"]
    lead = max(raised, key=lambda c: c.points).reason if raised else ""
    return FrameFunnel(det.frame.index, mask, (n, int(sel.in_view), on_mask), clusters, site, weakest, raised=lead,
                       cells=det.cells)


def weakest_map(maps: TerrainMaps) -> tuple[str, float, float] | None:
    """The terrain map with the lowest median over the pixels with depth (on a coarse grid), and the
    median slope (deg): which cue kept the score below the threshold."""
    valid = maps.valid[::_SAMPLE_PX, ::_SAMPLE_PX]
    if not valid.any():
        return None
    medians = {name: float(np.median(values[::_SAMPLE_PX, ::_SAMPLE_PX][valid]))
               for name, values in maps.as_dict().items()}
    name = min(medians, key=lambda k: medians[k])
    slope = maps.slope_deg[::_SAMPLE_PX, ::_SAMPLE_PX][valid]
    slope = slope[np.isfinite(slope)]
    return name, medians[name], float(np.median(slope)) if slope.size else math.nan


@dataclass
class FunnelLog:
    """The funnels of a run's detection frames: one small row each, and the sums the reason needs."""

    rows: list[FrameFunnel] = field(default_factory=list)

    def add(self, f: FrameFunnel) -> None:
        self.rows.append(f)

    def mask_always_empty(self) -> bool:
        """Every detection frame with mask counts had an empty mask (and there was one)."""
        masks = [f.mask for f in self.rows if f.mask is not None]
        return bool(masks) and all(m.left[-1] == 0 for m in masks)

    def as_dict(self) -> FunnelDoc:
        """run.json ``funnel``: the per-step sums over the detection frames, and every frame's row."""
        masks = [f.mask for f in self.rows if f.mask is not None]
        emptied = Counter(e for m in masks if (e := m.emptied_by()) is not None)
        failed = Counter(t for f in self.rows for _, t in f.clusters if t)
        pts = [f.points for f in self.rows if f.points is not None]
        return {
            "steps": MASK_STEPS,
            "mask_px": {s: int(sum(m.left[i] for m in masks)) for i, s in enumerate(MASK_STEPS)},
            "frames_emptied_by": {s: emptied.get(s, 0) for s in MASK_STEPS[1:]},
            "map_points": {k: int(sum(p[i] for p in pts)) for i, k in enumerate(("keyframe", "in_view", "on_mask"))},
            "clusters": sum(len(f.clusters) for f in self.rows),
            "clusters_failed": dict(failed),
            "frames": [f.as_dict() for f in self.rows],
        }

    def reason(self, unvouched_reason: str = "") -> str | None:
        """The no-site reason from the funnel (None: no frame has mask counts, e.g. px4slp)."""
        masks = [f.mask for f in self.rows if f.mask is not None]
        if not masks:
            return None
        n = len(masks)
        if self.mask_always_empty():
            return self._empty_mask_reason(masks, unvouched_reason)
        with_mask = [f for f in self.rows if f.mask is not None and f.mask.left[-1] > 0]
        px = sum(f.mask.left[-1] for f in with_mask if f.mask is not None)
        head = f"the landing mask held {px} px over {len(with_mask)} of {n} detection frames"
        selected = [f for f in with_mask if f.points is not None]
        if not selected:
            notes = Counter(f.note for f in with_mask)
            why = "; ".join(f"{k} in {v}" for k, v in notes.most_common())
            return (f"{head}, but none of them had SLAM map points to select a site from ({why}): a longer "
                    "recording over the same ground, with the SLAM tracking, gives keyframes there")
        on_mask = sum(f.points[2] for f in selected if f.points is not None)
        in_view = sum(f.points[1] for f in selected if f.points is not None)
        if on_mask == 0:
            return (f"{head}, but none of the {in_view} SLAM map points in view in those frames fell on it: "
                    "the safe ground has too little texture for map points, or too little of it was seen; more "
                    "flight over it (a longer or slower pass) gives more keyframes and points")
        failed = Counter(t for f in selected for _, t in f.clusters if t)
        clusters = sum(len(f.clusters) for f in selected)
        if clusters == 0:
            need = f"{on_mask} map points on the mask, too few to cluster (landing.min_cluster_points)"
            return f"{head}: {need}; more flight over the safe ground gives more map points"
        tests = ", ".join(f"{v} {CLUSTER_TESTS.get(k, k)}" for k, v in failed.most_common())
        raised = [f.raised for f in selected if f.raised]
        edge = ("" if not raised or NOT_TOLD in raised[-1]
                else ": a UAV that misses it by its landing error drops off an edge")
        lead = f"the best site is {raised[-1]}{edge}; " if raised else ""
        tail = ""
        if failed and failed.most_common(1)[0][0] in ("extent", "points", "normals"):
            tail = ("; the safe patches are smaller than the footprint or hold too few map points: more flight "
                    "over them adds points, a smaller uav.footprint_m needs less")
        return (f"{lead}no cluster of mask-filtered map points met the footprint in any detection frame ({head}; "
                f"{on_mask} map points on it; of {clusters} clusters: {tests}){tail}")

    def _empty_mask_reason(self, masks: list[MaskFunnel], unvouched_reason: str) -> str:
        n = len(masks)
        with_depth = [m for m in masks if m.left[0] > 0] or masks
        removed = {s: sum(m.removed()[s] for m in with_depth) for s in MASK_STEPS[1:]}
        total = sum(m.left[0] for m in with_depth)
        main = max(removed, key=lambda s: removed[s])
        emptied = Counter(e for m in with_depth if (e := m.emptied_by()) is not None)
        by = ", ".join(f"{STEP_TEXT[s]} in {c}" for s, c in emptied.most_common())
        parts = [f"the landing mask was empty in all {n} detection frames: {STEP_TEXT[main]} removed the most "
                 f"({removed[main] / max(total, 1):.0%} of the {total} px with depth; the step that emptied it: "
                 f"{by or 'none, no pixel had depth'})"]
        steps = [main, *(s for s, _ in emptied.most_common() if s != main)]
        parts += [_what_would_change(s, with_depth, self.rows, unvouched_reason) for s in steps]
        envelope = _envelope(with_depth)
        if envelope:
            parts.append(envelope)
        return "; ".join(parts)


def _what_would_change(step: str, masks: list[MaskFunnel], rows: list[FrameFunnel], unvouched_reason: str) -> str:
    m = masks[0]
    if step == "threshold":
        bests = [x.best_score for x in masks if x.best_score is not None]
        text = f"no pixel scored above {m.threshold:g} in {len(bests)} of {len(masks)} frames"
        if bests:
            text += f" (best there {max(bests):.2f})"
        weak = Counter(f.weakest[0] for f in rows if f.weakest is not None)
        if weak:
            name = weak.most_common(1)[0][0]
            vals = [f.weakest for f in rows if f.weakest is not None and f.weakest[0] == name]
            med = float(np.median([v[1] for v in vals]))
            text += f"; the lowest of the four maps is {name} (median {med:.2f})"
            slopes = [v[2] for v in vals if math.isfinite(v[2])]
            if name == "steepness" and slopes:
                text += (f": the surfaces in view slope a median {float(np.median(slopes)):.0f} deg against gravity "
                         "as slz takes it; if the camera does not look straight down, give its tilt (camera.mount)")
        return text
    if step == "footprint":
        above = sum(x.left[1] for x in masks)
        kept = sum(x.left[2] for x in masks) / max(above, 1)
        text = (f"the whole {m.side_m:.2f} m footprint square (uav.footprint_m x mask.margin_factor + the clearance "
                f"on each side) scored above the threshold around {kept:.0%} of the pixels that did")
        views = [x.view_m for x in masks if x.view_m is not None]
        if views:
            w = float(np.median([v[0] for v in views]))
            h = float(np.median([v[1] for v in views]))
            text += f" (the view spans ~{w:.1f} x {h:.1f} m at its median depth)"
        return text + ": a higher frame sees more ground around each point, a smaller uav.footprint_m needs less"
    if step == "column":
        col = m.column_m if m.column_m is not None else float("nan")
        return (f"the final descent's column (control.desired_depth_m {col:g} m above the ground) was out of view: "
                "close to the ground the view is too narrow to see what may overhang a site, a higher frame sees "
                "more")
    return unvouched_reason or ("the ground lay beyond the depth up to which the noise limits vouch for a site "
                                "(run.json summary.depth_noise): a lower frame sees it with less noise")


def _envelope(masks: list[MaskFunnel]) -> str:
    """A note when the camera was closer to the scene than the final descent's hover: out of the UAV's envelope."""
    depths = [m.depth_m for m in masks if m.depth_m is not None]
    col = masks[0].column_m
    if not depths or col is None or float(np.median(depths)) >= col:
        return ""
    text = (f"the camera was {min(depths):.1f}-{max(depths):.1f} m from the scene (median depth per frame), closer "
            f"than the final descent's hover (control.desired_depth_m {col:g} m): outside this UAV's envelope")
    if col > BENCH_COLUMN_M:
        text += "; for a hand-held or bench recording use --profile bench (a 0.2 m footprint and a 0.5 m column)"
    return text


def _round(v: float, digits: int) -> float | None:
    return round(v, digits) if math.isfinite(v) else None
