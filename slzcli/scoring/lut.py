"""The general fallback of the compiled fuzzy score: a table over the inputs, read by simplex interpolation.

``scoring.compile_fuzzy`` uses this table only when the closed form (``closed_form.py``:
exact, 3 ms per 640x480 frame for the shipped rules) does not apply, i.e. when the used
output terms overlap in some other way than a falling edge meeting a rising edge (a term
spanning two others, three terms over one point) or reach outside the output universe.
The table works for any rule base of 1 to 4 inputs, approximately: 0.0054 max error on the
shipped rules, 14 ms per frame (9.4 ms measured earlier on a quieter machine).

Why this design (max |table - exact| on 100k random inputs, 17 levels per input, float
interpolation; the shipped rule base first, the first, table-style rule base in brackets):
- Tabulating the centroid itself is poor: near a veto the centroid is a ratio of small
  areas and bends sharply. Multilinear interpolation of it is off by 0.10 [0.084], simplex
  interpolation by 0.038 [0.048] ([0.015] at 33 levels).
- So the table holds the two things the centroid is made of, the aggregated output's
  area A and moment M, and the score is interp(M) / interp(A). A and M are piecewise
  polynomial in the rule activations, with no division to bend them.
- The activations are min/max of memberships, so A and M have kinks where two
  memberships are equal. With equal triangles those lie on the diagonals ``w_i = w_j`` of
  every quarter cell, ``w`` measured from where two terms cross (x = 0.25, 0.75). Kuhn
  (Freudenthal) simplex interpolation with each cell's triangulation mirrored so that its
  diagonal starts at that crossing reproduces those kinks. A/M with plain simplices:
  0.0032 [0.026]; mirrored: 0.0032 [0.0024] (the shipped rules have no kink across a cell).
- In use (inputs quantised to 1/256 of a cell) the error is 0.0092 at 9 levels and 0.0054
  at 13 (the default and, for 4 inputs, near the most the int16 cell index allows), on
  100k random points plus the breakpoint grid (tests, benchmarks/scoring.py).
- Speed: the per-input work is done in uint16/uint8 with 8-bit lookup tables (cv2.LUT).
  The table is stored cell-local: one row per cell, one column per corner in the cell's
  (mirrored) walk frame, so a simplex vertex is (corner bits from the ordering code, cell
  row) whatever the mirroring. The 5 vertices are gathered with np.take (cheaper than
  cv2.remap here, measured) and weighted with cv2.accumulateProduct; the frame is done in
  row blocks of ~40k pixels so the ~100 passes stay in cache. No Python loop over pixels.
  The cell index is int16 with the 8-bit cell codes: (levels - 1)^n < 32767, i.e. at most
  14 levels for 4 inputs.

Build: levels^n exact evaluations, 0.3-0.8 s at 13 levels (busy machine), kept in memory per (rules-file
digest, levels). The mirroring rule is general (each cell's walk starts at the end where
the memberships are closest to 1/2); the build measures its own error on random inputs
and logs a warning above the 0.01 tolerance.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.errors import ConfigError
from slzcli.scoring import fuzzy
from slzcli.scoring.rules import RuleBase

log = logging.getLogger(__name__)

SUB = 256            # quantisation steps per table cell (8-bit fraction)
MAX_INPUTS = 4       # ordering code of n inputs needs n(n-1)/2 <= 6 bits of an 8-bit LUT index
CHECK_POINTS = 4096  # random inputs on which the build measures its own error
MAX_CELLS = 32767    # the cell index is int16
FLAT_WIDTH = 1024    # row width used when the inputs are not an image
CHUNK_PX = 40_000    # pixels per block of the compiled evaluator (fits the L2 cache with its temporaries)
TOLERANCE = 0.01     # max |compiled - exact| the design promises (issue 4)


@dataclass(frozen=True, eq=False)
class CompiledFuzzy:
    """Area and moment tables (one row per cell, one column per corner) and the 8-bit lookup tables."""

    levels: int
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    area_img: np.ndarray        # float32 (cells, 2^n): area at each cell's corners, in walk order
    moment_img: np.ndarray      # float32 (cells, 2^n): moment about out_lo (>= 0), same layout
    cell_lut: tuple[np.ndarray, ...]     # per input, by cell along it: int16 contribution to the cell index
    mirror_lut: tuple[np.ndarray, ...]   # per input, by cell along it: uint16 SUB where mirrored, else 0
    corner_luts: tuple[np.ndarray, ...]  # per vertex 1..n-1, by ordering code: int16 corner bits (2^i per input)
    out_lo: float
    max_error: float            # measured at build on CHECK_POINTS random inputs

    @property
    def n(self) -> int:
        return len(self.lo)

    def __call__(self, inputs: list[np.ndarray]) -> np.ndarray:
        """Score of n same-shape float32 inputs (an image, or any shape) -> float32 of that shape."""
        shape = np.shape(inputs[0])
        if len(shape) == 2:
            # row blocks of ~CHUNK_PX pixels: the ~100 passes over the pixels then stay in cache
            # (measured 26 % faster than whole frames at 640x480)
            rows = max(1, CHUNK_PX // max(1, shape[1]))
            if rows >= shape[0]:
                return interpolate(self, inputs)
            out = np.empty(shape, np.float32)
            xs = [np.ascontiguousarray(x, np.float32) for x in inputs]
            for r in range(0, shape[0], rows):
                out[r:r + rows] = interpolate(self, [x[r:r + rows] for x in xs])
            return out
        size = int(np.prod(shape))
        rows = -(-size // FLAT_WIDTH)
        padded = []
        for x in inputs:  # the evaluator works on 2-D blocks of rows
            flat = np.zeros(rows * FLAT_WIDTH, np.float32)
            flat[:size] = np.ravel(x)
            padded.append(flat.reshape(rows, FLAT_WIDTH))
        return self(padded).ravel()[:size].reshape(shape)


_CACHE: dict[tuple[str, int], CompiledFuzzy] = {}


def compile_rules(rb: RuleBase, levels: int) -> CompiledFuzzy:
    """The compiled table for this rules file (by content digest) and level count, built once per process."""
    key = (rb.digest, levels)
    if key not in _CACHE:
        _CACHE[key] = build(rb, levels)
    return _CACHE[key]


def build(rb: RuleBase, levels: int) -> CompiledFuzzy:
    n = len(rb.inputs)
    if not 1 <= n <= MAX_INPUTS:
        raise ConfigError("scoring.fuzzy.evaluator", f"the compiled table supports 1 to {MAX_INPUTS} inputs, "
                          f"{rb.source} has {n}; use evaluator: exact", None)
    L = levels
    cells = L - 1
    if cells ** n >= MAX_CELLS or cells > 255:
        raise ConfigError("scoring.fuzzy.lut_levels", f"{L} levels make {cells ** n} table cells for {n} inputs; "
                          f"the compiled table holds at most {MAX_CELLS - 1} (e.g. 13 levels for 4 inputs)")
    grids = [np.linspace(v.universe[0], v.universe[1], L) for v in rb.inputs]
    nodes = np.stack([g.ravel() for g in np.meshgrid(*grids, indexing="ij")])
    area, moment = fuzzy.evaluate_area_moment(rb, nodes)
    out_lo = rb.output.universe[0]
    area = area.reshape((L,) * n)
    moment = (moment - out_lo * area.ravel()).reshape((L,) * n)
    flips = [_mirror_cells(v, g) for v, g in zip(rb.inputs, grids, strict=True)]
    # cell-local layout: row = cell index, column = corner bits in the walk's (mirrored) frame,
    # so a vertex is found from the ordering code alone, whatever the cell's mirroring
    cidx = np.meshgrid(*[np.arange(cells)] * n, indexing="ij")
    area_img = np.empty((cells ** n, 2 ** n), np.float32)
    moment_img = np.empty_like(area_img)
    for bits in range(2 ** n):
        node = tuple((c + ((bits >> i & 1) ^ flips[i][c])).ravel() for i, c in enumerate(cidx))
        area_img[:, bits] = area[node]
        moment_img[:, bits] = moment[node]
    c = np.minimum(np.arange(256), cells - 1)
    cell_lut = tuple((c * cells ** (n - 1 - i)).astype(np.int16) for i in range(n))
    mirror_lut = tuple((flips[i][c] * SUB).astype(np.uint16) for i in range(n))
    corner_luts = tuple(_corner_lut(n, k) for k in range(1, n))
    compiled = CompiledFuzzy(L, tuple(v.universe[0] for v in rb.inputs), tuple(v.universe[1] for v in rb.inputs),
                             area_img, moment_img, cell_lut, mirror_lut, corner_luts, out_lo, 0.0)
    err = _self_check(rb, compiled)
    if err > TOLERANCE:
        log.warning("compiled fuzzy table (%d levels) is off by up to %.4f from the exact evaluator on %s; "
                    "raise scoring.fuzzy.lut_levels or use evaluator: exact", L, err, rb.source)
    return dataclasses.replace(compiled, max_error=err)


def _mirror_cells(var: fuzzy.Variable, grid: np.ndarray) -> np.ndarray:
    """Per cell: start the simplex walk at the upper end (True) where memberships are closer to 1/2 there."""
    ends = np.stack([fn(grid) for fn in var.terms])
    active = np.stack([fn((grid[1:] + grid[:-1]) / 2) for fn in var.terms]) > 0
    d_lo = np.max(np.where(active, np.abs(ends[:, :-1] - 0.5), 0.0), axis=0)
    d_hi = np.max(np.where(active, np.abs(ends[:, 1:] - 0.5), 0.0), axis=0)
    return d_hi < d_lo


def _precedes(code: int, n: int, a: int, b: int) -> bool:
    """Does input a come before b in the descending order encoded by the comparison bits?"""
    pairs = list(itertools.combinations(range(n), 2))
    if a < b:
        return bool(code >> pairs.index((a, b)) & 1)
    return not (code >> pairs.index((b, a)) & 1)


def _corner_lut(n: int, k: int) -> np.ndarray:
    """Corner bits of simplex vertex k (the k inputs with the largest fractions have stepped), by ordering code."""
    lut = np.zeros(256, np.int16)
    for code in range(1 << (n * (n - 1) // 2)):
        for i in range(n):
            if sum(_precedes(code, n, o, i) for o in range(n) if o != i) < k:
                lut[code] |= 1 << i
    return lut


def _self_check(rb: RuleBase, compiled: CompiledFuzzy) -> float:
    rng = np.random.default_rng(0)
    lo, hi = np.array(compiled.lo)[:, None], np.array(compiled.hi)[:, None]
    x = (lo + rng.random((compiled.n, CHECK_POINTS)) * (hi - lo)).astype(np.float32)
    exact = fuzzy.evaluate_exact(rb, x.astype(np.float64))
    approx = compiled(list(x))
    return float(np.max(np.abs(approx - exact)))


SORT_NETWORKS = {1: [], 2: [(0, 1)], 3: [(0, 1), (1, 2), (0, 1)], 4: [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)]}


def _lut(src: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``cv2.LUT``, typed as the array it is (OpenCV's stubs widen the result to any number type)."""
    return cv2.LUT(src, table)


def interpolate(t: CompiledFuzzy, inputs: list[np.ndarray]) -> np.ndarray:
    """Mirrored Kuhn simplex interpolation of the area and moment tables; returns out_lo + M / A."""
    n, L = t.n, t.levels
    scale_max = (L - 1) * SUB - 1
    shape = np.shape(inputs[0])
    cell = np.zeros(shape, np.int16)
    fracs = []
    for i, x in enumerate(inputs):
        x = np.ascontiguousarray(x, np.float32)
        s = (L - 1) * SUB / (t.hi[i] - t.lo[i])
        q: np.ndarray = cv2.addWeighted(x, s, x, 0.0, -t.lo[i] * s, dtype=cv2.CV_16U)  # quantised, rounded, >= 0
        np.minimum(q, scale_max, out=q)
        c8 = (q >> 8).astype(np.uint8)                                     # cell along this input
        np.bitwise_and(q, SUB - 1, out=q)                                  # fraction in the cell
        fracs.append(cv2.absdiff(q, _lut(c8, t.mirror_lut[i])))            # SUB - fraction where mirrored
        cell += _lut(c8, t.cell_lut[i])
    code = np.zeros(shape, np.uint8)  # one bit per pair (a < b): fraction a > fraction b
    for bit, (a, b) in enumerate(itertools.combinations(range(n), 2)):
        gt: np.ndarray = cv2.compare(fracs[a], fracs[b], cv2.CMP_GT)
        np.bitwise_and(gt, 1 << bit, out=gt)
        code |= gt
    # descending sorted fractions -> barycentric weights (they sum to SUB; the ratio M/A cancels it)
    srt = list(fracs)
    for a, b in SORT_NETWORKS[n]:
        srt[a], srt[b] = cv2.max(srt[a], srt[b]), cv2.min(srt[a], srt[b])
    weights = [np.subtract(SUB, srt[0])] + [cv2.subtract(srt[k], srt[k + 1]) for k in range(n - 1)] + [srt[-1]]
    rows = cell.astype(np.intp)
    rows *= 2 ** n                                   # flat index of the cell's first corner
    area = np.zeros(shape, np.float32)
    moment = np.zeros(shape, np.float32)
    flat_area, flat_moment = t.area_img.ravel(), t.moment_img.ravel()
    gathered = np.empty(shape, np.float32)
    for k, w in enumerate(weights):
        if k == 0:
            index = rows
        elif k == n:
            index = rows + (2 ** n - 1)
        else:
            index = rows + _lut(code, t.corner_luts[k - 1])
        wf = w.astype(np.float32)
        np.take(flat_area, index, out=gathered)
        cv2.accumulateProduct(gathered, wf, area)
        np.take(flat_moment, index, out=gathered)
        cv2.accumulateProduct(gathered, wf, moment)
    score = cv2.divide(moment, area)
    np.fmax(score, 0.0, out=score)  # 0/0 where no rule fires is NaN on OpenCV 5 (0 on 4): the universe minimum
    if t.out_lo != 0.0:
        score += np.float32(t.out_lo)
    return score
