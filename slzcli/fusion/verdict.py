"""The four maps, score, mask and the verdict per cell on the fused heights (METHOD 2.3.6).

The maps keep their METHOD 2.3 meaning, on cells instead of pixels (a height field seen from above):
  depth variance  exp(-s / s0): s the residual height std about the plane of 3 x 3 cells, the fused
                  noise's share removed (2.3.1)
  flatness        min(d / clearance_m, 1): d the distance (m) to the nearest cell where a step to a
                  4-neighbour exceeds uav.max_step_m significantly (k sigma of the difference) or a refused
                  cell (2.3.2; an unseen cell keeps its square from being decided instead)
  inclination     exp(-C / curvature_ref): C = l0 / (l0 + l1 + l2) of the cells within radius_m (2.3.3)
  steepness       exp(-(psi / max_slope)^2): psi the slope of the plane over the footprint's cells (2.3.4)
The fuzzy rules score them (``Scorer.score_arrays``, the rules stay data); the mask is the score smoothed
by ``mask.smooth_m``, its minimum over the landing square (footprint + margins), over the threshold.

Verdict per cell:
  SAFE       the mask holds, every cell of its landing square is *decided* (its fused variance no longer
             hides a step of uav.max_step_m nor a slope of max_slope_deg: the per-frame limits of
             ``limits.working_scale`` scaled by the cell's fused std, ``terrain.fusion.decided_margin`` times within
             them),
             the step fitted across every cell of the square (and in the windows centred up to half a
             window beyond it along the step, which read a step ending in the square whole) and the slope
             of its plane stay within the tolerances by those limits (estimate + limit <= tolerance), the
             column above its whole square was seen clear, and its connected patch of such cells is not on a
             raised surface (below);
  UNSAFE     a defect is known in its square (a step or slope beyond the tolerance by more than (k + 1) / k
             times its limit, a refused cell), or the mask fails on a square whose limits are
             ``terrain.fusion.unsafe_margin`` times within the tolerances, or its patch is raised;
  UNDECIDED  seen, neither of the above: the noise still hides what the UAV cannot take;
  UNSEEN     no frame measured it.

Raised surfaces (``landing/raised.py``, METHOD 2.5.1): a flat, level box top or car roof passes every test
above. The rule runs once per connected patch of the cells that pass them, at the patch's best cell (the one
``best_site`` takes: deepest inside it); a patch the rule refuses is UNSAFE whole. One test per patch: a patch
is one surface (a raised top's edge is a step, whose defect square keeps its cells from the ground's patch),
and the rule reads the ground within ``landing.raised.ground_radius_m`` of the cell, which the fused heights
of the region hold. A patch whose surroundings hold fewer than ``min_cells`` plan cells is not measured and
stays SAFE; ``FusedMaps.patch_tests`` and the site's ``raised`` say so.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.fusion import kernels
from slzcli.fusion.funnel import CellFunnel
from slzcli.fusion.grid import Region
from slzcli.fusion.measure import FusionParams
from slzcli.landing.raised import Raised, RaisedParams, above_ground, raised_params
from slzcli.terrain.geometry import eigvalsh3

UNSEEN, UNSAFE, UNDECIDED, SAFE = 0, 1, 2, 3
VERDICT_NAMES = {UNSEEN: "unseen", UNSAFE: "unsafe", UNDECIDED: "undecided", SAFE: "safe"}
_EQUAL_AREA_HALF_SIDE = math.sqrt(math.pi) / 2.0


@dataclass(frozen=True, eq=False)
class StepFits:
    """The steps fitted across every cell (|s|, m; NaN where the window is not fully seen) between columns (``x``)
    and between rows (``y``); the verdict reads each against its limit, ``scale`` x the cell's ``step_min_m``
    (how the fitted steps scatter on the map), ``reach`` cells beyond a landing square along the step included,
    and takes a step beyond ``known`` x its limit for a finding (a known defect when beyond the tolerance)."""

    x_m: np.ndarray
    y_m: np.ndarray
    scale_x: float
    scale_y: float
    reach: int
    known: float


@dataclass(frozen=True, eq=False)
class FusedMaps:
    """Everything the fused terrain says about a region (arrays of the region's shape)."""

    region: Region
    depth_variance: np.ndarray
    flatness: np.ndarray
    inclination: np.ndarray
    steepness: np.ndarray
    slope_deg: np.ndarray
    score: np.ndarray
    mask: np.ndarray          # the min-filtered score over the threshold
    clear_score: np.ndarray   # the min-filtered score itself (ranks candidates)
    step_min_m: np.ndarray    # smallest step the cell's fused noise lets through (per cell)
    slope_min_deg: np.ndarray
    decided: np.ndarray       # the whole landing square's noise limits decided_margin times within the tolerances
    defect: np.ndarray        # a known defect in the landing square
    refused: np.ndarray       # two heights
    verdict: np.ndarray       # uint8 UNSEEN / UNSAFE / UNDECIDED / SAFE
    patch: np.ndarray         # int32: the patch of cells the raised-surface rule tested (1, 2, ...; 0: none)
    steps: StepFits           # the fitted steps and how they are read (what holds a square's step test)
    patch_tests: tuple[Raised, ...] = ()   # the rule's finding per patch (patch k: [k - 1]), best patch first
    funnel: CellFunnel | None = None       # the cells each test of the verdict left (``fusion/funnel.py``)
    whole: np.ndarray | None = None        # the seen cells whose four maps rest on their windows (none scored 0 for
                                           # a window too little seen)
    covered: np.ndarray | None = None      # the cells whose landing square and the windows around it are seen whole
                                           # (what ``decided`` needs besides the noise)
    column: np.ndarray | None = None       # the cells whose landing square's column was seen clear whole

    def counts(self) -> dict[str, int]:
        return {name: int(np.count_nonzero(self.verdict == code)) for code, name in VERDICT_NAMES.items()}

    @property
    def raised(self) -> np.ndarray:
        """The cells of the patches the raised-surface rule refused (SAFE but for it: UNSAFE where raised beyond
        doubt, else UNDECIDED)."""
        return np.array([False, *(t.refused for t in self.patch_tests)])[self.patch]

    def raised_lead(self) -> str:
        """A no-site reason's lead when the best patch the rule refused is raised: what the user must hear first
        (as the per-frame path's ``select.raised_lead``); "" when the rule refused none."""
        best = next((t for t in self.patch_tests if t.refused), None)
        return "" if best is None else f"the best site is {best.reason()}; "

    def why_none(self, camera_depth_m: float | None = None) -> str:
        """Why no cell here is SAFE (``CellFunnel.text``), with the weakest map and the slope where the score
        threshold left none (medians over the cells whose maps rest on their windows, taken only then)."""
        f = self.funnel
        if f is None:
            return "no verdict"
        if f.emptied_by() == "score" and self.whole is not None:
            ok = self.whole
            maps = {"depth_variance": self.depth_variance, "flatness": self.flatness,
                    "inclination": self.inclination, "steepness": self.steepness}
            medians = {name: float(np.median(m[ok])) for name, m in maps.items()} if ok.any() else {}
            finite = ok & np.isfinite(self.slope_deg)
            weakest = min(medians.items(), key=lambda kv: kv[1]) if medians else None
            if finite.any():
                f = replace(f, slope_deg=float(np.median(self.slope_deg[finite])),
                            slope_limit_deg=float(np.median(self.slope_min_deg[finite])))
            f = replace(f, weakest=weakest)
        return f.text(camera_depth_m)


def _box(a: np.ndarray, n: int) -> np.ndarray:
    return cv2.boxFilter(a, cv2.CV_64F, (n, n), normalize=False, borderType=cv2.BORDER_CONSTANT)


def _window_terms(hz: np.ndarray, ok: np.ndarray, cell: float) -> tuple[np.ndarray, ...]:
    """The per-cell terms whose n x n window sums give ``_window_moments`` at any n (``hz`` 0 where not seen):
    the weight w and w x, w y, w h, w x x, w y y, w x y, w x h, w y h, w h h, each product once (w x x is (w x) x,
    the same bits). The maps' three window sizes share them."""
    w = ok.astype(np.float64)
    ny, nx = hz.shape
    x = np.broadcast_to(np.arange(nx, dtype=np.float64)[None, :] * cell, hz.shape)
    y = np.broadcast_to(np.arange(ny, dtype=np.float64)[:, None] * cell, hz.shape)
    wx, wy, wh = w * x, w * y, w * hz
    return w, wx, wy, wh, wx * x, wy * y, wx * y, wx * hz, wy * hz, wh * hz


def _window_moments(terms: tuple[np.ndarray, ...], n: int) -> tuple[np.ndarray, ...]:
    """Over every n x n window of the seen cells (``_window_terms``): the count s1 and the second moments
    sxx, syy, sxy, sxh, syh, shh of (x, y, h) about the window's own centroid (which keeps the sums well
    conditioned), what a plane fit and the surface variation both need."""
    w, wx, wy, wh, wxx, wyy, wxy, wxh, wyh, whh = terms
    s1 = _box(w, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx, my, mh = _box(wx, n) / s1, _box(wy, n) / s1, _box(wh, n) / s1
        sxx = _box(wxx, n) / s1 - mx * mx
        syy = _box(wyy, n) / s1 - my * my
        sxy = _box(wxy, n) / s1 - mx * my
        sxh = _box(wxh, n) / s1 - mx * mh
        syh = _box(wyh, n) / s1 - my * mh
        shh = _box(whh, n) / s1 - mh * mh
    return s1, sxx, syy, sxy, sxh, syh, shh


def _plane_fit(h: np.ndarray, ok: np.ndarray, n: int, cell: float,
               terms: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                                    np.ndarray]:
    """Least-squares plane over every n x n window of cells: (slope gradient gx, gy (m/m), residual variance,
    valid, the window's count of seen cells). A window needs 3/4 of its cells seen. ``terms``: the
    ``_window_terms`` of (h where ``ok`` else 0, ``ok``) when the caller has them."""
    if terms is None:
        terms = _window_terms(np.where(ok, h, 0.0), ok, cell)
    s1, sxx, syy, sxy, sxh, syh, shh = _window_moments(terms, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        det = sxx * syy - sxy * sxy
        gx = (syy * sxh - sxy * syh) / det
        gy = (sxx * syh - sxy * sxh) / det
        res = np.maximum(shh - gx * sxh - gy * syh, 0.0)
    valid = ok & (s1 >= 0.75 * n * n) & (det > 0)
    return gx, gy, res, valid, s1


def _odd(x: float) -> int:
    k = max(1, math.floor(x))
    return k if k % 2 == 1 else max(1, k - 1)


@functools.lru_cache(maxsize=8)
def step_kernel(rows: int, half: int) -> tuple[np.ndarray, float]:
    """The least-squares estimate of a step across the middle column of a ``rows`` x ``2 half + 1`` window,
    fitted together with a plane (h = a + b x + c y + s [x > 0]) over every column but the middle one: the
    kernel giving s as a weighted sum of the window's heights (0 on the middle column), and its squared norm
    (var(s) = norm x sigma^2 for independent cell errors). The middle column is left out because a step
    rarely falls on a cell border: the cell it crosses averages both levels, and a step fitted at a border
    would see two half steps. A plane, tilted any way, gives s = 0."""
    x = np.arange(2 * half + 1, dtype=np.float64) - half
    y = np.arange(rows, dtype=np.float64) - (rows - 1) / 2.0
    X, Y = np.meshgrid(x, y)
    use = (X != 0).ravel()
    A = np.stack([np.ones(X.size), X.ravel(), Y.ravel(), (X.ravel() > 0).astype(np.float64)], axis=1)
    flat = np.zeros(X.size)
    flat[use] = np.linalg.pinv(A[use])[3]
    w = flat.reshape(X.shape)
    return w, float(np.sum(w * w))


def step_fits(hc: np.ndarray, ok: np.ndarray, rows: int, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The step s fitted across every cell along x (a step between columns, the kernel's rows running along
    y) and along y, signed (up towards +x / +y), each NaN where its window is not fully seen."""
    w, _ = step_kernel(rows, half)
    ok8 = ok.astype(np.uint8)
    out = []
    for kern in (w, np.ascontiguousarray(w.T)):
        est = cv2.filter2D(hc, cv2.CV_64F, kern, borderType=cv2.BORDER_CONSTANT)
        # every cell the kernel weighs is seen (beyond the region: not): a minimum, not a sum of ones
        full = cv2.erode(ok8, (kern != 0).astype(np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        out.append(np.where(full, est, np.nan))
    return out[0], out[1]


_HALF_NORMAL_MEDIAN = 0.6745     # median of |z| for a standard normal z


def step_noise_scale(s_abs: np.ndarray, step_min: np.ndarray, k: float) -> float:
    """How much the fitted steps scatter beyond their stated noise (step_min / k) over a region (>= 1): the
    median of |s| / (step_min / k) over its fitted cells, over the half-normal median. Mostly level ground,
    so the median reads the noise; real steps can only raise it. The stated noise is the per-frame limit
    scaled by the fused std, which knows each cell's variance but not how the errors of neighbouring cells
    go together: flown over, a cell averages the pattern fixed to the image along the track, so its errors
    form stripes along it that a step across the track reads."""
    fin = np.isfinite(s_abs) & np.isfinite(step_min) & (step_min > 0)
    if not fin.any():
        return 1.0
    return max(1.0, kernels.median_inplace(s_abs[fin] / (step_min[fin] / k)) / _HALF_NORMAL_MEDIAN)


def _erode(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Where every cell of the rows x cols window around a cell is set (beyond the region: not)."""
    return cv2.erode(a.astype(np.uint8), np.ones((rows, cols), np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0) > 0


def step_passes(s_x: np.ndarray, s_y: np.ndarray, lim_x: np.ndarray, lim_y: np.ndarray, n_sq: int, reach: int,
                max_step_m: float) -> np.ndarray:
    """The cells whose landing square (n_sq cells) passes the step test: |s| + limit within the UAV's step on every
    window centred in the square (each fully seen), and on every window whose middle column crosses the square
    centred up to ``reach`` cells beyond it along the line the step runs (y for a step between columns), where
    seen. Why beyond: a step that ends in the square (a block's corner) fills only part of the rows of a window
    centred there (the one centred on its end reads (reach + 1) / rows of it: 0.057 m of a 0.095 m block's
    corner, called safe); the windows beyond read it whole wherever it runs on for a footprint."""
    with np.errstate(invalid="ignore"):
        fine_x = s_x + lim_x <= max_step_m
        fine_y = s_y + lim_y <= max_step_m
    fine = _erode(fine_x & fine_y, n_sq, n_sq)
    fine &= _erode(fine_x | np.isnan(s_x), n_sq + 2 * reach, n_sq)    # steps between columns, rows along y
    fine &= _erode(fine_y | np.isnan(s_y), n_sq, n_sq + 2 * reach)
    return fine


def fused_maps(reg: Region, config: Config, params: FusionParams, scorer: object) -> FusedMaps:
    """The maps, score, mask and verdict of a region of the fused grid."""
    cell = reg.cell_m
    terrain, uav = config.terrain, config.uav
    k = params.confidence_sigma
    seen = reg.seen
    refused = seen & (reg.rejected > params.two_heights_fraction * np.maximum(reg.frames, 1))
    ok = seen & ~refused
    h = np.where(ok, reg.h, np.nan)
    ref = kernels.median_inplace(h[ok & ~np.isnan(h)]) if ok.any() else 0.0     # np.nanmedian(h)
    hc = np.where(ok, h - ref, 0.0)
    var = np.where(ok, reg.var, 0.0)
    var_mean = np.where(ok, var, 0.0)

    # depth variance: residual std about the 3 x 3 plane, the fused noise's share removed
    dv = terrain.depth_variance
    terms = _window_terms(hc, ok, cell)     # hc is 0 where not ok: the terms every window size sums
    _, _, res3, ok3, n3 = _plane_fit(hc, ok, 3, cell, terms)
    with np.errstate(invalid="ignore", divide="ignore"):
        noise3 = _box(var_mean, 3) / np.maximum(n3, 1) * (n3 - 3) / np.maximum(n3, 1)
    s = np.sqrt(np.maximum(res3 - noise3, 0.0))
    depth_variance = np.where(ok3, np.exp(-s / dv.s0_m), 0.0)

    # steepness: the plane over the footprint's cells (the widest window the per-frame path uses)
    n_fp = max(3, _odd(max(uav.footprint_m) / cell))
    gx, gy, _, okf, n_seen_fp = _plane_fit(hc, ok, n_fp, cell, terms)
    tan_psi = np.hypot(np.where(okf, gx, 0.0), np.where(okf, gy, 0.0))   # a degenerate window's gradient is inf
    psi = np.arctan(tan_psi)
    slope_deg = np.where(okf, np.degrees(psi), np.nan)
    steepness = np.where(okf, np.exp(-(psi / math.radians(uav.max_slope_deg)) ** 2), 0.0)

    # inclination: surface variation of the cells within radius_m (an equal-area square)
    inc = terrain.inclination
    n_r = max(3, _odd(2.0 * _EQUAL_AREA_HALF_SIDE * inc.radius_m / cell))
    s1, cxx, cyy, cxy, cxh, cyh, chh = _window_moments(terms, n_r)
    with np.errstate(invalid="ignore", divide="ignore"):
        chh = np.maximum(chh - _box(var_mean, n_r) / s1, 0.0)
        lam = eigvalsh3(cxx, cxy, cxh, cyy, cyh, chh)
        lam = np.maximum(lam, 0.0)
        curv = lam[..., 0] / np.sum(lam, axis=-1)
    okr = ok & (s1 >= max(inc.min_points, 0.5 * n_r * n_r))
    inclination = np.where(okr & np.isfinite(curv), np.exp(-np.nan_to_num(curv) / inc.curvature_ref), 0.0)

    # flatness: distance to the nearest significant step, refused or unseen cell
    ny, nx = hc.shape
    step_edge = np.zeros(hc.shape, bool)
    for dy, dx in ((0, 1), (1, 0)):
        a, b = hc[: ny - dy, : nx - dx], hc[dy:, dx:]
        both = ok[: ny - dy, : nx - dx] & ok[dy:, dx:]
        sd = np.sqrt(var[: ny - dy, : nx - dx] + var[dy:, dx:])
        big = both & (np.abs(a - b) > np.maximum(uav.max_step_m, k * sd))
        step_edge[: ny - dy, : nx - dx] |= big
        step_edge[dy:, dx:] |= big
    # unseen cells are not edges here (as the image border is not in 2.3.2): a landing square must be seen
    # whole to be decided, so what an unseen cell may hide already keeps every square over it from SAFE,
    # while counting the edge of the seen ground as an edge called ground beside it unsafe
    clear = (~refused & ~step_edge).astype(np.uint8)
    dist = cv2.distanceTransform(clear, cv2.DIST_L2, 5) * cell if not clear.all() else \
        np.full(hc.shape, float(max(hc.shape)) * cell, np.float32)
    flatness = np.where(ok, np.minimum(dist / terrain.flatness.clearance_m, 1.0), 0.0)

    maps = {"depth_variance": depth_variance, "flatness": flatness, "inclination": inclination,
            "steepness": steepness}
    score = scorer.score_arrays({n: m.astype(np.float32) for n, m in maps.items()}, ok)  # type: ignore[attr-defined]

    # the mask: smoothed score, its minimum over the landing square, the threshold
    mc = config.mask
    sm = score
    kk = 1
    if mc.smooth_m > 0:
        sg = mc.smooth_m / cell
        kk = max(3, round(sg * 8 + 1) | 1)
        sm = cv2.GaussianBlur(score.astype(np.float32), (kk, kk), sg)
        sm = np.where(ok, sm, 0.0).astype(np.float32)
    n_sq = square_cells(params.square_m, cell)
    kernel = np.ones((n_sq, n_sq), np.uint8)
    clear_score = cv2.erode(sm.astype(np.float32), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    thr = scorer.threshold  # type: ignore[attr-defined]
    mask = clear_score > thr

    # the limits of the per-frame path, scaled by the cell's fused std (correlated noise at coarser scales
    # included, as limits.working_scale evaluates it)
    sd_cell = np.sqrt(np.where(ok, var, 0.0))
    step_min = np.where(ok, reg.step_ratio * sd_cell, np.inf)        # an unseen cell hides everything
    tan_min = np.where(ok, reg.tan_ratio * sd_cell, np.inf)
    slope_min = np.degrees(np.arctan(tan_min))

    def limits_within(m: float) -> np.ndarray:
        return ok & (m * step_min <= uav.max_step_m) & (m * tan_min <= math.tan(math.radians(uav.max_slope_deg)))
    # a step across every cell, fitted with a plane over the footprint's window, and the plane's slope. Their
    # noise at k sigma is the per-frame path's limit scaled by the fused std (step_min, tan_min: it holds the
    # noise's correlation between neighbouring cells, which a sum over independent cells would not). SAFE
    # needs both upper bounds (estimate + limit) within the UAV's tolerance, UNSAFE a lower bound beyond it;
    # in between the noise still hides what the UAV cannot take
    half = max(2, n_fp // 2)
    s_x, s_y = (np.abs(s) for s in step_fits(hc, ok, n_fp, half))
    # each direction's limit as its fitted steps scatter on this map (the errors' stripes are directional)
    scale_x, scale_y = step_noise_scale(s_x, step_min, k), step_noise_scale(s_y, step_min, k)
    lim_x, lim_y = scale_x * step_min, scale_y * step_min
    tan_lim = math.tan(math.radians(uav.max_slope_deg))
    # (a known defect at k + 1 sigma: a square holds ~240 step estimates, and at k alone noise would mark
    # some level squares unsafe)
    kb = (k + 1.0) / k
    with np.errstate(invalid="ignore"):
        step_bad = (s_x - kb * lim_x > uav.max_step_m) | (s_y - kb * lim_y > uav.max_step_m)
        # the limits hold for a full window: a plane over a window cut by the edge of the seen ground is neither
        full = n_seen_fp >= n_fp * n_fp - 0.5
        slope_fine = okf & full & (tan_psi + tan_min <= tan_lim)
        steep = okf & full & (tan_psi - kb * tan_min > tan_lim)
    # decided over the square and the widest window around it (the maps' and the smoothing's): every score of
    # the square then rests on full windows (a window cut by the edge of the seen ground scores 0, which is
    # not a finding)
    n_dec = n_sq + 2 * max(n_fp // 2, n_r // 2, 1) + 2 * (kk // 2)
    def square_within(m: float) -> np.ndarray:
        return _erode(limits_within(m), n_dec, n_dec)

    decided = square_within(params.decided_margin)
    # a failing mask is a finding only where the noise is well within the tolerances: near them, noise alone
    # fails the mask of level ground (the maps read it as roughness)
    mask_conclusive = decided if params.unsafe_margin == params.decided_margin else square_within(params.unsafe_margin)
    # the slope of every window centred in the square, the steps of those and of the windows beyond it
    reach = n_fp // 2
    fine = _erode(slope_fine, n_sq, n_sq) & step_passes(s_x, s_y, lim_x, lim_y, n_sq, reach, uav.max_step_m)
    bad = steep | refused | step_bad      # a step between two neighbours only lowers the flatness map
    defect = cv2.dilate(bad.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0

    verdict = np.full(hc.shape, UNSEEN, np.uint8)
    # the final descent's column above every cell of the landing square, not only its centre: the UAV's body comes
    # down over the whole square (a tree crown's rim beside a site overhangs its edge, not its middle)
    column = _erode(reg.column, n_sq, n_sq)
    safe = ok & mask & decided & fine & column
    patch, tests = raised_patches(reg, ok, safe, clear_score, raised_params(config))
    # a patch the rule refuses is not safe: UNSAFE where it is raised beyond doubt, UNDECIDED where its height is
    # not told from the tolerance (fewer looks or a higher camera than it needs)
    held = np.array([False, *(t.refused for t in tests)])[patch]
    raised = np.array([False, *(t.raised for t in tests)])[patch]
    safe &= ~held
    unsafe = seen & ~safe & (defect | (~mask & mask_conclusive) | refused | raised)
    verdict[seen] = UNDECIDED
    verdict[unsafe] = UNSAFE
    verdict[safe] = SAFE
    left, cells = [], seen
    for test in (seen, mask, decided, ok & fine, column, ~held):   # in the order of CELL_STEPS
        cells = cells & test
        left.append(int(np.count_nonzero(cells)))
    whole = ok & ok3 & okf & okr
    covered = _erode(ok, n_dec, n_dec)
    funnel = CellFunnel(tuple(left), float(thr), float(clear_score[seen].max()) if seen.any() else None,
                        int(np.count_nonzero(whole)), n_fp * cell, int(np.count_nonzero(seen & mask & covered)),
                        n_dec * cell, int(np.count_nonzero(unsafe)), uav.max_step_m, uav.max_slope_deg,
                        config.control.desired_depth_m)
    f32 = {n: m.astype(np.float32) for n, m in maps.items()}
    return FusedMaps(reg, f32["depth_variance"], f32["flatness"], f32["inclination"], f32["steepness"],
                     slope_deg.astype(np.float32), score.astype(np.float32), mask, clear_score,
                     step_min.astype(np.float32), slope_min.astype(np.float32), decided, defect, refused, verdict,
                     patch, StepFits(s_x, s_y, scale_x, scale_y, reach, kb), tests, funnel, whole, covered, column)


def _site_rank(safe: np.ndarray, clear_score: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per cell: its distance (cells) to the nearest cell that is not ``safe``, and the site's rank (that
    distance, ties: the higher cleared score; -1 where not safe)."""
    dist = cv2.distanceTransform(safe.astype(np.uint8), cv2.DIST_L2, 5).astype(np.float64)
    return dist, np.where(safe, dist + 1e-3 * clear_score, -1.0)


def raised_patches(reg: Region, ok: np.ndarray, safe: np.ndarray, clear_score: np.ndarray,
                   params: RaisedParams) -> tuple[np.ndarray, tuple[Raised, ...]]:
    """The raised-surface rule once per connected patch (8-neighbours) of ``safe`` cells, at its best cell (the
    site ``best_site`` would take in it), ``ok`` cells (seen, one height) its surroundings: the patch of every
    cell (int32, 0: none; patches numbered best first) and the rule's finding per patch."""
    n_lab, labels = cv2.connectedComponents(safe.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    if n_lab <= 1:
        return labels, ()
    _, rank = _site_rank(safe, clear_score)
    flat_rank, flat_lab = rank.ravel(), labels.ravel()
    idx = np.flatnonzero(flat_lab > 0)
    by = idx[np.lexsort((-flat_rank[idx], flat_lab[idx]))]       # per patch, its cells best first
    best = by[np.r_[True, flat_lab[by][1:] != flat_lab[by][:-1]]]  # each patch's best cell, in label order
    order = np.argsort(-flat_rank[best], kind="stable")           # the patches, best first
    renumber = np.zeros(n_lab, np.int32)
    renumber[1 + order] = np.arange(1, n_lab, dtype=np.int32)
    usable = ok & np.isfinite(reg.h)
    nx = safe.shape[1]
    tests = tuple(_raised_at(reg, usable, int(f) // nx, int(f) % nx, params) for f in best[order])
    return renumber[labels], tests


@dataclass(frozen=True)
class FusedSite:
    """The landing site the fused verdict gives: the safe cell deepest inside safe ground."""

    x_m: float
    y_m: float
    z_m: float
    clearance_m: float     # distance to the nearest cell that is not safe
    score: float
    looks: float
    step_min_m: float
    raised: Raised | None = None   # the raised-surface rule on its patch (``measured`` False: too little around)


def best_site(fm: FusedMaps) -> FusedSite | None:
    """The safe cell farthest from any cell that is not safe (ties: the higher cleared score); None: none. The
    raised-surface rule has already made the raised patches UNSAFE (``fused_maps``); the site carries its
    patch's finding."""
    safe = fm.verdict == SAFE
    if not safe.any():
        return None
    reg = fm.region
    dist, rank = _site_rank(safe, fm.clear_score)
    j, i = np.unravel_index(int(np.argmax(rank)), safe.shape)
    k = int(fm.patch[j, i])
    x0, y0 = reg.origin_m
    return FusedSite(x0 + (i + 0.5) * reg.cell_m, y0 + (j + 0.5) * reg.cell_m, float(reg.h[j, i]),
                     float(dist[j, i] * reg.cell_m), float(fm.score[j, i]), float(reg.looks[j, i]),
                     float(fm.step_min_m[j, i]), fm.patch_tests[k - 1] if k > 0 else None)


def square_cells(square_m: float, cell_m: float) -> int:
    """The landing square's side in cells: odd, so that a cell is its centre (at least 1)."""
    return max(1, 2 * math.ceil((square_m / cell_m - 1) / 2) + 1)


def site_surface(fm: FusedMaps, site: FusedSite, square_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The site's centre on its landing square's plane (world) and that plane's unit normal (z up): the plane
    fitted to the fused heights of the square's cells (least squares; SAFE needs every one of them seen)."""
    reg = fm.region
    c = reg.cell_m
    x0, y0 = reg.origin_m
    i, j = int((site.x_m - x0) // c), int((site.y_m - y0) // c)
    half = square_cells(square_m, c) // 2
    ja, ia = max(0, j - half), max(0, i - half)
    h = reg.h[ja:j + half + 1, ia:i + half + 1].astype(np.float64)
    jj, ii = np.nonzero(np.isfinite(h))
    pts = np.stack([x0 + (ii + ia + 0.5) * c, y0 + (jj + ja + 0.5) * c, h[jj, ii]], axis=1)
    centre, normal = _plane_through(pts, np.array([site.x_m, site.y_m, site.z_m]))
    return centre, normal / np.linalg.norm(normal)


def _plane_through(pts: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares plane z = a + b dx + c dy through ``pts`` (n, 3), dx, dy from ``centre``'s plan
    position: ``centre`` lifted onto it and its upward normal (not unit); with fewer than 3 points ``centre`` as
    given and straight up."""
    if len(pts) < 3:
        return centre.copy(), np.array([0.0, 0.0, 1.0])
    a = np.c_[np.ones(len(pts)), pts[:, 0] - centre[0], pts[:, 1] - centre[1]]
    coef = np.linalg.lstsq(a, pts[:, 2], rcond=None)[0]
    return np.array([centre[0], centre[1], coef[0]]), np.array([-coef[1], -coef[2], 1.0])


def raised_cell(fm: FusedMaps, j: int, i: int, params: RaisedParams) -> Raised:
    """The raised-surface rule for the cell (j, i) of fused maps (``_raised_at``)."""
    return _raised_at(fm.region, fm.region.seen & ~fm.refused & np.isfinite(fm.region.h), j, i, params)


def _raised_at(reg: Region, usable: np.ndarray, j: int, i: int, params: RaisedParams) -> Raised:
    """The raised-surface rule for the cell (j, i): the ``usable`` cells of its landing square are the site's
    points (their plane its surface), the other usable cells within ``params.radius_m`` its surroundings, with
    their fused variance (a window of the region: the rule's cost does not grow with the region)."""
    c = reg.cell_m
    r = math.ceil(params.radius_m / c) + 1
    ny, nx = usable.shape
    ja, jb, ia, ib = max(0, j - r), min(ny, j + r + 1), max(0, i - r), min(nx, i + r + 1)
    jj, ii = np.nonzero(usable[ja:jb, ia:ib])
    jj, ii = jj + ja, ii + ia
    xyz = np.stack([(ii + 0.5) * c, (jj + 0.5) * c, reg.h[jj, ii].astype(np.float64)], axis=1)
    centre = np.array([(i + 0.5) * c, (j + 0.5) * c, float(reg.h[j, i])])
    half = params.inner_radius_m
    own = (np.abs(xyz[:, 0] - centre[0]) <= half) & (np.abs(xyz[:, 1] - centre[1]) <= half)
    pts = xyz[own]
    centre, normal = _plane_through(pts, centre)
    return above_ground(centre, normal, pts, xyz, params, np.array([0.0, 0.0, 1.0]),
                        reg.var[jj, ii].astype(np.float64))
