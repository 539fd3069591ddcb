"""Every detection method by name: the one list ``--method``, ``scoring.method``, ``compare.methods`` and the
JSON schema's enum follow (tests/pipeline/test_run_assembly.py holds the schema to it).

A leaf (it imports nothing of slzcli, not even for types, so that the config check can read it): the
config check and the CLI's choices read the names without importing the methods; a method's module is
imported when the method is first built (``base.build``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Entry:
    """A method: ``build`` is ``"module:function"`` (imported at the first build) or the function itself,
    taking the config and returning a fresh ``base.Method``; ``summary``: one line for ``--help``."""

    build: str | Callable[..., object]
    summary: str


METHODS: dict[str, Entry] = {
    "fuzzy": Entry("slzcli.methods.maps:fuzzy", "Mamdani fuzzy score of the four terrain maps (METHOD 2.4)"),
    "bayes": Entry("slzcli.methods.maps:bayes", "naive Bayes fusion of the four terrain maps (BASELINE.md)"),
    "px4slp": Entry("slzcli.methods.px4slp:px4slp", "PX4-Avoidance's grid planner on depth points (PX4SLP.md)"),
    "fused": Entry("slzcli.methods.fused:fused", "the fuzzy rules on the terrain fused over every tracked frame, "
                   "safe / unsafe / undecided per cell (METHOD 2.3.6)"),
}


def names() -> tuple[str, ...]:
    """The registered methods, in registry order."""
    return tuple(METHODS)


def factory(name: str) -> Callable[..., object]:
    """The function that builds method ``name`` from a config; KeyError for an unknown name (the config check
    refuses one before a run starts)."""
    target = METHODS[name].build
    if isinstance(target, str):
        module, attr = target.split(":")
        target = getattr(importlib.import_module(module), attr)
    return target
