"""The part of a recording slz reads: a time window, every Nth pair, at most N pairs (``sources.window``).

``slz detect / compare / info --start --end --stride --max-frames`` set these keys. The readers
apply the window to colour/depth pairs in stamp order, before any image is decoded, and stop
reading the recording once no pair still to come can fall inside it. Offsets (``start_s``,
``end_s``) count from the first pair's stamp, so ``--start 0`` is the recording's first frame
whatever other topics were logged before it; ``start_stamp_s``/``end_stamp_s`` are stamps on the
recording's own clock (``--start @1712345678.25``). The window is half-open: ``[start, end)``.
"""

from __future__ import annotations

from dataclasses import dataclass

from slzcli.config import WindowCfg
from slzcli.errors import ConfigError
from slzcli.types import PairingReport

NS_PER_S = 1_000_000_000
# A stamp this close to a bound counts as on it: seconds in a float resolve 0.24 us at today's epoch
# stamps (2^31 s), so "@1700000000.166666665" cannot be held exactly; 1 us is far below any frame period.
BOUND_TOLERANCE_NS = 1_000


def check_window(w: WindowCfg) -> None:
    """ConfigError naming the keys when the window contradicts itself (each key alone is range-checked)."""
    pre = "sources.window."
    for kind in ("start", "end"):
        if getattr(w, f"{kind}_s") is not None and getattr(w, f"{kind}_stamp_s") is not None:
            raise ConfigError(f"{pre}{kind}_s", f"give {pre}{kind}_s (an offset) or {pre}{kind}_stamp_s (a stamp), "
                                                "not both")
    for a, b in (("start_s", "end_s"), ("start_stamp_s", "end_stamp_s")):
        lo, hi = getattr(w, a), getattr(w, b)
        if lo is not None and hi is not None and hi <= lo:
            raise ConfigError(f"{pre}{b}", f"must be later than {pre}{a} ({lo:g} s), got {hi:g} s: the window "
                                           "would hold no frame")


def is_whole(w: WindowCfg) -> bool:
    """True when the window keeps every pair (the default)."""
    return (w.start_s is None and w.end_s is None and w.start_stamp_s is None and w.end_stamp_s is None
            and w.stride == 1 and w.max_frames == 0)


def describe(w: WindowCfg) -> str:
    """The window in a few words, as a user would give it on the command line."""
    parts = []
    for kind in ("start", "end"):
        off, stamp = getattr(w, f"{kind}_s"), getattr(w, f"{kind}_stamp_s")
        if off is not None:
            parts.append(f"--{kind} {off:g} s")
        elif stamp is not None:
            parts.append(f"--{kind} @{stamp:.9f}".rstrip("0").rstrip("."))
    if w.stride != 1:
        parts.append(f"--stride {w.stride}")
    if w.max_frames:
        parts.append(f"--max-frames {w.max_frames}")
    return " ".join(parts)


@dataclass
class WindowFilter:
    """One pass over a recording's pairs, in stamp order: which are read, and how many were left out."""

    window: WindowCfg
    first_ns: int | None = None  # the first pair's stamp: where offsets count from
    in_window: int = 0           # pairs within [start, end), stride not yet applied
    kept: int = 0
    before: int = 0
    after: int = 0
    strided: int = 0
    over_max: int = 0

    def __post_init__(self) -> None:
        check_window(self.window)

    def _bound(self, offset_s: float | None, stamp_s: float | None) -> int | None:
        if stamp_s is not None:
            return round(stamp_s * NS_PER_S)
        if offset_s is None:
            return None
        return (self.first_ns or 0) + round(offset_s * NS_PER_S)

    def _bounds(self) -> tuple[int | None, int | None]:
        w = self.window
        return self._bound(w.start_s, w.start_stamp_s), self._bound(w.end_s, w.end_stamp_s)

    def keep(self, stamp_ns: int) -> bool:
        """Whether the pair at this stamp is read (counted either way). Call once per pair, in stamp order."""
        if self.first_ns is None:
            self.first_ns = stamp_ns
        lo, hi = self._bounds()
        if lo is not None and stamp_ns < lo - BOUND_TOLERANCE_NS:
            self.before += 1
            return False
        if hi is not None and stamp_ns >= hi - BOUND_TOLERANCE_NS:
            self.after += 1
            return False
        if self.window.max_frames and self.kept >= self.window.max_frames:
            self.over_max += 1
            return False
        index, self.in_window = self.in_window, self.in_window + 1
        if index % self.window.stride:
            self.strided += 1
            return False
        self.kept += 1
        return True

    def done(self) -> bool:
        """True once no pair still to come can be read: ``max_frames`` are read, or a pair past the end
        came (pairs come in stamp order: the pairer refuses a message older than what it settled)."""
        return bool(self.window.max_frames and self.kept >= self.window.max_frames) or self.after > 0

    @property
    def left_out(self) -> int:
        """Pairs seen but not read (outside the window, between strides, over max_frames)."""
        return self.before + self.after + self.strided + self.over_max

    def note(self) -> str | None:
        """One line for the pairing notes (None for the whole recording)."""
        if is_whole(self.window):
            return None
        parts = [f"{n} {what}" for n, what in ((self.before, "before the start"), (self.after, "after the end"),
                                                (self.strided, "between strides"),
                                                (self.over_max, "over --max-frames")) if n]
        return (f"window {describe(self.window)}: {self.kept} frame(s) read"
                + (f", {', '.join(parts)} left out" if parts else "")
                + ("" if self.first_ns is None else f"; offsets from the first pair's stamp "
                   f"{self.first_ns // NS_PER_S}.{self.first_ns % NS_PER_S:09d} s"))

    def as_dict(self) -> dict[str, object]:
        """run.json / slz info ``window``: the keys as set and what they left out."""
        w = self.window
        return {"start_s": w.start_s, "end_s": w.end_s, "start_stamp_s": w.start_stamp_s,
                "end_stamp_s": w.end_stamp_s, "stride": w.stride, "max_frames": w.max_frames,
                "first_stamp_ns": self.first_ns, "read": self.kept, "before_start": self.before,
                "after_end": self.after, "between_strides": self.strided, "over_max_frames": self.over_max}


def no_frames_reason(report: PairingReport) -> str:
    """Why a recording gave no frame: the pairing report's window note when the window left every pair out."""
    notes = [n for n in report.notes if n.startswith("window ")]
    if report.outside_window and notes:
        return f"no RGB-D frame in the window ({notes[-1]})"
    apart = [n for n in report.notes if n.startswith("colour and depth never pair")]
    return f"no RGB-D frame could be read: {apart[0]}" if apart else "no RGB-D frame could be read"
