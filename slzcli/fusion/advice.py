"""What would decide undecided ground: "N more frames", "X m of sideways flight" or "descend to Z m".

For the undecided landing square with the best cleared score, the factor its fused noise must still
shrink by is ``r = m max(step_min / max_step, tan(slope_min) / tan(max_slope))`` over the square, m the
larger of ``terrain.fusion.decided_margin`` (the gate on the noise alone) and 2: ``verdict`` calls a square
safe when the fitted step plus its limit stays within the UAV's tolerance, and over a square of cells the
largest fitted step of level ground is about the limit itself (estimate + limit ~ 2 limits); and at least what
that tolerance test reads now where the step or slope is the noise's (estimate + limit over the tolerance: both
shrink with the noise; the largest of hundreds of fitted steps is often more than one limit). The cell's
own Kalman filter (``grid``'s model: a shared error that decorrelates as exp(-shift / decorrelation_px)
with the cell's shift in the image, and a white part) is then run forward:
- frames: at the image shift per frame the flight has now; holding position (a hover: its net ground speed
  over the recent frames below ``terrain.fusion.hover_speed_m_s``, ``GroundTrack``) at no shift at all: a
  hover's drift and attitude wobble go back and forth over the same views, so what they shift a cell by
  between frames is not a motion that keeps decorrelating the shared error (the issue's stereo renderer:
  20 hovering frames 0.055 -> 0.049 m), and when the variance cannot get below the target without it, the
  answer is to move;
- sideways: one look every ``decorrelation_px`` of image shift (metres at the altitude: px x z / f);
- descend: the per-frame limits grow as z^2 (sigma_z = a z^2 over metric windows), so one frame decides
  from ``z / sqrt(r1)``, r1 the factor of a single frame at the current altitude.
Noise is not always what holds a square: where the slope fitted over it or a step fitted across it (beyond
its own limit: a finding, not noise) already reads the UAV's tolerance or more, no look will make it safe
(the limit only shrinks towards the estimate), and the advice says what it reads instead of promising
frames (the one further beyond its tolerance); level ground reading that steep means the run's gravity is
off. A step is read along its run (the median of the windows along it), not by its largest window, which
the noise biases up.
A loop over future frames of a handful of cells, never over pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from slzcli.fusion.grid import Region
from slzcli.fusion.measure import FusionParams
from slzcli.fusion.verdict import UNDECIDED, FusedMaps, square_cells
from slzcli.records import DecideAdvice

_MAX_FRAMES = 1800      # frames; beyond a minute at 30 Hz "N more frames" is not an answer (fly instead)
_STILL_PX = 0.05        # px; image shifts below this are the estimate's own jitter, not motion
_LEVEL_FIT = 2.0        # x the limit; level ground's largest fitted step over a square ~ its limit: estimate + limit
RECENT_FRAMES = 15      # frames the net ground speed is taken over (as the fused terrain's recent image shift)


@dataclass(frozen=True)
class Advice:
    """What would decide the best undecided square (None fields: that way cannot)."""

    x_m: float
    y_m: float
    factor: float                  # how much its fused std must still shrink
    frames: int | None             # more frames at the current motion
    sideways_m: float | None       # metres of sideways flight
    descend_to_m: float | None     # altitude from which one frame decides it
    hover: bool                    # the current motion is (nearly) a hover
    slope_deg: float | None = None       # the square's fitted slope when it alone holds it (at the tolerance or more)
    max_slope_deg: float | None = None   # the UAV's tolerance it is read against
    step_m: float | None = None          # the square's fitted step when it holds it (beyond or near the tolerance)
    max_step_m: float | None = None      # the UAV's tolerance it is read against
    step_beyond: bool = False            # read along its run at the tolerance or more: no look makes it safe

    def text(self) -> str:
        where = f"the ground at ({self.x_m:.1f}, {self.y_m:.1f}) m"
        if self.step_m is not None:
            held = ("more frames will not make it safe" if self.step_beyond else
                    "no flight with this sensor tells it from a step the UAV cannot take")
            return f"{where} reads a step of {self.step_m:.3g} m (the UAV takes {self.max_step_m:.3g} m): {held}"
        if self.slope_deg is not None:
            held = ("more frames will not make it safe" if self.slope_deg >= (self.max_slope_deg or 0.0) else
                    "no flight with this sensor tells it from a slope the UAV cannot take")
            return (f"{where} reads a slope of {self.slope_deg:.1f} deg (the UAV takes {self.max_slope_deg:.0f} deg): "
                    f"{held}; if that ground is level, the run's gravity is off (camera.gravity, camera.mount)")
        if self.hover and self.frames is None:
            moves = [f"fly {self.sideways_m:.1f} m sideways"] if self.sideways_m is not None else []
            if self.descend_to_m is not None:
                moves.append(f"descend to {self.descend_to_m:.1f} m")
            if not moves:
                return f"hovering: more frames will not decide {where}, and no flight would with this sensor"
            return f"hovering: more frames will not decide {where}; move: " + " or ".join(moves)
        parts = []
        if self.frames is not None:
            parts.append(f"{self.frames} more frame{'' if self.frames == 1 else 's'}")
        if self.sideways_m is not None:
            parts.append(f"{self.sideways_m:.1f} m of sideways flight")
        if self.descend_to_m is not None:
            parts.append(f"descend to {self.descend_to_m:.1f} m")
        if not parts:
            return f"{where} cannot be decided with this sensor"
        return f"to decide {where}: " + " or ".join(parts)

    def record(self) -> DecideAdvice:
        """As landing.json and the summary carry it, the figures rounded as the text gives them or finer."""
        return DecideAdvice("fused", self.text(), self.frames,
                            None if self.sideways_m is None else round(self.sideways_m, 2),
                            None if self.descend_to_m is None else round(self.descend_to_m, 2), self.hover,
                            round(self.x_m, 3), round(self.y_m, 3))

    def as_dict(self) -> dict[str, object]:
        """The record's fields and the factor (benchmarks)."""
        r = self.record()
        return {"x_m": r.x_m, "y_m": r.y_m, "factor": round(self.factor, 3), "frames": r.frames,
                "sideways_m": r.sideways_m, "descend_to_m": r.descend_to_m, "hover": r.hover, "text": r.text}


@dataclass
class GroundTrack:
    """The camera's recent positions in the current map segment (mutable: part of a stateful method's state):
    its net horizontal speed over them, first to last, tells a hover from a flight. Net, not summed frame to
    frame: a position hold's drift and wobble go back and forth and add little displacement."""

    segment: int | None = None
    stamps_ns: list[int] = field(default_factory=list)
    xy_m: list[tuple[float, float]] = field(default_factory=list)

    def add(self, segment: int, stamp_ns: int, T_world_camera: np.ndarray) -> None:
        if segment != self.segment:
            self.segment, self.stamps_ns, self.xy_m = segment, [], []
        self.stamps_ns = [*self.stamps_ns, int(stamp_ns)][-RECENT_FRAMES:]
        self.xy_m = [*self.xy_m, (float(T_world_camera[0, 3]), float(T_world_camera[1, 3]))][-RECENT_FRAMES:]

    def speed_m_s(self) -> float:
        """Net horizontal speed over the recent frames (0 before two frames with time between them)."""
        if len(self.stamps_ns) < 2 or self.stamps_ns[-1] <= self.stamps_ns[0]:
            return 0.0
        (x0, y0), (x1, y1) = self.xy_m[0], self.xy_m[-1]
        return math.hypot(x1 - x0, y1 - y0) / ((self.stamps_ns[-1] - self.stamps_ns[0]) * 1e-9)

    def hovering(self, hover_speed_m_s: float) -> bool:
        return self.speed_m_s() < hover_speed_m_s


def frames_to_variance(p_hh: float, p_hc: float, p_cc: float, sigma_c: float, sigma_w: float, shift_px: float,
                       target: float, params: FusionParams, limit: int = _MAX_FRAMES) -> int | None:
    """Frames, each shifting the cell ``shift_px`` in the image, until its height variance is <= ``target``
    (None: not within ``limit``, or never: the variance stalls above the target)."""
    rho = 1.0 if shift_px < _STILL_PX else math.exp(-shift_px / params.decorrelation_px)
    rho = min(rho, 1.0 - 1e-9)
    rv, sc2 = sigma_w * sigma_w, sigma_c * sigma_c
    if rho > 1.0 - 1e-6:
        # a hover: the shared error never decorrelates; endless frames learn h + c exactly, leaving h's
        # variance given h + c
        floor = p_hh - (p_hh + p_hc) ** 2 / max(p_hh + 2.0 * p_hc + p_cc, 1e-300)
        if target <= floor * (1.0 + 1e-6):
            return None
    for n in range(1, limit + 1):
        p_hc_p = rho * p_hc
        p_cc_p = rho * rho * p_cc + (1 - rho * rho) * sc2
        s = p_hh + 2 * p_hc_p + p_cc_p + rv
        kh, kc = (p_hh + p_hc_p) / s, (p_hc_p + p_cc_p) / s
        new_hh = p_hh - kh * kh * s
        p_hc, p_cc = p_hc_p - kh * kc * s, p_cc_p - kc * kc * s
        if new_hh <= target:
            return n
        if p_hh - new_hh <= 1e-12 * p_hh:       # stalled: no frame of this motion will get there
            return None
        p_hh = new_hh
    return None


def _runs_along(s: np.ndarray, known: np.ndarray, fitted: np.ndarray, axis: int) -> np.ndarray:
    """Per line of windows a step runs along (a column of ``s`` for steps between columns, ``axis`` 0; a row for
    ``axis`` 1): the median of the fitted steps of the line's ``fitted`` windows where at least half the line
    is fitted and that median is a finding (beyond the median of ``known``, the finding bar per window), else
    0; broadcast over the line. Every window of a line reads the same step where it runs on: the median reads
    it, while the largest single window is biased up by the noise (the largest of a hundred estimates) and a
    lone window beyond its bar is as likely noise (2 of 135,000 windows of level ground in the tests)."""
    vals = np.where(fitted, s, np.nan)
    out = np.zeros(s.shape)
    use = np.flatnonzero(np.sum(fitted, axis=axis) >= 0.5 * fitted.shape[axis])
    if use.size == 0:
        return out
    lines = (slice(None), use) if axis == 0 else (use, slice(None))
    with np.errstate(invalid="ignore"):
        med = np.nanmedian(vals[lines], axis=axis, keepdims=True)
        bar = np.nanmedian(np.where(fitted, known, np.nan)[lines], axis=axis, keepdims=True)
    out[lines] = np.where(med > bar, med, 0.0)
    return out


def advise(fm: FusedMaps, params: FusionParams, shift_px_per_frame: float, depth_m: float, focal_px: float,
           single_step_m: float, single_tan: float, hover: bool | None = None) -> Advice | None:
    """Advice for the undecided square with the best cleared score (None: nothing undecided is a candidate).

    A candidate is held by what looks can change: its landing square and the maps' windows around it are seen whole
    and the column above the square was seen clear (``kernels.column_clear``). Ground held by too narrow a view, an
    unseen column or an overhang is no candidate for frames: more of the same flight would not decide it, and the
    reason's verdict funnel (``fusion/funnel.py``) says what would. Where no square has its whole column clear,
    squares with their centre's column clear are read for what they hold (a step or a slope beyond the tolerance),
    never promised frames.

    ``shift_px_per_frame``: the current motion (median image shift of cells between frames);
    ``single_step_m`` / ``single_tan``: one frame's limits at ``depth_m`` (``limits.working_scale``);
    ``hover``: the UAV holds position (``GroundTrack.hovering``): more frames are projected without any shift;
    None: judged by the shift alone (a tenth of the decorrelation length a frame).
    """
    reg: Region = fm.region
    base = (fm.verdict == UNDECIDED) & (fm.clear_score > 0) & reg.column
    if fm.covered is not None:
        base &= fm.covered
    whole = base if fm.column is None else base & fm.column
    if whole.any():
        return _advise(fm, whole, params, shift_px_per_frame, depth_m, focal_px, single_step_m, single_tan, hover)
    if not base.any():
        return None
    adv = _advise(fm, base, params, shift_px_per_frame, depth_m, focal_px, single_step_m, single_tan, hover)
    # the square's column is not all seen clear: what it holds is a finding, a promise of frames is not
    return adv if adv is not None and (adv.step_m is not None or adv.slope_deg is not None) else None


def _advise(fm: FusedMaps, cand: np.ndarray, params: FusionParams, shift_px_per_frame: float, depth_m: float,
            focal_px: float, single_step_m: float, single_tan: float, hover: bool | None) -> Advice | None:
    """``advise`` for the best of the candidate cells ``cand``."""
    reg: Region = fm.region
    j, i = np.unravel_index(int(np.argmax(np.where(cand, fm.clear_score, -1.0))), cand.shape)
    half = square_cells(params.square_m, reg.cell_m) // 2
    st = fm.steps
    # the square and, as the verdict reads them, the step windows up to ``reach`` cells beyond it along the step
    far = half + st.reach
    sl = (slice(max(0, j - far), j + far + 1), slice(max(0, i - far), i + far + 1))
    ny, nx = reg.seen[sl].shape
    dy = np.abs(np.arange(sl[0].start, sl[0].start + ny) - j)[:, None]
    dx = np.abs(np.arange(sl[1].start, sl[1].start + nx) - i)[None, :]
    square = (dy <= half) & (dx <= half)
    ok = reg.seen[sl]
    tan_max = math.tan(math.radians(params.max_slope_deg))
    # the slope fitted over a cell's footprint is a finding where it exceeds its own limit (else it is noise)
    tan_lim = np.tan(np.radians(fm.slope_min_deg[sl]))
    tan_fit = np.tan(np.radians(np.nan_to_num(fm.slope_deg[sl], nan=0.0)))
    tan_est = np.where(square & ok & (tan_fit > tan_lim), tan_fit, 0.0)
    tan_found = float(np.max(tan_est, initial=0.0))
    # a fitted step is a finding beyond ``known`` x its limit (the verdict's bar for a known defect: a square
    # holds hundreds of step estimates, and at the limit alone noise puts a few beyond it) on a line of windows
    # that reads it along its run; its limit must fit in what the estimate leaves of the tolerance (safe:
    # estimate + limit)
    step_min = fm.step_min_m[sl].astype(np.float64)
    r_step = np.zeros(ok.shape)
    # what the verdict's tolerance test reads now (SAFE: the fitted step plus its limit within the tolerance),
    # where the step is the noise's (both shrink with it): over a square's hundreds of windows the largest fitted
    # step of level ground is often more than the limit the level fit below assumes (a hover: 2.7 limits)
    r_fit = np.zeros(ok.shape)
    s_read, r1_step = 0.0, 0.0
    for axis, (s_dir, scale) in enumerate(((st.x_m[sl], st.scale_x), (st.y_m[sl], st.scale_y))):
        along = ((dy <= far) & (dx <= half)) if axis == 0 else ((dy <= half) & (dx <= far))
        lim = scale * step_min
        fitted = along & ok & np.isfinite(s_dir) & np.isfinite(lim)
        r_fit = np.maximum(r_fit, np.where(fitted, (np.nan_to_num(s_dir) + np.nan_to_num(lim)) / params.max_step_m,
                                           0.0))
        found = fitted & (np.nan_to_num(s_dir) > st.known * lim)
        if not found.any():
            continue
        runs = _runs_along(s_dir, st.known * lim, fitted, axis)
        s_read = max(s_read, float(np.max(runs)))
        found &= runs > 0
        if not found.any():
            continue
        s_est = np.where(found, s_dir, 0.0)
        with np.errstate(divide="ignore"):
            r_dir = np.where(found, lim / np.maximum(params.max_step_m - s_est, 0.0), 0.0)
        s_max = float(np.max(s_est, initial=0.0))
        r1_step = max(r1_step, single_step_m * scale / (params.max_step_m - s_max)
                      if s_max < params.max_step_m else math.inf)
        r_step = np.maximum(r_step, r_dir)
    x0, y0 = reg.origin_m
    x, y = x0 + (i + 0.5) * reg.cell_m, y0 + (j + 0.5) * reg.cell_m
    if hover is None:
        hover = shift_px_per_frame < 0.1 * params.decorrelation_px
    elif hover:
        shift_px_per_frame = 0.0

    def held_by_step(s_m: float, beyond: bool) -> Advice:
        """Held by a step: what it reads along its run."""
        return Advice(x, y, math.inf, None, None, None, hover, step_m=s_m, max_step_m=params.max_step_m,
                      step_beyond=beyond)

    over_slope, over_step = tan_found / tan_max, s_read / params.max_step_m
    if max(over_slope, over_step) >= 1.0:
        # no look makes it safe (the limit only shrinks towards the estimate): say the one further beyond
        if over_step >= over_slope:
            return held_by_step(s_read, True)
        return Advice(x, y, math.inf, None, None, None, hover, math.degrees(math.atan(tan_found)),
                      params.max_slope_deg)
    with np.errstate(invalid="ignore", divide="ignore"):
        # the slope's limit must fit in what its estimate leaves of the tolerance (safe: estimate + limit)
        r_noise = max(params.decided_margin, _LEVEL_FIT) * np.maximum(step_min / params.max_step_m,
                                                                       tan_lim / tan_max)
        r_slope = tan_lim / (tan_max - tan_est)
        # the slope's tolerance test as it reads now where the fitted slope is the noise's (estimate + limit)
        r_noise = np.maximum(r_noise, np.where(tan_fit > tan_lim, 0.0, (tan_fit + tan_lim) / tan_max))
    r_noise, r_slope = np.where(square, r_noise, -np.inf), np.where(square, r_slope, -np.inf)
    r_cells = np.where(square & ~ok, np.inf, np.maximum(np.maximum(np.maximum(r_noise, r_fit), r_slope), r_step))
    jj, ii = np.unravel_index(int(np.argmax(r_cells)), r_cells.shape)
    r = float(r_cells[jj, ii])
    step_holds = bool(r_step[jj, ii] > max(r_noise[jj, ii], r_fit[jj, ii], r_slope[jj, ii]))
    if not math.isfinite(r):
        # a single window's step at the tolerance, not read beyond it along its run: no look tells which it is
        return held_by_step(s_read, False) if step_holds else Advice(x, y, r, None, None, None, hover)
    var = float(reg.var[sl][jj, ii])
    sc = float(reg.sigma_c[sl][jj, ii])
    sigma1 = float(reg.sigma_1[sl][jj, ii])
    fixed = params.fixed_fraction * sigma1 * sigma1          # the part fixed to the ground: no flight removes it
    p_now = var - fixed
    target = var / (r * r) - fixed
    sw = math.sqrt(max(sigma1 * sigma1 * (1.0 - params.fixed_fraction) - sc * sc, 0.0))
    p_hc, p_cc = float(reg.p_hc[sl][jj, ii]), float(reg.p_cc[sl][jj, ii])
    frames = side = None
    if target > 0:
        frames = frames_to_variance(p_now, p_hc, p_cc, sc, sw, shift_px_per_frame, target, params)
        side = frames_to_variance(p_now, p_hc, p_cc, sc, sw, params.decorrelation_px, target, params)
    sideways = None if side is None else side * params.decorrelation_px * depth_m / focal_px
    r1 = max(max(params.decided_margin, _LEVEL_FIT) * max(single_step_m / params.max_step_m, single_tan / tan_max),
             single_tan / (tan_max - tan_found), r1_step)
    descend = depth_m / math.sqrt(r1) if r1 > 1 else None
    if descend is not None and descend < params.column_m:
        descend = None     # below the final-descent hover: not an answer
    if frames is None and sideways is None and descend is None:
        # nothing decides it: where its step or slope estimate is what holds it, say so rather than blame the sensor
        if step_holds:
            return held_by_step(s_read, False)
        if r_slope[jj, ii] > r_noise[jj, ii]:
            return Advice(x, y, r, None, None, None, hover, math.degrees(math.atan(tan_found)), params.max_slope_deg)
    return Advice(x, y, r, frames, sideways, descend, hover)
