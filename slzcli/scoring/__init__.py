"""Scoring stage: TerrainMaps -> landing score -> ScoreMap (score + landing mask).

``SCORERS`` maps a map-scoring method's name to its scorer class; ``get_scorer(config.scoring,
config.mask)`` builds one. A scorer maps the four terrain maps to a float32 score in [0, 1] (1 = good
for landing) and carries the threshold its score is cut at; pixels without depth (``valid`` False)
score 0. ``score_frame`` adds the landing mask, which reads what ``MaskParams`` holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from slzcli.config import Config, MaskCfg, ScoringCfg, UavCfg
from slzcli.errors import ConfigError
from slzcli.funnel import MaskFunnel, mask_funnel
from slzcli.geometry import valid_depth
from slzcli.scoring import bayes, closed_form, fuzzy, lut
from slzcli.scoring.mask import camera_points, column_in_view, landing_mask
from slzcli.scoring.rules import RuleBase, did_you_mean, load_rules
from slzcli.terrain.geometry import block_depth, fit_intrinsics, median_depth_m
from slzcli.types import Intrinsics, ScoreMap, TerrainMaps, Working


def _zero_invalid(score: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    if valid is not None:
        score[~np.asarray(valid, bool)] = 0.0
    return score


CompiledEvaluator = closed_form.ClosedFormFuzzy | lut.CompiledFuzzy


def compile_fuzzy(rules: RuleBase, levels: int) -> CompiledEvaluator:
    """``evaluator: compiled``: the closed form (exact, fast) when the output terms the rules use
    meet only edge to edge (``closed_form.output_plan``), else the simplex table of ``levels``
    nodes per input (1-4 inputs, max error ~0.005-0.01)."""
    return closed_form.compile_rules(rules) or lut.compile_rules(rules, levels)


@dataclass(frozen=True, eq=False)
class FuzzyScorer:
    """Mamdani score (METHOD 2.4), by the compiled evaluator (default) or the exact engine."""

    rules: RuleBase
    evaluator: str
    threshold: float  # mask.threshold: a pixel above it may be safe
    compiled: CompiledEvaluator | None = field(default=None)
    name: str = "fuzzy"

    @classmethod
    def from_config(cls, scoring: ScoringCfg, mask: MaskCfg) -> FuzzyScorer:
        cfg = scoring.fuzzy
        rules = load_rules(cfg.rules)
        unknown = [name for name in rules.input_names if name not in TerrainMaps.NAMES]
        if unknown:
            raise ConfigError("inputs", f"unknown input map {unknown[0]!r}; the inputs are "
                              f"{', '.join(TerrainMaps.NAMES)}{did_you_mean(unknown[0], TerrainMaps.NAMES)}",
                              rules.source)
        compiled = compile_fuzzy(rules, cfg.lut_levels) if cfg.evaluator == "compiled" else None
        return cls(rules, cfg.evaluator, mask.threshold, compiled)

    def score_arrays(self, inputs: dict[str, np.ndarray], valid: np.ndarray | None = None) -> np.ndarray:
        """Score of the named input maps (the rules file's input names), float32 in [0, 1]."""
        xs = [np.asarray(inputs[name], np.float32) for name in self.rules.input_names]
        if self.compiled is not None:
            score = self.compiled(xs)
        else:
            shape = xs[0].shape
            flat = np.stack([x.ravel() for x in xs])
            score = fuzzy.evaluate_exact(self.rules, flat).astype(np.float32).reshape(shape)
        return _zero_invalid(score, valid)

    def __call__(self, maps: TerrainMaps) -> np.ndarray:
        return score_maps(self, maps)


@dataclass(frozen=True, eq=False)
class BayesScorer:
    """Naive Bayes fusion of the four maps (BASELINE.md)."""

    prior: float
    eps: float
    threshold: float  # scoring.bayes.threshold: a posterior above it may be safe
    name: str = "bayes"

    @classmethod
    def from_config(cls, scoring: ScoringCfg, mask: MaskCfg) -> BayesScorer:
        """``mask`` is not read (the posterior has its own threshold): the signature every scorer shares."""
        return cls(scoring.bayes.prior, scoring.bayes.eps, scoring.bayes.threshold)

    def score_arrays(self, inputs: dict[str, np.ndarray], valid: np.ndarray | None = None) -> np.ndarray:
        score = bayes.fuse([inputs[name] for name in TerrainMaps.NAMES], self.prior, self.eps)
        return _zero_invalid(score, valid)

    def __call__(self, maps: TerrainMaps) -> np.ndarray:
        return score_maps(self, maps)


Scorer = FuzzyScorer | BayesScorer


def score_maps(scorer: Scorer, maps: TerrainMaps) -> np.ndarray:
    """The score of a frame's maps at full resolution: scored on their block grid when they have one
    (``TerrainMaps.grid``), then upsampled (bilinear) and 0 where the maps are (the pixel, or its
    nearest block, has no depth)."""
    if maps.grid is None:
        return scorer.score_arrays(maps.as_dict(), maps.valid)
    on_grid = scorer.score_arrays(maps.grid.maps, maps.grid.valid)
    h, w = maps.valid.shape
    score = cv2.resize(on_grid, (w, h), interpolation=cv2.INTER_LINEAR)
    known = cv2.resize(maps.grid.valid.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)
    return _zero_invalid(score, known & maps.valid)

SCORERS: dict[str, type[FuzzyScorer] | type[BayesScorer]] = {"fuzzy": FuzzyScorer, "bayes": BayesScorer}
# the scorers of the four maps; the detection methods (these two and px4slp) are slzcli.methods.registry's


def get_scorer(scoring: ScoringCfg, mask: MaskCfg, method: str | None = None) -> Scorer:
    """The scorer for ``scoring.method`` (or ``method``, e.g. for ``slz compare``), cutting at its threshold."""
    name = method or scoring.method
    if name not in SCORERS:
        raise ConfigError("scoring.method", f"{name!r} does not score the four terrain maps (scorers: "
                                            f"{', '.join(SCORERS)}); run it through slz detect or slz compare")
    return SCORERS[name].from_config(scoring, mask)


@dataclass(frozen=True)
class MaskParams:
    """What the landing mask reads: the ``mask`` section, the UAV's footprint and clearance (``uav``) and the
    hover height above the site the final descent starts from (``control.desired_depth_m``)."""

    mask: MaskCfg
    uav: UavCfg
    desired_depth_m: float

    @classmethod
    def of(cls, config: Config) -> MaskParams:
        return cls(config.mask, config.uav, config.control.desired_depth_m)


def score_frame(scorer: Scorer, maps: TerrainMaps, depth_m: np.ndarray, intrinsics: Intrinsics,
                params: MaskParams) -> ScoreMap:
    """Score the maps and make the landing mask (min filter of the UAV footprint, then threshold)."""
    return mask_score(scorer, scorer(maps), depth_m, intrinsics, params, maps.work, maps.up_camera)


def mask_score(scorer: Scorer, score: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics,
               params: MaskParams, work: Working | None = None, up_camera: np.ndarray | None = None) -> ScoreMap:
    """The landing mask of a score already computed (so the pipeline can time the two apart).

    ``work``: the maps' working scale; nothing is called safe where its noise limits fail (the
    whole frame when it cannot vouch, else the pixels beyond its ``vouch_depth_m``).
    ``up_camera``: world up in the camera frame, for ``mask.clearance: plan`` (without it: image).
    The plan-view filter runs on m x m block means of score and depth (``mask.plan_samples_per_cell``),
    its mask upsampled (nearest) and cut to the pixels with depth. The ScoreMap's ``funnel`` counts the
    pixels each step left (``slzcli.funnel``).
    """
    depth = np.asarray(depth_m)
    mc = params.mask
    threshold = scorer.threshold
    above = int(np.count_nonzero(np.greater(score, threshold)))  # the funnel's count, while the score is in cache
    valid = valid_depth(depth)
    if mc.clearance == "plan" and up_camera is not None:
        m = plan_block_px(depth, intrinsics, params)
        if m > 1:
            depth_b, _ = block_depth(depth, valid, m)
            score_b = cv2.resize(np.asarray(score, np.float32), depth_b.shape[::-1], interpolation=cv2.INTER_AREA)
            sm, before_b = _mask(scorer, score_b, depth_b, fit_intrinsics(intrinsics, depth_b.shape), params,
                                 up_camera)
            mask, footprint = _upsampled(sm.mask, before_b, valid)
            sm = ScoreMap(sm.method, score, mask, sm.column_cut)
        else:
            sm, before = _mask(scorer, score, depth, intrinsics, params, up_camera)
            footprint = None if before is None else int(np.count_nonzero(before))
    else:
        sm, _ = _mask(scorer, score, depth, intrinsics, params, None)
        footprint = None
    column = int(np.count_nonzero(sm.mask))
    if work is not None and not work.vouched:
        sm = ScoreMap(sm.method, sm.score, np.zeros_like(sm.mask), sm.column_cut)
    elif work is not None and math.isfinite(work.vouch_depth_m):
        with np.errstate(invalid="ignore"):
            np.logical_and(sm.mask, depth <= work.vouch_depth_m, out=sm.mask)
    plan = mc.clearance == "plan" and up_camera is not None
    return replace(sm, funnel=_funnel(score, depth, valid, threshold, above, footprint, column, sm.mask, intrinsics,
                                      params, plan, work))


def _upsampled(mask_b: np.ndarray, before_b: np.ndarray | None, valid: np.ndarray) -> tuple[np.ndarray, int | None]:
    """A block-grid mask at the full resolution (nearest), cut to the pixels with depth, and the full-resolution
    pixels of ``before_b`` (the mask before the column rule, a superset; None: no count): one resize of both."""
    h, w = valid.shape
    if before_b is None:
        mask = cv2.resize(mask_b.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)
        np.logical_and(mask, valid, out=mask)
        return mask, None
    up = cv2.resize(mask_b.view(np.uint8) + before_b.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    np.multiply(up, valid, out=up)      # 2: in the mask, 1: only before the column rule, 0: neither or no depth
    before = int(np.count_nonzero(up))
    mask = up.view(bool)
    np.equal(up, 2, out=mask)           # in place: no new full-size array (their page faults cost more)
    return mask, before


def _funnel(score: np.ndarray, depth: np.ndarray, valid: np.ndarray, threshold: float, above: int,
            footprint: int | None, column: int, final: np.ndarray, intrinsics: Intrinsics, params: MaskParams,
            plan: bool, work: Working | None) -> MaskFunnel:
    """The pixels each mask step left (``slzcli.funnel``). ``footprint`` None: no column rule ran, so the
    footprint step left what the column step did; ``above``: the pixels whose score is above the threshold.
    The score is 0 where there is no depth: its maximum and the pixels above the threshold are those of the
    pixels with depth; the maximum is taken only when no pixel is above (what the no-site reason quotes).
    The median depth is the working scale's (the same median), measured here only without one."""
    depth_px = int(np.count_nonzero(valid))
    best = float(np.max(score)) if above == 0 and score.size else None   # what the reason needs: below it
    uav = params.uav
    side = params.mask.margin_factor * max(uav.footprint_m) + 2.0 * uav.clearance_m
    d = work.altitude_m if work is not None else median_depth_m(depth)
    view = None if d is None else (intrinsics.width * d / intrinsics.fx, intrinsics.height * d / intrinsics.fy)
    counts = (depth_px, above, column if footprint is None else footprint, column, int(np.count_nonzero(final)))
    return mask_funnel(valid.size, counts, threshold, best, side, params.desired_depth_m if plan else None,
                       d, view)


def plan_block_px(depth_m: np.ndarray, intrinsics: Intrinsics, params: MaskParams) -> int:
    """The block side m (px) the plan-view filter runs on: the coarsest that still puts
    ``mask.plan_samples_per_cell`` samples across a plan cell at the frame's median depth (0: every pixel).

    The cell is the bare footprint's (without the clearance margins, which only make the raster's cells
    larger): so m does not move with ``uav.margin_m`` or the touch-down dispersion, and a larger
    clearance gives a mask inside the smaller one's, on the same samples.
    """
    mc = params.mask
    depth = median_depth_m(depth_m)
    if depth is None or mc.plan_samples_per_cell <= 0:
        return 1
    cell_m = mc.margin_factor * max(params.uav.footprint_m) / mc.plan_cells_per_footprint
    px_m = depth / (0.5 * (intrinsics.fx + intrinsics.fy))
    return max(1, math.floor(cell_m / (mc.plan_samples_per_cell * px_m)))


def _mask(scorer: Scorer, score: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics, params: MaskParams,
          up_camera: np.ndarray | None) -> tuple[ScoreMap, np.ndarray | None]:
    """Footprint filter, threshold and column rule of a score and the depth image it is on; and the mask
    before the column rule (None: the rule did not run)."""
    mc = params.mask
    plan = points = None
    if mc.clearance == "plan" and up_camera is not None:
        plan = (fit_intrinsics(intrinsics, depth_m.shape), up_camera, mc.plan_cells_per_footprint)
        points = camera_points(depth_m, plan[0])          # once, for the plan filter and the column
    sm = landing_mask(scorer.name, score, depth_m, intrinsics.fx, intrinsics.fy, params.uav.footprint_m,
                      mc.margin_factor, scorer.threshold, mc.smooth_m, plan=plan,
                      margin_m=params.uav.clearance_m, points=points)
    if plan is None:
        return sm, None
    # the final descent's column must have been in view (control.desired_depth_m hover)
    footprint = sm.mask.copy()
    before = int(np.count_nonzero(footprint))
    np.logical_and(sm.mask, column_in_view(depth_m, plan[0], plan[1], params.desired_depth_m,
                                           points=points, among=sm.mask), out=sm.mask)
    if before:
        sm = ScoreMap(sm.method, sm.score, sm.mask, 1.0 - int(np.count_nonzero(sm.mask)) / before)
    return sm, footprint
