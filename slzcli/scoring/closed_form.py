"""The compiled fuzzy score in closed form: exact rule strengths, then an exact centroid.

Why (issue 4: under 5 ms per 640x480 frame on one core, max error <= 0.01; the simplex
table in ``lut.py`` took 9.4 ms at error 0.0054):
- The rule strengths are min / max / 1 - x of memberships, and a trapezoid membership is
  one or two affine maps of the input plus a clip. So the premise side compiles to a short
  straight-line program of float32 array ops and is computed exactly, not tabulated:
  common subexpressions are shared (also a min/max over a subset of another's operands),
  NOTs are gathered by De Morgan (min(1-a, 1-b) = 1 - max(a, b)), and clips the input
  range makes unnecessary are left out; a membership of the clipped input is computed from
  the raw input (``_membership``). Shipped rules: 29 ops up to the 4 activations.
- The defuzzified value then depends on the output-term activations h_k only, in closed
  form: a trapezoid (a, b, c, d) clipped at h has, with r = b - a, s = d - c, W = d - a,
      A(h) = W h - (r + s) h^2 / 2
      M(h) = W (a + d) h / 2 - (r a + s d) h^2 / 2 - (r^2 - s^2) h^3 / 6   (moment about 0)
  The aggregate max_k min(h_k, mu_k) is the sum of the clipped terms minus, where two
  overlap, the min of the two; where a falling edge meets a rising edge that min is a
  triangle of height p (the edges' crossing), clipped at min(h_k, h_j): p times a unit
  triangle clipped at min(h_k, h_j, p) / p. So area and moment are sums of polynomials and
  the score is M / A: exact up to float32 rounding (<= 3e-7 against the float64 exact
  engine on 100k random points plus the membership kinks; tests). Shipped rules: 20 ops.
- It applies to any premises and any number of inputs, whenever the used output terms lie
  in the output universe and meet only edge to edge (``output_plan``: the usual partitions
  of triangles, shoulders and trapezoids). Other output layouts fall back to the simplex
  table (``lut.py``, general but approximate); ``scoring.compile_fuzzy`` chooses.
- Speed: the program runs over the frame in chunks of CHUNK_PX pixels with preallocated
  buffers reused by liveness (ops write in place when an operand dies; 8 buffers for the
  shipped rules), so the 51 passes stay in the L2 cache: a float32 op there costs ~0.04 ms
  per full frame instead of ~0.12 ms streamed from memory. Python loops only over chunks
  and instructions, never over pixels. Shipped rules, 640x480, one core: 2.7-3.6 ms CPU
  (median of 30; the table: 9.2-13.9 ms on the same runs; benchmarks/scoring.py).
- Not done: uint16 fixed point (half the memory traffic, free clipping by saturation) and
  cv2.min/max/threshold (~20 % faster than numpy's, but they drop NaN); numba: not needed.

NaN inputs, and points where no rule fires, give the output universe minimum, as in the
exact engine (unknown is unsafe); a NaN is dropped only where the score does not depend on
that input or by a step membership (a vertical edge inside the universe).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from slzcli.scoring.rules import And, Is, MembershipFn, Node, Not, Or, RuleBase

log = logging.getLogger(__name__)

CHUNK_PX = 32_768   # pixels per chunk: the shipped rules need 8 float32 scratch buffers, 1 MB at 32k px, which
                    # stay in a 2 MB L2 cache; measured 4.9 / 3.3 / 2.8 / 2.8 / 2.8 / 2.8 ms CPU at 8k / 16k /
                    # 32k / 48k / 64k / 96k px (fewer, larger chunks also cut the ~1 us per-call overhead)

SYMMETRIC_TOL = 1e-9  # |rise - fall| / width below which a term counts as symmetric (YAML thirds round)

# An instruction: (op, destination register, operand registers, constants). Registers index a
# per-chunk list of array views: scratch buffers, then the inputs, then the output.
Instr = tuple[str, int, tuple[int, ...], tuple[float, ...]]


@dataclass(frozen=True)
class _Val:
    """A value while compiling: an SSA array id with its known range, or a constant (id None)."""

    id: int | None
    lo: float
    hi: float

    @property
    def const(self) -> bool:
        return self.id is None

    @property
    def ssa(self) -> int:
        """The array id; only arrays enter the program (constants fold while compiling)."""
        if self.id is None:
            raise AssertionError("a constant has no array id")
        return self.id


def _const(c: float) -> _Val:
    return _Val(None, c, c)


class _Builder:
    """SSA program with common-subexpression elimination and range-based simplification."""

    def __init__(self, n_inputs: int) -> None:
        self.ops: list[tuple[str, tuple[int, ...], tuple[float, ...]]] = [("input", (), (float(i),))
                                                                         for i in range(n_inputs)]
        self.memo: dict[tuple[str, tuple[int, ...], tuple[float, ...]], _Val] = {}
        self.vals: dict[int, _Val] = {}
        self.nary_memo: dict[str, dict[frozenset[int], _Val]] = {}

    def emit(self, op: str, args: tuple[_Val, ...], consts: tuple[float, ...], lo: float, hi: float) -> _Val:
        ids = tuple(a.ssa for a in args)
        if op in ("min", "max", "mul"):
            ids = tuple(sorted(ids))  # commutative: one key for both orders
        key = (op, ids, consts)
        if key not in self.memo:
            self.ops.append((op, ids, consts))
            self.memo[key] = self.vals[len(self.ops) - 1] = _Val(len(self.ops) - 1, lo, hi)
        return self.memo[key]

    def input(self, i: int) -> _Val:
        self.vals[i] = _Val(i, -np.inf, np.inf)
        return self.vals[i]

    def affine(self, x: _Val, s: float, t: float) -> _Val:
        if x.const:
            return _const(s * x.lo + t)
        a, b = (t, t) if s == 0.0 else (s * x.lo + t, s * x.hi + t)
        return self.emit("affine", (x,), (s, t), min(a, b), max(a, b))

    def minimum(self, x: _Val, y: _Val) -> _Val:
        if x.const and y.const:
            return _const(min(x.lo, y.lo))
        if x.hi <= y.lo:
            return x
        if y.hi <= x.lo:
            return y
        if y.const:
            x, y = y, x
        if x.const:
            return self.emit("minc", (y,), (x.lo,), min(y.lo, x.lo), x.lo)
        return self.emit("min", (x, y), (), min(x.lo, y.lo), min(x.hi, y.hi))

    def maximum(self, x: _Val, y: _Val) -> _Val:
        if x.const and y.const:
            return _const(max(x.lo, y.lo))
        if x.lo >= y.hi:
            return x
        if y.lo >= x.hi:
            return y
        if y.const:
            x, y = y, x
        if x.const:
            return self.emit("maxc", (y,), (x.lo,), x.lo, max(y.hi, x.lo))
        return self.emit("max", (x, y), (), max(x.lo, y.lo), max(x.hi, y.hi))

    def negate(self, x: _Val) -> _Val:
        """1 - x; NOT of a NOT is the value itself."""
        if x.const:
            return _const(1.0 - x.lo)
        op, ids, _ = self.ops[x.ssa]
        if op == "not":
            return self.vals[ids[0]]
        return self.emit("not", (x,), (), 1.0 - x.hi, 1.0 - x.lo)

    def nary(self, op: str, vals: list[_Val]) -> _Val:
        """min (op 'min') or max of several values. NOTs are gathered by De Morgan
        (min(1-a, 1-b) = 1 - max(a, b): one NOT instead of several), and a min/max already
        computed over a subset of the operands is reused (rule bases repeat premise parts)."""
        consts = [v.lo for v in vals if v.const]
        arrays = list({v.ssa: v for v in vals if not v.const}.values())
        negated = [v for v in arrays if self.ops[v.ssa][0] == "not"]
        if len(negated) >= 2:
            dual = "max" if op == "min" else "min"
            bases = [self.vals[self.ops[v.ssa][1][0]] for v in negated]
            arrays = [v for v in arrays if v not in negated]
            arrays.append(self.negate(self.nary(dual, bases)))
            arrays = list({v.ssa: v for v in arrays}.values())
        pair = self.minimum if op == "min" else self.maximum
        acc = self._fold(op, arrays, pair) if arrays else None
        for c in consts:
            acc = _const(c) if acc is None else pair(acc, _const(c))
        assert acc is not None  # And/Or have at least two operands
        return acc

    def _fold(self, op: str, arrays: list[_Val], pair: Callable[[_Val, _Val], _Val]) -> _Val:
        key = frozenset(v.ssa for v in arrays)
        memo = self.nary_memo.setdefault(op, {})
        if key not in memo:
            todo = sorted(arrays, key=lambda v: v.ssa)
            subsets = [t for t in memo if t < key]
            done = max(subsets, key=len) if subsets else frozenset([todo[0].ssa])
            acc = memo[done] if subsets else todo[0]
            memo[done] = acc
            for v in todo:
                if v.ssa not in done:
                    acc = pair(acc, v)
                    done = done | {v.ssa}
                    memo[done] = acc
        return memo[key]

    def step(self, x: _Val, op: str, c: float) -> _Val:
        """1 where x >= c (op 'ge') or x <= c (op 'le'), else 0."""
        return self.emit(op, (x,), (c,), 0.0, 1.0)


def _membership(b: _Builder, x: _Val, fn: MembershipFn, universe: tuple[float, float]) -> _Val:
    """Membership of the input clipped to its universe, mu(clip(x)), computed from the raw input x.

    A piece p (rising or falling edge, affine in x) is monotone, so p(clip(x)) = clip(p(x),
    p_min, p_max) with its extremes over the universe, and mu = clip(min of the pieces, 0, 1)
    becomes clip(min_k max(p_k, p_min_k), 0, U) with U = min(1, min_k p_max_k): the inner max
    only where p_min_k > 0 (else the outer clip at 0 covers it), one np.clip at the end. So a
    shoulder costs 2 ops, a triangle 4, and the input itself is never clipped (NaN stays NaN).
    """
    lo, hi = universe
    pieces: list[_Val] = []
    upper = 1.0
    for rising in (True, False):
        if rising and fn.b > fn.a:
            s, t = 1.0 / (fn.b - fn.a), -fn.a / (fn.b - fn.a)
        elif not rising and fn.d > fn.c:
            s, t = -1.0 / (fn.d - fn.c), fn.d / (fn.d - fn.c)
        else:  # a vertical edge: a step, unless it lies outside the universe
            edge = fn.a if rising else fn.d
            if (edge <= lo) if rising else (edge >= hi):
                continue  # always 1 on the universe
            if (edge > hi) if rising else (edge < lo):
                return _const(0.0)
            pieces.append(b.step(x, "ge" if rising else "le", edge))
            continue
        p_min, p_max = sorted((s * lo + t, s * hi + t))
        if p_min >= 1.0:
            continue
        if p_max <= 0.0:
            return _const(0.0)
        p = b.affine(x, s, t)
        pieces.append(b.maximum(p, _const(p_min)) if p_min > 0.0 else p)
        upper = min(upper, p_max)
    if not pieces:
        return _const(1.0)
    mu = pieces[0]
    for p in pieces[1:]:
        mu = b.minimum(mu, p)
    return b.emit("clip", (mu,), (0.0, upper), 0.0, upper)


def _premise(b: _Builder, node: Node, leaves: dict[int, _Val]) -> _Val:
    if isinstance(node, Is):
        return leaves[node.index]
    if isinstance(node, Not):
        return b.negate(_premise(b, node.arg, leaves))
    if isinstance(node, (And, Or)):
        return b.nary("min" if isinstance(node, And) else "max", [_premise(b, a, leaves) for a in node.args])
    raise TypeError(f"not a rule node: {node!r}")


def term_polynomials(fn: MembershipFn, origin: float) -> tuple[tuple[float, float], tuple[float, float, float]]:
    """Coefficients of A(h) = A1 h + A2 h^2 and M(h) = M1 h + M2 h^2 + M3 h^3 (moment about origin)
    of the trapezoid clipped at height h."""
    a, d = fn.a - origin, fn.d - origin
    r, s, w = fn.b - fn.a, fn.d - fn.c, fn.d - fn.a
    m3 = 0.0 if abs(r - s) <= SYMMETRIC_TOL * w else -(r * r - s * s) / 6.0  # symmetric: M = centre x A
    return (w, -(r + s) / 2.0), (w * (a + d) / 2.0, -(r * a + s * d) / 2.0, m3)


@dataclass(frozen=True)
class Overlap:
    """Two used output terms that overlap: ``left`` falls and ``right`` rises across the overlap,
    so min of the two memberships there is a triangle ``tent`` of height ``peak``."""

    left: int
    right: int
    tent: MembershipFn
    peak: float


def output_plan(rb: RuleBase) -> tuple[tuple[Overlap, ...] | None, str]:
    """The overlapping pairs of used output terms, or None and why the closed form does not apply.

    It applies when every used term lies inside the output universe, no point lies in three
    used terms, and where two overlap one is falling and the other rising across the overlap
    (any usual partition: equal triangles, shoulders, trapezoids meeting edge to edge)."""
    lo, hi = rb.output.universe
    terms, names = rb.output.terms, rb.output.term_names
    used = sorted({r.term for r in rb.rules}, key=lambda k: (terms[k].a, terms[k].d))
    for k in used:
        if terms[k].a < lo or terms[k].d > hi:
            return None, f"output term {names[k]!r} reaches outside the universe {rb.output.universe}"
    pairs = []
    for i, k in enumerate(used):
        for j in used[i + 1:]:
            left, right = terms[k], terms[j]
            if left.d <= right.a:
                continue
            if left.c > right.a or right.b < left.d:
                return None, f"output terms {names[k]!r} and {names[j]!r} overlap beyond a falling and a rising edge"
            fall, rise = left.d - left.c, right.b - right.a
            y = (left.d * rise + right.a * fall) / (rise + fall)  # where the two edges cross
            pairs.append(Overlap(k, j, MembershipFn(right.a, y, y, left.d), (y - right.a) / rise))
    for p in pairs:
        for q in pairs:
            if p.right == q.left and terms[p.left].d > terms[q.right].a:
                return None, f"output terms {names[p.left]!r}, {names[p.right]!r} and {names[q.right]!r} overlap"
    return tuple(pairs), ""


@dataclass(frozen=True, eq=False)
class ClosedFormFuzzy:
    """A compiled straight-line program: memberships, rule strengths, area/moment polynomials, M / A."""

    program: tuple[Instr, ...]
    n_inputs: int
    n_registers: int
    source: str

    max_error: float = 0.0  # nothing tabulated: float32 rounding only (tests measure it)

    def __call__(self, inputs: list[np.ndarray]) -> np.ndarray:
        """Score of n same-shape inputs (any shape) -> float32 of that shape."""
        shape = np.shape(inputs[0])
        # registers are (1, m) views: OpenCV takes a 1-D array of length <= 4 for a scalar
        xs = [np.ascontiguousarray(x, np.float32).reshape(1, -1) for x in inputs]
        size = xs[0].size
        out = np.empty((1, size), np.float32)
        scratch = np.empty((self.n_registers, 1, min(CHUNK_PX, max(size, 1))), np.float32)
        for s in range(0, size, CHUNK_PX):
            e = min(size, s + CHUNK_PX)
            regs = [buf[:, :e - s] for buf in scratch] + [x[:, s:e] for x in xs] + [out[:, s:e]]
            _run(self.program, regs)
        return out.reshape(shape)


def _muladd_op(r: list[np.ndarray], d: int, a: tuple[int, ...], c: tuple[float, ...]) -> None:
    """d = a0 * a1 + a2, accumulated in place when d is a2's register."""
    if d == a[2]:
        cv2.accumulateProduct(r[a[0]], r[a[1]], r[d])
    else:
        cv2.multiply(r[a[0]], r[a[1]], dst=r[d])
        np.add(r[d], r[a[2]], out=r[d])


def _step(r: list[np.ndarray], d: int, a: tuple[int, ...], c: tuple[float, ...], ge: bool) -> None:
    r[d][...] = (r[a[0]] >= c[0]) if ge else (r[a[0]] <= c[0])


Op = Callable[[list, int, tuple, tuple], object]
# Each op writes register d from operand registers a and constants c. All are NaN-propagating
# (numpy min/max, arithmetic), except the rare step memberships; cv2.min/max are not.
OPS: dict[str, Op] = {
    "clip": lambda r, d, a, c: np.clip(r[a[0]], c[0], c[1], out=r[d]),
    "affine": lambda r, d, a, c: cv2.addWeighted(r[a[0]], c[0], r[a[0]], 0.0, c[1], dst=r[d]),
    "min": lambda r, d, a, c: np.minimum(r[a[0]], r[a[1]], out=r[d]),
    "max": lambda r, d, a, c: np.maximum(r[a[0]], r[a[1]], out=r[d]),
    "minc": lambda r, d, a, c: np.minimum(r[a[0]], c[0], out=r[d]),
    "maxc": lambda r, d, a, c: np.maximum(r[a[0]], c[0], out=r[d]),
    "not": lambda r, d, a, c: np.subtract(1.0, r[a[0]], out=r[d]),
    "mul": lambda r, d, a, c: cv2.multiply(r[a[0]], r[a[1]], dst=r[d]),
    "muladd": _muladd_op,
    "scaleadd": lambda r, d, a, c: cv2.scaleAdd(r[a[0]], c[0], r[a[1]], dst=r[d]),  # a0 * c + a1
    "divide": lambda r, d, a, c: cv2.divide(r[a[0]], r[a[1]], dst=r[d]),  # 0/0: NaN (OpenCV 5) or 0 (4)
    "addc": lambda r, d, a, c: np.add(r[a[0]], c[0], out=r[d]),
    "fmaxc": lambda r, d, a, c: np.fmax(r[a[0]], c[0], out=r[d]),  # NaN (no rule fires, NaN input) -> c
    "fill": lambda r, d, a, c: r[d].fill(c[0]),
    "ge": lambda r, d, a, c: _step(r, d, a, c, True),
    "le": lambda r, d, a, c: _step(r, d, a, c, False),
}


def _run(program: tuple[Instr, ...], r: list[np.ndarray]) -> None:
    for op, d, a, c in program:
        OPS[op](r, d, a, c)


_CACHE: dict[str, ClosedFormFuzzy | None] = {}


def compile_rules(rb: RuleBase) -> ClosedFormFuzzy | None:
    """The program for this rules file (by content digest), built once per process; None if not applicable."""
    if rb.digest not in _CACHE:
        _CACHE[rb.digest] = build(rb)
    return _CACHE[rb.digest]


def build(rb: RuleBase) -> ClosedFormFuzzy | None:
    """The closed-form program for this rule base, or None when its output layout is not one
    ``output_plan`` accepts (then the simplex table is used)."""
    overlaps, reason = output_plan(rb)
    if overlaps is None:
        log.debug("closed-form fuzzy evaluator not applicable to %s: %s", rb.source, reason)
        return None
    n = len(rb.inputs)
    b = _Builder(n)
    xs = [b.input(i) for i in range(n)]  # raw inputs: ranges unknown, never clipped themselves
    leaves = {k: _membership(b, xs[v], rb.inputs[v].terms[t], rb.inputs[v].universe)
              for k, (v, t) in enumerate(rb.leaves) if any(_uses(r.premise, k) for r in rb.rules)}
    act: dict[int, _Val] = {}
    for rule in rb.rules:
        h = _premise(b, rule.premise, leaves)
        act[rule.term] = b.maximum(act[rule.term], h) if rule.term in act else h

    # max of clipped terms = their sum minus, where two overlap, the min of the two: a tent
    # (triangle of height p) clipped at u = min(h_left, h_right, p), i.e. p times the unit
    # triangle clipped at u / p (inclusion-exclusion; no point is in three terms)
    out_lo = rb.output.universe[0]
    acc = _Sums()
    for k in sorted(act):
        acc.add(b, act[k], *term_polynomials(rb.output.terms[k], out_lo), sign=1.0)
    for o in overlaps:
        if o.left in act and o.right in act:
            u = b.minimum(b.minimum(act[o.left], act[o.right]), _const(o.peak))
            (a1, a2), (m1, m2, m3) = term_polynomials(o.tent, out_lo)
            acc.add(b, u, (a1, a2 / o.peak), (m1, m2 / o.peak, m3 / o.peak ** 2), sign=-1.0)
    area, moment, area_c, moment_c = acc.area, acc.moment, acc.area_c, acc.moment_c
    if area is None or moment is None:  # every activation is constant
        value = moment_c / area_c if area_c > 1e-12 else 0.0
        score = b.emit("fill", (), (out_lo + value,), out_lo, out_lo)
    else:
        if area_c:
            area = b.emit("addc", (area,), (area_c,), -np.inf, np.inf)
        if moment_c:
            moment = b.emit("addc", (moment,), (moment_c,), -np.inf, np.inf)
        score = b.emit("divide", (moment, area), (), -np.inf, np.inf)
        if out_lo != 0.0:
            score = b.emit("addc", (score,), (out_lo,), -np.inf, np.inf)
        score = b.emit("fmaxc", (score,), (out_lo,), -np.inf, np.inf)
    program, n_regs = _allocate(b.ops, n, score.ssa)
    return ClosedFormFuzzy(program, n, n_regs, rb.source)


class _Sums:
    """Area and moment accumulated as program values, plus the parts from constant activations."""

    def __init__(self) -> None:
        self.area: _Val | None = None
        self.moment: _Val | None = None
        self.area_c = 0.0
        self.moment_c = 0.0

    def add(self, b: _Builder, h: _Val, area: tuple[float, float], moment: tuple[float, float, float],
            sign: float) -> None:
        """+= sign * (A1 h + A2 h^2) and sign * (M1 h + M2 h^2 + M3 h^3)."""
        (a1, a2), (m1, m2, m3) = [sign * c for c in area], [sign * c for c in moment]
        if h.const:
            self.area_c += a1 * h.lo + a2 * h.lo ** 2
            self.moment_c += m1 * h.lo + m2 * h.lo ** 2 + m3 * h.lo ** 3
            return
        self.area = _muladd(b, b.affine(h, a2, a1), h, self.area)       # h (A1 + A2 h)
        if m3 != 0.0:                                                   # M1 h + h (h (M2 + M3 h))
            t = b.emit("mul", (b.affine(h, m3, m2), h), (), -np.inf, np.inf)
            base = b.affine(h, m1, 0.0) if self.moment is None else b.emit(
                "scaleadd", (h, self.moment), (m1,), -np.inf, np.inf)
            self.moment = _muladd(b, t, h, base)
        else:                                                           # h (M1 + M2 h)
            self.moment = _muladd(b, b.affine(h, m2, m1), h, self.moment)


def _uses(node: Node, leaf: int) -> bool:
    if isinstance(node, Is):
        return node.index == leaf
    if isinstance(node, Not):
        return _uses(node.arg, leaf)
    return any(_uses(a, leaf) for a in node.args)


def _muladd(b: _Builder, x: _Val, y: _Val, acc: _Val | None) -> _Val:
    """x * y (+ acc)."""
    if acc is None:
        return b.emit("mul", (x, y), (), -np.inf, np.inf)
    return b.emit("muladd", (x, y, acc), (), -np.inf, np.inf)


INPLACE = {"muladd": 2, "scaleadd": 1}  # operand a write-in-place op prefers to overwrite


def _allocate(ops: list[tuple[str, tuple[int, ...], tuple[float, ...]]], n_inputs: int,
              result: int) -> tuple[tuple[Instr, ...], int]:
    """Map SSA values to scratch registers by liveness; inputs and the result get their own slots."""
    live = {result}
    for i in range(result, -1, -1):  # dead-code elimination: NOTs folded away by De Morgan
        if i in live:
            live.update(ops[i][1])
    last = {}
    for i, (_, args, _) in enumerate(ops):
        if i in live:
            for a in args:
                last[a] = i
    reg: dict[int, int] = {}
    free: list[int] = []
    n_regs = 0
    body = []
    for i, (op, args, consts) in enumerate(ops):
        if op == "input" or i not in live:
            continue
        dying = [a for a in dict.fromkeys(args) if a >= n_inputs and last[a] == i]
        freed = [reg[a] for a in dying]
        free.extend(freed)
        if i == result:
            dst = -1
        elif op in INPLACE and args[INPLACE[op]] in dying:
            dst = reg[args[INPLACE[op]]]
            free.remove(dst)
        elif free:
            dst = free.pop()
        else:
            dst, n_regs = n_regs, n_regs + 1
        reg[i] = dst
        body.append((op, dst, args, consts))
    out_slot = n_regs + n_inputs  # registers: scratch 0..n_regs-1, then the inputs, then the output

    def slot(v: int) -> int:
        return n_regs + v if v < n_inputs else out_slot if reg[v] < 0 else reg[v]

    program = tuple((op, out_slot if dst < 0 else dst, tuple(slot(a) for a in args), consts)
                    for op, dst, args, consts in body)
    return program, n_regs
