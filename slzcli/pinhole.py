"""Whether a pinhole model can be used at all: for the recordings' camera models (``sources/``) and the
config's ``camera`` block alike. Plain arithmetic on six numbers, no numpy: ``config/`` checks the
camera block with it at load time without pulling the array stack into ``import slzcli.cli``."""

from __future__ import annotations

import math
from typing import Protocol


class Pinhole(Protocol):
    """What the check reads: ``types.Intrinsics`` and the config's ``camera`` block both have it."""

    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...


def intrinsics_problem(k: Pinhole, min_fov_deg: float, max_fov_deg: float) -> str | None:
    """Why a pinhole model cannot be used, or None: finite, positive focal lengths, a size of at
    least 1x1 px, the principal point inside the image, a field of view within the given range."""
    for name in ("fx", "fy", "cx", "cy"):
        value = getattr(k, name)
        if not math.isfinite(value):
            return f"{name} = {value} is not a finite number"
    for name in ("fx", "fy"):
        if getattr(k, name) <= 0:
            return f"{name} = {getattr(k, name):g} px must be > 0"
    for name in ("width", "height"):
        if int(getattr(k, name)) < 1:
            return f"{name} = {getattr(k, name)} px must be >= 1"
    if not (0 <= k.cx <= k.width and 0 <= k.cy <= k.height):
        return (f"principal point (cx, cy) = ({k.cx:g}, {k.cy:g}) px is outside the {k.width}x{k.height} image")
    for axis, f, size in (("horizontal", k.fx, k.width), ("vertical", k.fy, k.height)):
        fov = math.degrees(2.0 * math.atan(size / (2.0 * f)))
        if not min_fov_deg <= fov <= max_fov_deg:
            name = "fx" if axis == "horizontal" else "fy"
            return (f"{name} = {f:g} px gives a {axis} field of view of {fov:.3g} deg over {size} px, outside "
                    f"sources.intrinsics.min_fov_deg..max_fov_deg = {min_fov_deg:g}..{max_fov_deg:g} deg "
                    "(a focal length in the wrong unit?)")
    return None
