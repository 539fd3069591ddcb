"""Per-run random streams: run i's randomness depends only on (seed, i), never on the batch size.

Each run has its own generator, seeded by ``SeedSequence(seed, spawn_key=(i, stream))`` (the
same child ``SeedSequence(seed).spawn`` would give), with one stream for the start scatter and
one for the in-flight noise. So run 7 of a 100-run batch is run 7 of a 10-run batch, and a
batch can be split across processes. The in-flight stream is drawn in blocks of steps, so the
per-step path stays one vectorised (N, width) array and Python loops only over runs once a block.
"""

from __future__ import annotations

import numpy as np

START_STREAM = 0
FLIGHT_STREAM = 1
BLOCK_STEPS = 256
"""Steps drawn per generator call: a speed knob only (a generator's stream does not depend on it)."""


def run_generator(seed: int, run: int, stream: int) -> np.random.Generator:
    """The generator of one stream of run ``run`` under ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(run, stream)))


class FlightNoise:
    """Standard normals for each run and control step: ``next()`` -> (N, width), row i from run i's stream.

    A small stateful object (the generators and the current block): the simulation asks for one
    row per step, in step order, and the values for run i at step k are fixed by (seed, i, k).
    """

    def __init__(self, seed: int, runs: int, width: int, first_run: int = 0) -> None:
        self._gens = [run_generator(seed, first_run + i, FLIGHT_STREAM) for i in range(runs)]
        self._width = width
        self._block = np.empty((runs, 0, width))
        self._pos = 0

    def next(self) -> np.ndarray:
        """The next step's (N, width) standard normals."""
        if self._pos == self._block.shape[1]:
            rows = [g.standard_normal((BLOCK_STEPS, self._width)) for g in self._gens]
            self._block = np.stack(rows) if rows else np.empty((0, BLOCK_STEPS, self._width))
            self._pos = 0
        out = self._block[:, self._pos]
        self._pos += 1
        return out
