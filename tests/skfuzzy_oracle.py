"""scikit-fuzzy built from one of our rule bases: the test oracle (and the benchmark's reference).

scikit-fuzzy is a test-only dependency; nothing in slzcli imports it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slzcli.scoring.rules import And, Is, Node, Not, RuleBase


def skfuzzy_simulation(rb: RuleBase) -> Any:
    """A ControlSystemSimulation equivalent to the rule base ``rb`` (exact centroid on its grid)."""
    from skfuzzy import control as ctrl

    # scikit-fuzzy has no type information: its objects are Any here.
    ants: list[Any] = []
    for v in rb.inputs:
        lo, hi = v.universe
        a = ctrl.Antecedent(np.linspace(lo, hi, 101), v.name)  # breakpoints 0, .5, 1 on the grid
        for name, fn in zip(v.term_names, v.terms, strict=True):
            a[name] = fn(a.universe)
        ants.append(a)
    # 601 samples: every output breakpoint (k/6) is a sample, so the piecewise-linear
    # aggregate scikit-fuzzy integrates is the exact one wherever the clipped terms do not
    # cross each other - which the shipped consequents (non-overlapping terms) guarantee.
    lo, hi = rb.output.universe
    out = ctrl.Consequent(np.linspace(lo, hi, 601), rb.output.name, defuzzify_method="centroid")
    used = {r.term for r in rb.rules}  # skfuzzy fails on array inputs with unused consequent terms
    for k, (name, fn) in enumerate(zip(rb.output.term_names, rb.output.terms, strict=True)):
        if k in used:
            out[name] = fn(out.universe)

    def conv(node: Node) -> Any:
        if isinstance(node, Is):
            vi, ti = rb.leaves[node.index]
            return ants[vi][rb.inputs[vi].term_names[ti]]
        if isinstance(node, Not):
            return ~conv(node.arg)
        args = [conv(x) for x in node.args]
        acc = args[0]
        for x in args[1:]:
            acc = (acc & x) if isinstance(node, And) else (acc | x)
        return acc

    rules = [ctrl.Rule(conv(r.premise), out[rb.output.term_names[r.term]]) for r in rb.rules]
    return ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))
