"""Per-stage wall-clock timing: a tiny accumulator the pipeline threads through its steps."""

from __future__ import annotations

import time
from array import array
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np


@dataclass
class StageTimer:
    """Collects milliseconds per stage name, per frame; summaries are medians and p90s.

    Samples are kept as C doubles (8 B each; a list of floats takes 40): a long recording's
    timings stay small.
    """

    samples_ms: dict[str, array[float]] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, (time.perf_counter() - t0) * 1e3)

    def add(self, name: str, ms: float) -> None:
        self.samples_ms.setdefault(name, array("d")).append(ms)

    def last(self) -> dict[str, float]:
        return {k: v[-1] for k, v in self.samples_ms.items() if v}

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for name, values in self.samples_ms.items():
            arr = np.asarray(values)
            out[name] = {"median_ms": float(np.median(arr)), "p90_ms": float(np.percentile(arr, 90)),
                         "mean_ms": float(arr.mean()), "count": int(arr.size)}
        return out
