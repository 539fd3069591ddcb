"""Scoring: the Mamdani engine (vs scikit-fuzzy), the compiled table, the shipped rule base's
properties, rule parse errors, the Bayes baseline and the landing mask."""

from __future__ import annotations

import itertools
import re
from typing import Any

import numpy as np
import pytest
import yaml
from skfuzzy_oracle import skfuzzy_simulation

from slzcli.config import load_config
from slzcli.errors import ConfigError
from slzcli.scoring import (
    SCORERS,
    BayesScorer,
    FuzzyScorer,
    MaskParams,
    bayes,
    closed_form,
    compile_fuzzy,
    fuzzy,
    get_scorer,
    lut,
    score_frame,
)
from slzcli.scoring.mask import landing_mask, median_depth_m, window_px
from slzcli.scoring.rules import And, Not, Or, RuleBase, load_rules, parse_rule_base, resolve_rules_path
from slzcli.types import Intrinsics, ScoreMap, TerrainMaps


@pytest.fixture(scope="module")
def rb() -> RuleBase:
    return load_rules("fuzzy_rules.yaml")


@pytest.fixture(scope="module")
def rules_data() -> Any:
    return yaml.safe_load(resolve_rules_path("fuzzy_rules.yaml").read_text())


def _breakpoint_points(n: int) -> np.ndarray:
    """Every combination of the membership breakpoints and crossings (0, .25, .5, .75, 1) and
    points just either side of them: where min/max kinks and the table's cell edges are."""
    vals = [0.0, 0.25, 0.5, 0.75, 1.0, 0.5 - 1e-4, 0.5 + 1e-4, 0.25 + 1e-3, 0.75 - 1e-3]
    return np.array(list(itertools.product(vals, repeat=n))).T


# ----------------------------------------------------------------------------- exact vs scikit-fuzzy


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_exact_equals_scikit_fuzzy(rb):
    """Our exact evaluator is the exact piecewise-linear centroid; scikit-fuzzy integrates the
    same piecewise-linear aggregate (sampled at its universe + the cut points), so on the
    shipped rule base the two agree to rounding: asserted within 1e-6 on 2000 random inputs
    plus the breakpoint grid (a discrete 101-point centroid would differ by up to ~0.006)."""
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.random((4, 2000)), _breakpoint_points(4)[:, ::7]], axis=1)
    sim = skfuzzy_simulation(rb)
    for v, row in zip(rb.inputs, x, strict=True):
        sim.input[v.name] = row
    sim.compute()
    ours = fuzzy.evaluate_exact(rb, x)
    assert np.max(np.abs(np.asarray(sim.output[rb.output.name]) - ours)) < 1e-6


def test_exact_centroid_matches_fine_numeric_integration(rb):
    """The centroid is exact also where clipped terms cross (an overlapping output partition)."""
    data = yaml.safe_load(resolve_rules_path("fuzzy_rules.yaml").read_text())
    data["rules"] = ["if flatness is medium then score is low", "if flatness is high then score is medium_low",
                     "if steepness is high then score is very_high", "if steepness is low then score is high"]
    rb2 = parse_rule_base(data)
    rng = np.random.default_rng(1)
    x = rng.random((4, 60))
    act = fuzzy.activations(rb2, x)
    y = np.linspace(0, 1, 200001)
    agg = np.zeros((x.shape[1], y.size))
    for a, fn in zip(act, rb2.output.terms, strict=True):
        np.maximum(agg, np.minimum(a[:, None], fn(y)[None, :]), out=agg)
    numeric = np.trapezoid(agg * y, y, axis=1) / np.trapezoid(agg, y, axis=1)
    assert np.max(np.abs(fuzzy.evaluate_exact(rb2, x) - numeric)) < 1e-8


# ----------------------------------------------------------------------------- compiled evaluators
def _random_and_kinks(n: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.random((n, 100_000)), _breakpoint_points(n)], axis=1).astype(np.float32)


def test_compiled_default_is_the_exact_closed_form(rb):
    """The scorer's compiled evaluator for the shipped rules is the closed form: max |compiled -
    exact| <= 1e-5 on 100k random inputs plus the kink grid (measured 1.3e-7: float32 rounding)."""
    config = load_config()
    scorer = get_scorer(config.scoring, config.mask)
    assert isinstance(scorer, FuzzyScorer)
    assert isinstance(scorer.compiled, closed_form.ClosedFormFuzzy)
    x = _random_and_kinks(4)
    exact = fuzzy.evaluate_exact(rb, x.astype(np.float64))
    assert np.max(np.abs(scorer.compiled(list(x)) - exact)) <= 1e-5
    # outside the universe the inputs are clipped, NaN gives the universe minimum, as in the exact
    # engine (where the score depends on that input at all: a constant score stays constant)
    odd = np.array([[-0.5, 1.5, np.nan, 0.3], [0.7, 2.0, 0.5, np.nan], [1.2, -1.0, 0.9, 0.8], [0.9, 0.9, 0.9, 0.9]])
    assert np.allclose(scorer.compiled(list(odd.astype(np.float32))), fuzzy.evaluate_exact(rb, odd), atol=1e-5)
    assert scorer.compiled(list(odd.astype(np.float32)))[2] == 0.0


def test_simplex_table_within_stated_bound(rb):
    """The general fallback: max |table - exact| <= 0.01 on 100k random inputs plus the kink grid
    (measured 0.0054 at the default 13 levels; see lut.py for why area/moment tables and mirrored simplices)."""
    table = lut.compile_rules(rb, load_config().scoring.fuzzy.lut_levels)
    x = _random_and_kinks(4)
    exact = fuzzy.evaluate_exact(rb, x.astype(np.float64))
    err = np.max(np.abs(table(list(x)) - exact))
    assert err <= 0.01
    assert table.max_error <= 0.01


@pytest.mark.parametrize("kind", ["closed_form", "table"])
def test_compiled_on_an_image_and_cached(rb, kind):
    table = closed_form.compile_rules(rb) if kind == "closed_form" else lut.compile_rules(rb, 13)
    again = closed_form.compile_rules(rb) if kind == "closed_form" else lut.compile_rules(rb, 13)
    assert table is not None and again is table  # in-memory cache by rules digest (and levels)
    rng = np.random.default_rng(4)
    imgs = [rng.random((48, 64)).astype(np.float32) for _ in range(4)]
    out = table(imgs)
    assert out.shape == (48, 64) and out.dtype == np.float32
    exact = fuzzy.evaluate_exact(rb, np.stack([i.ravel() for i in imgs])).reshape(48, 64)
    assert np.max(np.abs(out - exact)) <= (1e-5 if kind == "closed_form" else 0.01)


def test_closed_form_chunks_join_seamlessly(rb, monkeypatch):
    prog = closed_form.compile_rules(rb)
    assert prog is not None
    rng = np.random.default_rng(6)
    imgs = [rng.random((50, 51)).astype(np.float32) for _ in range(4)]  # 2550 px
    whole = prog(imgs)
    monkeypatch.setattr(closed_form, "CHUNK_PX", 1000)  # 3 chunks, the last one short
    assert np.array_equal(prog(imgs), whole)


def test_closed_form_program_shares_work(rb):
    """The compiler shares the rules' common parts, gathers NOTs (De Morgan) and computes each
    membership in 2 ops from the raw input: the shipped rules need 51 array ops (29 up to the
    activations) in 8 buffers; evaluated as written they need ~75."""
    prog = closed_form.compile_rules(rb)
    assert prog is not None
    ops = [ins[0] for ins in prog.program]
    assert len(ops) <= 51 and prog.n_registers <= 8
    assert ops.count("not") <= 3  # 8 distinct NOT leaves in the text
    assert ops.count("clip") == 8  # the 8 memberships used: affine + clip each


_GENERAL_RULES = {
    "inputs": {
        "a": {"universe": [0.0, 1.0], "terms": {"low": {"trapezoid": [0.0, 0.0, 0.2, 0.6]},
                                                "mid": {"triangle": [0.1, 0.4, 0.9]},
                                                "high": {"trapezoid": [0.5, 0.7, 1.0, 1.0]},
                                                "band": {"trapezoid": [0.3, 0.3, 0.8, 0.8]}}},  # steps inside
        "b": {"universe": [-2.0, 3.0], "terms": {"neg": {"triangle": [-2.0, -2.0, 0.5]},
                                                 "pos": {"trapezoid": [0.0, 1.0, 2.0, 4.0]},
                                                 "wide": {"triangle": [-3.0, 0.0, 5.0]}}},
        "c": {"universe": [0.0, 10.0], "terms": {"lo": {"triangle": [0, 0, 5]}, "hi": {"triangle": [5, 10, 10]}}},
        "d": {"universe": [0.0, 1.0], "terms": {"lo": {"triangle": [0, 0, 1]}, "hi": {"triangle": [0, 1, 1]}}},
        "e": {"universe": [0.0, 1.0], "terms": {"lo": {"triangle": [0, 0, 1]}, "hi": {"triangle": [0, 1, 1]}}},
    },
    "output": {"y": {"universe": [-1.0, 2.0], "terms": {
        "bad": {"trapezoid": [-1.0, -1.0, -0.6, 0.0]}, "meh": {"triangle": [-0.2, 0.1, 0.9]},
        "ok": {"trapezoid": [0.8, 1.2, 1.3, 1.6]}, "great": {"triangle": [1.5, 2.0, 2.0]},
        "unused": {"triangle": [0.0, 1.0, 2.0]}}}},
    "rules": [
        "if a is low or b is neg then y is bad",
        "if not (a is low or b is neg) and c is not hi then y is meh",
        "if a is band and b is pos and (c is hi or d is hi) then y is ok",
        "if a is high and b is wide and not not e is hi then y is great",
        "if a is mid and e is lo then y is meh",
        "if d is lo and e is lo and c is lo then y is bad",
    ]}


def test_closed_form_is_general():
    """Any premises, 5 inputs, trapezoids, steps, other universes, overlapping asymmetric output
    terms (bad/meh, meh/ok, ok/great), inputs outside the universes, NaN, and points where no rule
    fires: max |closed form - exact| <= 1e-5 on 100k points (measured 2.5e-6)."""
    rb2 = parse_rule_base(_GENERAL_RULES)
    overlaps, _ = closed_form.output_plan(rb2)
    assert overlaps is not None and len(overlaps) == 3
    prog = closed_form.build(rb2)
    assert prog is not None
    rng = np.random.default_rng(0)
    lo, hi = np.array([-0.2, -2.5, -1, 0, 0])[:, None], np.array([1.2, 3.5, 11, 1, 1])[:, None]
    x = lo + rng.random((5, 100_000)) * (hi - lo)
    x[0, :10] = np.nan
    x[:, 10] = [0.95, 1.0, 10.0, 0.5, 0.0]  # no rule fires here
    assert fuzzy.activations(rb2, x[:, 10:11]).max() == 0
    exact = fuzzy.evaluate_exact(rb2, x)
    got = prog(list(x.astype(np.float32)))
    assert np.max(np.abs(got - exact)) <= 1e-5
    assert np.all(got[:11] == -1.0)  # NaN input or nothing fires: the output universe minimum


@pytest.mark.parametrize("rules", [
    ["if a is all then y is lo", "if a is up then y is hi"],            # a constant activation
    ["if a is all then y is lo", "if a is none then y is hi"],          # every activation constant
    ["if a is none then y is lo", "if a is not all then y is hi"],      # nothing ever fires
    ["if a is half then y is lo", "if a is hump or a is none then y is hi"],  # step; edge above 0 at the universe end
    ["if a is not half and not a is all then y is lo", "if a is half then y is hi"],
])
def test_closed_form_degenerate_memberships(rules):
    """Memberships constant on the universe, steps, edges cut by the universe: constants are folded
    into the program and the result still equals the exact engine (measured <= 1.2e-7)."""
    rb2 = parse_rule_base({
        "inputs": {"a": {"universe": [0.0, 1.0], "terms": {
            "all": {"trapezoid": [-1.0, 0.0, 1.0, 2.0]}, "none": {"triangle": [2.0, 3.0, 4.0]},
            "half": {"trapezoid": [-1.0, -1.0, 0.5, 0.5]}, "up": {"triangle": [0.0, 1.0, 1.0]},
            "hump": {"trapezoid": [-0.5, 0.5, 0.5, 1.5]}}}},
        "output": {"y": {"universe": [0.0, 1.0], "terms": {"lo": {"triangle": [0.0, 0.0, 0.5]},
                                                          "hi": {"trapezoid": [0.5, 0.6, 0.9, 1.0]}}}},
        "rules": rules})
    x = np.linspace(-0.5, 1.5, 2001)
    prog = closed_form.build(rb2)
    assert prog is not None
    got = prog([x.astype(np.float32)])
    assert np.max(np.abs(got - fuzzy.evaluate_exact(rb2, x[None]))) <= 1e-6


def test_closed_form_handles_the_full_overlapping_partition(rules_data):
    """All seven equal overlapping output triangles in use: still exact (measured 2.8e-7)."""
    rb2 = parse_rule_base(_with_rules(rules_data, [
        "if flatness is low then score is very_low",
        "if flatness is medium and steepness is low then score is low",
        "if flatness is medium then score is medium_low",
        "if steepness is medium then score is medium",
        "if steepness is high and inclination is medium then score is medium_high",
        "if steepness is high or depth_variance is high then score is high",
        "if depth_variance is high and inclination is high then score is very_high"]))
    prog = compile_fuzzy(rb2, 13)
    assert isinstance(prog, closed_form.ClosedFormFuzzy)
    x = _random_and_kinks(4)
    assert np.max(np.abs(prog(list(x)) - fuzzy.evaluate_exact(rb2, x.astype(np.float64)))) <= 1e-5


def test_other_output_layouts_fall_back_to_the_table(rules_data):
    """A term spanning others (here 'wide' over medium_low..medium_high) is outside the closed form:
    the simplex table takes over, within 0.01 (measured 0.0097) on 100k random + kink points."""
    data = _with_rules(rules_data, rules_data["rules"] + ["if inclination is medium then score is wide"])
    data["output"] = {"score": {"universe": [0.0, 1.0], "terms": dict(rules_data["output"]["score"]["terms"],
                                                                      wide={"triangle": [0.0, 0.5, 1.0]})}}
    rb2 = parse_rule_base(data)
    overlaps, reason = closed_form.output_plan(rb2)
    assert overlaps is None and "'wide'" in reason
    prog = compile_fuzzy(rb2, 13)
    assert isinstance(prog, lut.CompiledFuzzy)
    x = _random_and_kinks(4)
    assert np.max(np.abs(prog(list(x)) - fuzzy.evaluate_exact(rb2, x.astype(np.float64)))) <= 0.01


def test_mirrored_simplices_reproduce_min_kinks_exactly():
    """A table of min(1 - 2x, 2y)-type values (a kink on a cell anti-diagonal) interpolates exactly."""
    data = {"inputs": {n: {"universe": [0.0, 1.0], "terms": {"low": {"triangle": [0.0, 0.0, 0.5]},
                                                             "medium": {"triangle": [0.0, 0.5, 1.0]},
                                                             "high": {"triangle": [0.5, 1.0, 1.0]}}}
                       for n in ("a", "b")},
            "output": {"s": {"universe": [0.0, 1.0], "terms": {"lo": {"triangle": [0.0, 0.0, 0.5]},
                                                              "hi": {"triangle": [0.5, 1.0, 1.0]}}}},
            "rules": ["if a is low and b is medium then s is hi", "if a is not low or b is not medium then s is lo"]}
    rb2 = parse_rule_base(data)
    table = lut.build(rb2, 9)
    rng = np.random.default_rng(5)
    x = rng.random((2, 20000)).astype(np.float32)
    area, moment = fuzzy.evaluate_area_moment(rb2, x.astype(np.float64))
    # area and moment are piecewise quadratic in the activations; the error left is from that
    # curvature and the input quantisation, far below the 0.05+ a kink across a cell gives
    assert np.max(np.abs(table(list(x)) - moment / area)) < 0.01


# ----------------------------------------------------------------------------- rule base properties
def test_rule_base_is_complete(rb):
    rng = np.random.default_rng(11)
    x = np.concatenate([rng.random((4, 100_000)), _breakpoint_points(4)], axis=1)
    strongest = fuzzy.activations(rb, x).max(axis=0)
    assert strongest.min() > 0  # measured: >= 0.5 everywhere


def test_rule_base_is_monotone_in_every_input(rb):
    rng = np.random.default_rng(12)
    n = 50_000
    x = rng.random((4, n))
    axis = rng.integers(0, 4, n)
    cols = np.arange(n)
    y = x.copy()
    y[axis, cols] += rng.random(n) * (1 - x[axis, cols])
    small = x.copy()
    small[axis, cols] = np.minimum(1.0, small[axis, cols] + rng.random(n) * 0.01)
    sx = fuzzy.evaluate_exact(rb, x)
    assert np.all(fuzzy.evaluate_exact(rb, y) >= sx - 1e-9)
    assert np.all(fuzzy.evaluate_exact(rb, small) >= sx - 1e-9)


def test_any_low_input_vetoes(rb):
    rng = np.random.default_rng(13)
    for i in range(4):
        x = rng.random((4, 2000))
        x[i] = 0.0  # a bad cue: very_low alone (its centroid is 1/18)
        assert np.allclose(fuzzy.evaluate_exact(rb, x), 1 / 18)
        x[i] = rng.random(2000) * 0.1  # clearly bad: the good rules are capped at 0.2
        assert fuzzy.evaluate_exact(rb, x).max() < 0.34  # measured 0.323; mask.threshold is 0.5
    assert fuzzy.evaluate_exact(rb, np.ones((4, 1)))[0] > 0.9
    good_primary = np.array([[0.5], [1.0], [0.5], [1.0]])  # dv, fl, inc, st: the paper's rule
    assert fuzzy.evaluate_exact(rb, good_primary)[0] > 0.6


# ----------------------------------------------------------------------------- parsing
def _with_rules(rules_data, rules):
    data = dict(rules_data)
    data["rules"] = rules
    return data


def test_parser_precedence_and_parentheses(rules_data):
    rb2 = parse_rule_base(_with_rules(rules_data, [
        "if flatness is low or steepness is high and not depth_variance is medium then score is low",
        "if (flatness is low or steepness is high) and depth_variance is not medium then score is high"]))
    r1, r2 = rb2.rules
    assert isinstance(r1.premise, Or) and isinstance(r1.premise.args[1], And)
    assert isinstance(r2.premise, And) and isinstance(r2.premise.args[0], Or)
    assert isinstance(r2.premise.args[1], Not)
    x = np.array([[0.5], [0.0], [0.5], [1.0]])  # flatness low = 1, depth_variance medium = 1
    act = fuzzy.activations(rb2, x)
    assert act[rb2.output.term_names.index("low"), 0] == 1.0   # low or (... and ...) = max(1, 0)
    assert act[rb2.output.term_names.index("high"), 0] == 0.0  # (...) and not medium = min(1, 0)


@pytest.mark.parametrize("rule, words", [
    ("if flatnes is low then score is low", ["rule 2", "'flatnes'", "did you mean 'flatness'"]),
    ("if flatness is hihg then score is low", ["rule 2", "'hihg'", "did you mean 'high'"]),
    ("if flatness is high then score is very_hihg", ["rule 2", "'very_hihg'", "did you mean 'very_high'"]),
    ("if flatness is high then scor is low", ["rule 2", "'scor'", "did you mean 'score'"]),
    ("if flatness is high and then score is low", ["rule 2", "'then'"]),
    ("if (flatness is high then score is low", ["rule 2", "expected ')'"]),
    ("if flatness is high then score is low extra", ["rule 2", "'extra'"]),
    ("if flatness is high", ["rule 2", "ends early"]),
    ("when flatness is high then score is low", ["rule 2", "expected 'if'"]),
    ("if flatness is high; then score is low", ["rule 2", "';'"]),
])
def test_rule_errors_name_file_rule_and_word(rules_data, rule, words):
    with pytest.raises(ConfigError) as err:
        parse_rule_base(_with_rules(rules_data, [rules_data["rules"][0], rule]), source="my_rules.yaml")
    msg = str(err.value)
    assert "my_rules.yaml" in msg
    for w in words:
        assert w in msg


def test_bad_rules_file_errors(tmp_path, rules_data):
    with pytest.raises(ConfigError, match="not found"):
        load_rules(str(tmp_path / "missing.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("inputs: [\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*not valid YAML"):
        load_rules(str(bad))
    data = dict(rules_data)
    data["inputs"] = dict(data["inputs"])
    data["inputs"]["flatness"] = {"universe": [0.0, 1.0], "terms": {"low": {"triangel": [0, 0, 0.5]}}}
    with pytest.raises(ConfigError, match="did you mean 'triangle'"):
        parse_rule_base(data)
    data["inputs"]["flatness"] = {"universe": [0.0, 1.0], "terms": {"low": {"triangle": [0.5, 0.0, 1.0]}}}
    with pytest.raises(ConfigError, match=re.escape("inputs.flatness.terms.low")):
        parse_rule_base(data)


def test_rules_with_unknown_input_map_rejected_by_scorer(tmp_path, rules_data):
    data = dict(rules_data)
    data["inputs"] = {("flatnes" if k == "flatness" else k): v for k, v in rules_data["inputs"].items()}
    data["rules"] = ["if flatnes is low then score is very_low", "if flatnes is not low then score is very_high"]
    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump(data))
    config = load_config(overrides=[f"scoring.fuzzy.rules={path}"])
    with pytest.raises(ConfigError, match=r"r\.yaml.*'flatnes'.*did you mean 'flatness'"):
        get_scorer(config.scoring, config.mask)


# ----------------------------------------------------------------------------- Bayes
def test_bayes_known_values_and_product_form():
    m = [np.array([0.9]), np.array([0.8]), np.array([0.7]), np.array([0.6])]
    prod, inv = 0.9 * 0.8 * 0.7 * 0.6, 0.1 * 0.2 * 0.3 * 0.4
    assert bayes.fuse(m, 0.5, 0.01)[0] == pytest.approx(prod / (prod + inv), abs=1e-6)  # 0.99213
    rng = np.random.default_rng(2)
    maps = [rng.uniform(0.05, 0.95, 1000) for _ in range(4)]
    p = np.prod(maps, axis=0)
    q = np.prod([1 - x for x in maps], axis=0)
    assert np.max(np.abs(bayes.fuse(maps, 0.5, 0.01) - p / (p + q))) < 1e-5


def test_bayes_symmetric_and_prior():
    rng = np.random.default_rng(3)
    maps = [rng.random(500).astype(np.float32) for _ in range(4)]
    ref = bayes.fuse(maps, 0.3, 0.01)
    for perm in itertools.permutations(range(4)):
        assert np.allclose(bayes.fuse([maps[i] for i in perm], 0.3, 0.01), ref, atol=1e-6)
    # one cue alone is the posterior itself, whatever the prior; cues equal to the prior leave it
    assert bayes.fuse([np.array([0.8])], 0.3, 0.01)[0] == pytest.approx(0.8, abs=1e-6)
    assert bayes.fuse([np.full(3, 0.3)] * 4, 0.3, 0.01) == pytest.approx(0.3, abs=1e-6)
    # with a prior of 0.2, four neutral-at-0.5 cues each carry odds 4x the prior's
    assert bayes.fuse([np.array([0.5])] * 4, 0.2, 0.01)[0] == pytest.approx(1 / (1 + 4.0 ** -3), abs=1e-6)


def test_bayes_clipping_at_0_and_1():
    eps = 0.01
    one, zero = np.array([1.0]), np.array([0.0])
    assert np.isfinite(bayes.fuse([one] * 4, 0.5, eps)).all()
    assert bayes.fuse([one] * 4, 0.5, eps)[0] == pytest.approx((1 - eps) ** 4 / ((1 - eps) ** 4 + eps ** 4), abs=1e-6)
    assert bayes.fuse([zero, one, one, one], 0.5, eps)[0] == pytest.approx(
        (1 - eps) ** 2 / ((1 - eps) ** 2 + eps ** 2), abs=1e-6)
    assert bayes.fuse([zero, one], 0.5, eps)[0] == pytest.approx(0.5, abs=1e-6)
    assert bayes.fuse([one, one], 0.5, 1e-9)[0] == pytest.approx(1.0)  # float64 path, no inf/nan


# ----------------------------------------------------------------------------- scorers
def _maps(shape=(40, 50), seed=0, valid=None):
    rng = np.random.default_rng(seed)
    m = {k: rng.random(shape).astype(np.float32) for k in TerrainMaps.NAMES}
    v = np.ones(shape, bool) if valid is None else valid
    return TerrainMaps(**m, valid=v, slope_deg=np.zeros(shape, np.float32))


@pytest.mark.parametrize("method, evaluator", [("fuzzy", "compiled"), ("fuzzy", "exact"), ("bayes", "compiled")])
def test_scorers_registry_range_and_invalid(method, evaluator):
    assert set(SCORERS) == {"fuzzy", "bayes"}
    config = load_config(overrides=[f"scoring.method={method}", f"scoring.fuzzy.evaluator={evaluator}"])
    scorer = get_scorer(config.scoring, config.mask)
    assert isinstance(scorer, FuzzyScorer if method == "fuzzy" else BayesScorer)
    valid = np.ones((40, 50), bool)
    valid[:5] = False
    score = scorer(_maps(valid=valid))
    assert score.dtype == np.float32 and score.shape == (40, 50)
    assert score.min() >= 0 and score.max() <= 1
    assert np.all(score[:5] == 0) and score[5:].min() > 0


def test_score_frame_uses_method_threshold():
    config = load_config(overrides=["mask.threshold=0.99", "scoring.bayes.threshold=0.0", "mask.margin_factor=0",
                                    "uav.margin_m=0"])
    maps = _maps()
    depth = np.full((40, 50), 5.0, np.float32)
    K = Intrinsics(46.0, 46.0, 25.0, 20.0, 50, 40)
    fz = score_frame(get_scorer(config.scoring, config.mask, "fuzzy"), maps, depth, K, MaskParams.of(config))
    bz = score_frame(get_scorer(config.scoring, config.mask, "bayes"), maps, depth, K, MaskParams.of(config))
    assert fz.method == "fuzzy" and not fz.mask.any()
    assert bz.method == "bayes" and bz.mask.all()


# ----------------------------------------------------------------------------- mask
def _blob_score(size: int, shape=(240, 320)) -> np.ndarray:
    score = np.zeros(shape, np.float32)
    r0, c0 = (shape[0] - size) // 2, (shape[1] - size) // 2
    score[r0:r0 + size, c0:c0 + size] = 0.9
    return score


def test_window_size_from_footprint_and_depth():
    # 0.656 m at 5 m with f = 462.137 px is 60.6 px -> 61 (odd, rounded up)
    assert window_px(0.656, 462.137, 5.0) == 61
    assert window_px(0.0, 462.137, 5.0) == 1
    assert window_px(0.656, 462.137, 1.0) % 2 == 1


def _mask_5m(method: str, score: np.ndarray, depth: np.ndarray) -> ScoreMap:
    """The landing mask with the footprint and focal length of the window-size test above."""
    return landing_mask(method, score, depth, fx=462.137, fy=462.137, footprint_m=(0.656, 0.656), margin_factor=1.0,
                        threshold=0.5)


def test_small_blob_gives_empty_mask_large_one_survives_minus_margin():
    depth = np.full((240, 320), 5.0, np.float32)
    small = _mask_5m("fuzzy", _blob_score(40), depth)  # 40 px < 61 px footprint
    assert not small.mask.any()
    big = _mask_5m("fuzzy", _blob_score(150), depth)
    assert big.mask.sum() == (150 - 60) ** 2  # eroded by (61 - 1) / 2 px on every side
    rows, cols = np.nonzero(big.mask)
    assert rows.min() == (240 - 150) // 2 + 30 and cols.min() == (320 - 150) // 2 + 30
    assert big.score is not None and big.score.max() == pytest.approx(0.9)


def test_mask_border_counts_as_unsafe_and_no_depth_is_empty():
    depth = np.full((100, 100), 5.0, np.float32)
    full = _mask_5m("bayes", np.full((100, 100), 0.9, np.float32), depth)
    assert full.mask.sum() == (100 - 60) ** 2
    none = _mask_5m("bayes", np.full((100, 100), 0.9, np.float32), np.full((100, 100), np.nan))
    assert not none.mask.any()


def test_median_depth_ignores_holes():
    d = np.full((40, 40), np.nan, np.float32)
    d[:20] = 4.0
    d[20:24] = 0.0
    assert median_depth_m(d) == pytest.approx(4.0)
    assert median_depth_m(np.full((8, 8), np.nan)) is None


# ----------------------------------------------------------------------------- CLI (scoring keys)
@pytest.mark.parametrize("override, key", [("scoring.fuzzy.lut_levels=500", "scoring.fuzzy.lut_levels"),
                                           ("scoring.fuzzy.evaluator=fast", "scoring.fuzzy.evaluator"),
                                           ("scoring.bayes.eps=0", "scoring.bayes.eps")])
def test_cli_rejects_bad_scoring_keys_in_one_line(runner, override, key):
    from slzcli.cli import main

    res = runner.invoke(main, ["config", "dump", "--set", override])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in res.stderr


def test_too_many_levels_is_a_config_error(rb):
    with pytest.raises(ConfigError, match=re.escape("scoring.fuzzy.lut_levels")):
        lut.build(rb, 20)


def test_cli_dump_shows_scoring_keys(runner):
    from slzcli.cli import main

    res = runner.invoke(main, ["config", "dump", "--json"])
    assert res.exit_code == 0
    fuzzy_cfg = __import__("json").loads(res.stdout)["scoring"]["fuzzy"]
    assert fuzzy_cfg["lut_levels"] == 13 and fuzzy_cfg["evaluator"] == "compiled"


# ----------------------------------------------------------------------------- plan filter, whole-frame form
def _plan_min_filter_gathered(score: np.ndarray, depth: np.ndarray, intr: Intrinsics, up: np.ndarray,
                              side_m: float, cells: float) -> np.ndarray:
    """The plan filter as first written (issue 18's 'before'): valid points gathered into an N x 3 float64 copy."""
    import math

    import cv2

    from slzcli.scoring.mask import MAX_PLAN_CELLS, min_filter, plan_axes
    from slzcli.terrain.geometry import back_project

    pts = back_project(depth, intr).reshape(-1, 3)
    ok = np.isfinite(pts[:, 2])
    out = np.zeros(score.size, np.float32)
    e1, e2 = plan_axes(up)
    p = pts[ok].astype(np.float64)
    x, y = p @ e1, p @ e2
    x0, y0 = float(x.min()), float(y.min())
    cell = max(side_m / cells, max(float(x.max()) - x0, float(y.max()) - y0) / math.sqrt(MAX_PLAN_CELLS))
    ix, iy = ((x - x0) / cell).astype(np.int64), ((y - y0) / cell).astype(np.int64)
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    worst = np.full(ny * nx, np.inf, np.float32)
    flat = iy * nx + ix
    np.minimum.at(worst, flat, score.reshape(-1)[ok].astype(np.float32))
    raster = worst.reshape(ny, nx)
    seen = np.isfinite(raster)
    gap = ~seen & (cv2.boxFilter(seen.view(np.uint8), cv2.CV_16U, (3, 3), normalize=False,
                                 borderType=cv2.BORDER_CONSTANT) >= 5)
    big = np.float32(np.finfo(np.float32).max)
    near = cv2.erode(np.where(seen, raster, big), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=float(big))
    raster = np.where(seen, raster, np.where(gap, near, np.float32(0)))
    n = max(1, 2 * math.ceil((side_m / cell - 1) / 2) + 1)
    out[ok] = min_filter(raster.astype(np.float32), n, n).reshape(-1)[flat]
    return out.reshape(score.shape)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plan_filter_whole_frame_equals_the_gathered_form(seed: int) -> None:
    """The whole-frame plan filter (spare cell for pixels without depth, shared camera points) gives the
    same values as the gathered N x 3 form on an oblique, holed, noisy frame; with or without points."""
    from slzcli.scoring.mask import camera_points, plan_min_filter

    rng = np.random.default_rng(seed)
    intr = Intrinsics(462.137, 462.137, 320.0, 240.0, 640, 480)
    rows = np.arange(480, dtype=np.float32)[:, None]
    depth = (4.0 + rows * 0.004 + rng.normal(0, 0.02, (480, 640))).astype(np.float32)   # a tilted view
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[100:160, 200:300] = 0.0                                                         # a hole
    score = rng.random(depth.shape).astype(np.float32)
    up = np.array([0.05, -0.5, -0.86])
    want = _plan_min_filter_gathered(score, depth, intr, up, 0.856, 8.0)
    got = plan_min_filter(score, depth, intr, up, 0.856, 8.0)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(plan_min_filter(score, depth, intr, up, 0.856, 8.0,
                                                  points=camera_points(depth, intr)), want)
