"""What each test of the fused verdict left of the cells in view, and why nothing there is SAFE, in words.

The per-frame path says which filter emptied its landing mask (``slzcli/funnel.py``); this is the same for
the fused verdict (``fusion/verdict.py``). The tests in the order SAFE takes them, each counted on the cells
the ones before it left:

- ``seen``: cells some frame measured;
- ``score``: the cell's landing square scores above the threshold everywhere (the mask, after ``mask.smooth_m``);
- ``decided``: the fused noise no longer hides a step or slope the UAV cannot take over the square and the maps'
  windows around it (what ``terrain.fusion.decided_margin`` asks), all of them seen;
- ``tolerances``: the steps fitted across the square and the slope of its plane, each with its noise limit added,
  within the UAV's tolerances, one height per cell;
- ``column``: the column above every cell of its landing square seen clear: the final descent's top seen free by
  some frame, and every level above it that a frame had in view seen free by some frame (nothing overhangs it);
- ``safe``: not on a patch the raised-surface rule refused: the SAFE cells.

A low score or an undecided square has two causes the text tells apart: the ground (or its noise, read as
roughness: the slope it reads against what the noise hides) and the coverage (a window seen too little scores
0 and decides nothing, which is no finding about the ground).
"""

from __future__ import annotations

from dataclasses import dataclass

from slzcli.types import emptied_by

CELL_STEPS = ("seen", "score", "decided", "tolerances", "column", "safe")


@dataclass(frozen=True)
class CellFunnel:
    """The cells each test left (``left``, one per ``CELL_STEPS``, non-increasing) and what the reason needs:

    - threshold, best_score: the score threshold and the best landing square's score (None: nothing seen);
    - whole, window_m: the seen cells whose four maps rest on their windows (a map over a window seen too little
      is 0) and the widest window's side (m);
    - covered, decided_window_m: the cells past the score whose landing square and the windows around it are seen
      whole, and that square's side (m);
    - unsafe: the seen cells the verdict calls UNSAFE (a known defect, or a low score its noise cannot explain);
    - the UAV's step and slope tolerances and the descent column's height (m);
    - filled in when the score left none (``FusedMaps.why_none``): the map with the lowest median over the
      ``whole`` cells and that median, their median slope and the median slope their noise hides (deg)."""

    left: tuple[int, ...]
    threshold: float
    best_score: float | None
    whole: int
    window_m: float
    covered: int
    decided_window_m: float
    unsafe: int
    max_step_m: float
    max_slope_deg: float
    column_m: float
    weakest: tuple[str, float] | None = None
    slope_deg: float | None = None
    slope_limit_deg: float | None = None

    def emptied_by(self) -> str | None:
        """The test that left no cell while the one before it left some (None: some cell is SAFE, or none was
        seen)."""
        return emptied_by(self.left, CELL_STEPS)

    def as_dict(self) -> dict[str, int]:
        return dict(zip(CELL_STEPS, self.left, strict=True))

    def text(self, camera_depth_m: float | None = None) -> str:
        """Why no cell in view is SAFE: the test that left none, with the counts and what would change it
        (``camera_depth_m``: the camera's median depth, to say when it flew below the descent column)."""
        text = self._why()
        if camera_depth_m is not None and camera_depth_m < self.column_m and self.left[-1] == 0:
            text += (f"; the camera was {camera_depth_m:.1f} m from the ground, closer than the final descent's hover "
                     f"(control.desired_depth_m {self.column_m:g} m): outside this UAV's envelope (a hand-held or "
                     "bench recording: --profile bench)")
        return text

    def _why(self) -> str:
        n = self.as_dict()
        step = self.emptied_by()
        if n["seen"] == 0:
            return "no cell in view was measured"
        if step is None:
            return f"{n['safe']} of the {n['seen']} cells in view are safe"
        if step == "score":
            return self._score_text(n["seen"])
        if step == "decided":
            if self.covered == 0:
                return (f"the {n['score']} cells whose landing square scores above the threshold are undecided: the "
                        f"ground seen around them is narrower than a landing square with the maps' windows around it "
                        f"({self.decided_window_m:.1f} m), which must be seen whole; a wider view (a higher pass) or "
                        "a pass beside them sees it")
            return (f"the {n['score']} cells whose landing square scores above the threshold are all undecided: "
                    "the fused depth noise still hides a step or slope the UAV cannot take there")
        if step == "tolerances":
            return (f"every one of the {n['decided']} decided cells holds in its landing square a step or a slope "
                    "that its noise limit added puts beyond the UAV's tolerance "
                    f"(uav.max_step_m {self.max_step_m:g} m, uav.max_slope_deg {self.max_slope_deg:g} deg), or ground "
                    "seen at two heights")
        if step == "column":
            return (f"the column above the ground (from control.desired_depth_m {self.column_m:g} m up) was seen "
                    f"clear over the whole landing square of none of the {n['tolerances']} cells that pass every "
                    "other test: something overhangs them, or close to the ground the view is too narrow to see what "
                    "may overhang a site (a higher pass sees more)")
        return f"the {n['column']} cells that pass every other test lie on surfaces the raised-surface rule refused"

    def _score_text(self, seen: int) -> str:
        best = "" if self.best_score is None else f" (best {self.best_score:.2f})"
        text = f"no landing square among the {seen} cells seen scored above {self.threshold:g}{best}"
        if self.whole == 0:
            return (f"{text}: none of them has the ground around it seen enough for the maps (the footprint's "
                    f"{self.window_m:.1f} m square three-quarters seen); the seen ground is patchy: more frames over "
                    "the same ground, with the tracking holding, fill it in")
        text += f"; {self.unsafe} of them unsafe, {seen - self.unsafe} undecided"
        if self.weakest is None:
            return text
        name, median = self.weakest
        text += f"; the lowest of the four maps over the {self.whole} cells whose windows are seen is {name} " \
                f"(median {median:.2f})"
        if name != "steepness" or self.slope_deg is None:
            return text
        if self.slope_limit_deg is not None and self.slope_deg <= self.slope_limit_deg:
            return (f"{text}: the ground reads a median {self.slope_deg:.0f} deg, within the "
                    f"{self.slope_limit_deg:.0f} deg its fused noise hides: the noise, not the ground, may be what "
                    "slopes; more frames over it from a moving camera read it")
        return (f"{text}: the ground in view slopes a median {self.slope_deg:.0f} deg against gravity as slz takes "
                "it; if the camera does not look straight down, give its tilt (camera.mount)")
