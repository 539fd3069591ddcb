"""Scoring stage: TerrainMaps -> landing score -> ScoreMap (score + landing mask).

``SCORERS`` maps a map-scoring method's name to its scorer class; ``get_scorer(config)`` builds one.
A scorer maps the four terrain maps to a float32 score in [0, 1] (1 = good for landing);
pixels without depth (``valid`` False) score 0. ``score_frame`` adds the landing mask.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.errors import ConfigError
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
    compiled: CompiledEvaluator | None = field(default=None)
    name: str = "fuzzy"

    @classmethod
    def from_config(cls, config: Config) -> FuzzyScorer:
        cfg = config.scoring.fuzzy
        rules = load_rules(cfg.rules)
        unknown = [name for name in rules.input_names if name not in TerrainMaps.NAMES]
        if unknown:
            raise ConfigError("inputs", f"unknown input map {unknown[0]!r}; the inputs are "
                              f"{', '.join(TerrainMaps.NAMES)}{did_you_mean(unknown[0], TerrainMaps.NAMES)}",
                              rules.source)
        compiled = compile_fuzzy(rules, cfg.lut_levels) if cfg.evaluator == "compiled" else None
        return cls(rules, cfg.evaluator, compiled)

    def threshold(self, config: Config) -> float:
        return config.mask.threshold

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
    name: str = "bayes"

    @classmethod
    def from_config(cls, config: Config) -> BayesScorer:
        return cls(config.scoring.bayes.prior, config.scoring.bayes.eps)

    def threshold(self, config: Config) -> float:
        return config.scoring.bayes.threshold

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


def get_scorer(config: Config, method: str | None = None) -> Scorer:
    """The scorer for ``scoring.method`` (or ``method``, e.g. for ``slz compare``)."""
    name = method or config.scoring.method
    if name not in SCORERS:
        raise ConfigError("scoring.method", f"{name!r} does not score the four terrain maps (scorers: "
                                            f"{', '.join(SCORERS)}); run it through slz detect or slz compare")
    return SCORERS[name].from_config(config)


def score_frame(scorer: Scorer, maps: TerrainMaps, depth_m: np.ndarray, intrinsics: Intrinsics,
                config: Config) -> ScoreMap:
    """Score the maps and make the landing mask (min filter of the UAV footprint, then threshold)."""
    return mask_score(scorer, scorer(maps), depth_m, intrinsics, config, maps.work, maps.up_camera)


def mask_score(scorer: Scorer, score: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics,
               config: Config, work: Working | None = None, up_camera: np.ndarray | None = None) -> ScoreMap:
    """The landing mask of a score already computed (so the pipeline can time the two apart).

    ``work``: the maps' working scale; nothing is called safe where its noise limits fail (the
    whole frame when it cannot vouch, else the pixels beyond its ``vouch_depth_m``).
    ``up_camera``: world up in the camera frame, for ``mask.clearance: plan`` (without it: image).
    The plan-view filter runs on m x m block means of score and depth (``mask.plan_samples_per_cell``),
    its mask upsampled (nearest) and cut to the pixels with depth.
    """
    depth = np.asarray(depth_m)
    mc = config.mask
    if mc.clearance == "plan" and up_camera is not None:
        m = plan_block_px(depth, intrinsics, config)
        if m > 1:
            h, w = depth.shape
            valid = valid_depth(depth)
            depth_b, _ = block_depth(depth, valid, m)
            score_b = cv2.resize(np.asarray(score, np.float32), depth_b.shape[::-1], interpolation=cv2.INTER_AREA)
            sm = _mask(scorer, score_b, depth_b, fit_intrinsics(intrinsics, depth_b.shape), config, up_camera)
            mask = cv2.resize(sm.mask.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)
            np.logical_and(mask, valid, out=mask)
            sm = ScoreMap(sm.method, score, mask, sm.column_cut)
        else:
            sm = _mask(scorer, score, depth, intrinsics, config, up_camera)
    else:
        sm = _mask(scorer, score, depth, intrinsics, config, None)
    if work is None:
        return sm
    if not work.vouched:
        return ScoreMap(sm.method, sm.score, np.zeros_like(sm.mask), sm.column_cut)
    if math.isfinite(work.vouch_depth_m):
        with np.errstate(invalid="ignore"):
            np.logical_and(sm.mask, depth <= work.vouch_depth_m, out=sm.mask)
    return sm


def plan_block_px(depth_m: np.ndarray, intrinsics: Intrinsics, config: Config) -> int:
    """The block side m (px) the plan-view filter runs on: the coarsest that still puts
    ``mask.plan_samples_per_cell`` samples across a plan cell at the frame's median depth (0: every pixel).

    The cell is the bare footprint's (without the clearance margins, which only make the raster's cells
    larger): so m does not move with ``uav.margin_m`` or the touch-down dispersion, and a larger
    clearance gives a mask inside the smaller one's, on the same samples.
    """
    mc = config.mask
    depth = median_depth_m(depth_m)
    if depth is None or mc.plan_samples_per_cell <= 0:
        return 1
    cell_m = mc.margin_factor * max(config.uav.footprint_m) / mc.plan_cells_per_footprint
    px_m = depth / (0.5 * (intrinsics.fx + intrinsics.fy))
    return max(1, math.floor(cell_m / (mc.plan_samples_per_cell * px_m)))


def _mask(scorer: Scorer, score: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics, config: Config,
          up_camera: np.ndarray | None) -> ScoreMap:
    """Footprint filter, threshold and column rule of a score and the depth image it is on."""
    mc = config.mask
    plan = points = None
    if mc.clearance == "plan" and up_camera is not None:
        plan = (fit_intrinsics(intrinsics, depth_m.shape), up_camera, mc.plan_cells_per_footprint)
        points = camera_points(depth_m, plan[0])          # once, for the plan filter and the column
    sm = landing_mask(scorer.name, score, depth_m, intrinsics.fx, intrinsics.fy, config.uav.footprint_m,
                      mc.margin_factor, scorer.threshold(config), mc.smooth_m, plan=plan,
                      margin_m=config.uav.clearance_m, points=points)
    if plan is not None:   # the final descent's column must have been in view (control.desired_depth_m hover)
        before = int(sm.mask.sum())
        np.logical_and(sm.mask, column_in_view(depth_m, plan[0], plan[1], config.control.desired_depth_m,
                                               points=points, among=sm.mask), out=sm.mask)
        if before:
            sm = ScoreMap(sm.method, sm.score, sm.mask, 1.0 - int(sm.mask.sum()) / before)
    return sm
