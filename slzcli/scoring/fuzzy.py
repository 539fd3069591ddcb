"""Mamdani fuzzy landing score (METHOD 2.4): the exact engine.

AND = min, OR = max, NOT = 1 - x, implication = min, aggregation = max, centroid
defuzzification. The centroid is the exact one of the continuous aggregated output
``f(y) = max_k min(a_k, mu_k(y))``: f is piecewise linear, and every kink lies either at a
fixed point (a membership breakpoint, or where two membership segments cross) or where a
segment of some term reaches some activation level (``mu_j(y) = a_k``). Sampling f at all
of these points and integrating the straight pieces exactly gives the centroid with no
discretisation error (unlike a sum over a 101-point universe, which is off by up to ~0.006).
scikit-fuzzy computes the same piecewise-linear integral but samples only its universe
plus the ``mu_k(y) = a_k`` points, so it converges to this value as its universe is refined.

The per-frame path uses the compiled evaluator (``closed_form.py``, else the table in
``lut.py``; ``scoring.compile_fuzzy`` chooses); this module is the reference.
"""

from __future__ import annotations

import itertools

import numpy as np

from slzcli.scoring.rules import And, Is, Node, Not, Or, RuleBase, Variable

CHUNK_PX = 256  # pixels per chunk: temporaries stay small enough for malloc to reuse (big ones are
                # mmapped and page-faulted afresh every time: 8192 was 2.3x slower, measured)


def memberships(rb: RuleBase, inputs: np.ndarray) -> np.ndarray:
    """(n_inputs, N) crisp inputs -> (n_leaves, N) membership degrees (inputs clipped to their universes)."""
    rows: list[np.ndarray] = []
    for v, var in enumerate(rb.inputs):
        x = np.clip(inputs[v], var.universe[0], var.universe[1])
        rows.extend(fn(x) for fn in var.terms)
    return np.stack(rows)


def evaluate_node(node: Node, mu: np.ndarray) -> np.ndarray:
    """Firing strength of a premise AST over the membership rows."""
    if isinstance(node, Is):
        return mu[node.index]
    if isinstance(node, Not):
        return 1.0 - evaluate_node(node.arg, mu)
    if isinstance(node, And):
        return _reduce(np.minimum, node.args, mu)
    if isinstance(node, Or):
        return _reduce(np.maximum, node.args, mu)
    raise TypeError(f"not a rule node: {node!r}")


def _reduce(op: np.ufunc, args: tuple[Node, ...], mu: np.ndarray) -> np.ndarray:
    out = np.array(evaluate_node(args[0], mu), copy=True)
    for a in args[1:]:
        op(out, evaluate_node(a, mu), out=out)
    return out


def activations(rb: RuleBase, inputs: np.ndarray) -> np.ndarray:
    """(n_inputs, N) -> (n_output_terms, N): max over the rules of each consequent of their strengths."""
    mu = memberships(rb, inputs)
    act = np.zeros((len(rb.output.terms), inputs.shape[1]), dtype=mu.dtype)
    for rule in rb.rules:
        np.maximum(act[rule.term], evaluate_node(rule.premise, mu), out=act[rule.term])
    return act


def fixed_kinks(output: Variable) -> np.ndarray:
    """Kinks of the aggregated output that do not depend on the activations."""
    lo, hi = output.universe
    pts = [lo, hi] + [p for fn in output.terms for p in fn.points]
    segs = [s for fn in output.terms for s in fn.segments()]
    for (a0, m0, a1, m1), (b0, n0, b1, n1) in itertools.combinations(segs, 2):
        sa, sb = (m1 - m0) / (a1 - a0), (n1 - n0) / (b1 - b0)
        if sa == sb:
            continue
        y = (n0 - sb * b0 - m0 + sa * a0) / (sa - sb)
        if max(a0, b0) <= y <= min(a1, b1):
            pts.append(y)
    return np.unique(np.clip(pts, lo, hi))


def area_moment(output: Variable, act: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact area and first moment of max_k min(a_k, mu_k(y)); (K, N) activations -> two (N,)."""
    lo, hi = output.universe
    n = act.shape[1]
    a = act.T  # (N, K)
    kinks = fixed_kinks(output)
    cand = [np.broadcast_to(kinks, (n, len(kinks)))]
    for fn in output.terms:
        for u0, m0, u1, m1 in fn.segments():
            cand.append(u0 + (a - m0) / (m1 - m0) * (u1 - u0))  # where this segment equals each a_k
    y = np.sort(np.clip(np.concatenate(cand, axis=1), lo, hi), axis=1)
    f = np.zeros_like(y)
    for k, fn in enumerate(output.terms):
        np.maximum(f, np.minimum(a[:, k:k + 1], fn(y)), out=f)
    dy = np.diff(y, axis=1)
    f0, f1, y0, y1 = f[:, :-1], f[:, 1:], y[:, :-1], y[:, 1:]
    area = np.sum(dy * (f0 + f1), axis=1) / 2.0
    moment = np.sum(dy * (y0 * (2.0 * f0 + f1) + y1 * (f0 + 2.0 * f1)), axis=1) / 6.0
    return area, moment


def centroid_of(output: Variable, area: np.ndarray, moment: np.ndarray) -> np.ndarray:
    """moment / area; where no rule fires (zero area) the universe minimum: unknown is unsafe."""
    out = np.full(np.shape(area), output.universe[0], dtype=np.float64)
    ok = area > 0
    out[ok] = moment[ok] / area[ok]
    return out


def centroid(output: Variable, act: np.ndarray) -> np.ndarray:
    """Exact centroid of the aggregated output; (K, N) activations -> (N,)."""
    return centroid_of(output, *area_moment(output, act))


def evaluate_area_moment(rb: RuleBase, inputs: np.ndarray, chunk: int = CHUNK_PX) -> tuple[np.ndarray, np.ndarray]:
    """Area and moment of the aggregated output for (n_inputs, N) inputs, chunked."""
    inputs = np.asarray(inputs, dtype=np.float64)
    area = np.empty(inputs.shape[1])
    moment = np.empty(inputs.shape[1])
    for s in range(0, inputs.shape[1], chunk):
        area[s:s + chunk], moment[s:s + chunk] = area_moment(rb.output, activations(rb, inputs[:, s:s + chunk]))
    return area, moment


def evaluate_exact(rb: RuleBase, inputs: np.ndarray, chunk: int = CHUNK_PX) -> np.ndarray:
    """Crisp score for (n_inputs, N) inputs, in float64."""
    return centroid_of(rb.output, *evaluate_area_moment(rb, inputs, chunk))
