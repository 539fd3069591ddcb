"""Checks on what a recording claims before slz uses it: intrinsics, stamps, poses.

Pure functions: each returns the reason a value is unusable (or None), and the caller names
the file, topic or key. Nothing here imports the config (``intrinsics_problem`` is ``pinhole.py``'s, which the config's
check of the ``camera`` section uses too).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slzcli.pinhole import intrinsics_problem as intrinsics_problem  # sources/ name it from here
from slzcli.types import Intrinsics

STAMP_MAX_NS = 2**63 - 1  # stamps are int64 nanoseconds everywhere downstream (numpy, MCAP readers, TUM)


def size_problem(k: Intrinsics, width: int, height: int, aspect_tolerance: float) -> str | None:
    """Why intrinsics made for ``k.width x k.height`` cannot be scaled to an image of ``width x height``."""
    if (k.width, k.height) == (width, height):
        return None
    ours, theirs = k.width / k.height, width / height
    if abs(ours - theirs) <= aspect_tolerance * theirs:
        return None
    return (f"intrinsics for {k.width}x{k.height} px do not fit the {width}x{height} px images (aspect ratio "
            f"{ours:.3f} vs {theirs:.3f}, more than sources.intrinsics.aspect_tolerance = {aspect_tolerance:g} "
            "apart): not the calibration of this stream")


def info_frame_problem(info_topic: str, info_frame: str, image_topic: str, image_frame: str) -> str | None:
    """Why a CameraInfo is not the calibration of the image stream it is paired with: both name an optical
    frame, and not the same one (another camera of the same aspect ratio would otherwise be scaled and used).

    An empty frame_id on either side is no evidence (many recorders leave it empty); a leading '/' is
    ignored, as tf2 ignores it.
    """
    ours, theirs = info_frame.strip().lstrip("/"), image_frame.strip().lstrip("/")
    if not ours or not theirs or ours == theirs:
        return None
    return (f"CameraInfo on {info_topic} is for frame '{ours}' but {image_topic} is in frame '{theirs}': the "
            "calibration of another camera; record the CameraInfo published with this image stream, or name it "
            "with sources.topics.camera_info (depth: sources.topics.depth_info)")


def pixel_aspect_problem(k: Intrinsics, max_ratio: float) -> str | None:
    """Why ``k``'s focal lengths look wrong together: pixels far from square (fx, fy swapped or one mis-scaled).

    A warning, not a refusal: anamorphic cameras exist, depth cameras are not among them.
    """
    ratio = max(k.fx, k.fy) / min(k.fx, k.fy)
    if ratio <= max_ratio:
        return None
    return (f"fx = {k.fx:g} px and fy = {k.fy:g} px differ by {ratio:.3g}x (more than "
            f"sources.intrinsics.max_pixel_aspect = {max_ratio:g}): a depth camera's pixels are square, so K is "
            "probably wrong (fx and fy swapped, or one of them scaled for another image size); used as given")


def depth_shape_problem(depth_w: int, depth_h: int, width: int, height: int, aspect_tolerance: float) -> str | None:
    """Why a depth image cannot be resized onto a colour image of ``width x height`` (None: same shape or scale).

    A depth image of the colour's aspect ratio is the colour grid at another resolution (a decimated
    aligned stream) and is resized; any other shape (transposed, half width, a row step misread) would
    be stretched, every depth landing on the wrong pixel, and is refused.
    """
    if (depth_w, depth_h) == (width, height):
        return None
    ours, theirs = depth_w / depth_h, width / height
    if abs(ours - theirs) <= aspect_tolerance * theirs:
        return None
    return (f"depth {depth_w}x{depth_h} px is not of the colour's shape {width}x{height} px (aspect ratio {ours:.3f} "
            f"vs {theirs:.3f}, more than sources.intrinsics.aspect_tolerance = {aspect_tolerance:g} apart): slz never "
            "stretches depth onto colour; record depth aligned at the colour's shape, or a depth stream with its own "
            "CameraInfo of its size and the depth->colour extrinsics (/tf_static), which is registered")


def stamp_problem(stamp_ns: int) -> str | None:
    """Why a stamp cannot be used (negative, or beyond int64 nanoseconds), or None."""
    if stamp_ns < 0:
        return f"stamp {stamp_ns} ns is negative"
    if stamp_ns > STAMP_MAX_NS:
        return f"stamp {stamp_ns} ns is beyond 2^63 ns (year 2262)"
    return None


def pose_problem(T: np.ndarray) -> str | None:
    """Why a 4x4 pose cannot be used (shape, non-finite values, a rotation that is not one), or None."""
    T = np.asarray(T)
    if T.shape != (4, 4):
        return f"pose has shape {T.shape}, expected 4x4"
    if not np.all(np.isfinite(T)):
        return "pose has non-finite values (NaN or inf)"
    return None


@dataclass
class StampCounts:
    """What was wrong with the stamps of one stream, counted over a pass (reported once, at its end)."""

    messages: int = 0
    zero: int = 0          # header stamp 0: the log (receive) time was used
    out_of_range: int = 0  # negative or beyond int64 ns: skipped
    repeated: int = 0      # an earlier message of the stream had the same stamp and other content: skipped
    first_out_of_range: str = ""

    def problems(self) -> list[str]:
        """One phrase per kind of problem, with its count (empty when the stamps were fine)."""
        out = []
        n = self.messages
        if self.zero:
            out.append(f"{self.zero} of {n} message(s) have header stamp 0 (their log time is used instead)")
        if self.out_of_range:
            out.append(f"{self.out_of_range} of {n} message(s) have a stamp out of range and were skipped "
                       f"(first: {self.first_out_of_range})")
        if self.repeated:
            out.append(f"{self.repeated} of {n} message(s) repeat the stamp of a different earlier message and were "
                       "skipped (a stuck or unset clock?)")
        return out
