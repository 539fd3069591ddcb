"""Is the depth what the camera could have measured? Range and valid share of a few decoded frames.

A depth image read with the wrong unit decodes without error: a TUM folder of millimetre PNGs
read at the benchmark's 5000 counts per metre puts every depth at 1/5, millimetres read as
metres at 1000x. The maps then run on the wrong scale (the noise estimate grows with it) and
nothing fails. ``slz info`` decodes ``sources.depth_check.frames`` frames spread over the
window and prints the depth's percentiles and valid share, with a warning when most of the
depth lies nearer than the camera's minimum range (its preset's ``min_range_m``, else
``sources.depth_check.min_range_m``) or its median is beyond any camera's reach.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import numpy as np

from slzcli.config import Config, DepthCheckCfg
from slzcli.errors import SlzError
from slzcli.sources.presets import get_preset
from slzcli.sources.recording import RecordingInfo

PERCENTILES = (5, 50, 95)  # of the valid depth, pooled over the frames read
SAMPLE_STRIDE_PX = 4       # every 4th pixel both ways: 1/16 of a frame is plenty for percentiles


@dataclass(frozen=True)
class DepthRange:
    """The chosen depth stream over the frames read: percentiles (m) of its valid depth and the valid share."""

    stream: str
    frames: int
    valid_share: float
    percentiles_m: tuple[float, ...]   # at PERCENTILES; NaN without valid depth
    below_min_share: float             # of the valid depth, nearer than min_range_m
    min_range_m: float
    min_range_source: str
    warning: str = ""
    unread: str = ""                   # why no frame could be read (the check is then empty; info still answers)

    def to_dict(self) -> dict[str, object]:
        return {"stream": self.stream, "frames": self.frames, "valid_share": round(self.valid_share, 4),
                "percentiles_m": {f"p{p}": None if not np.isfinite(v) else round(v, 4)
                                  for p, v in zip(PERCENTILES, self.percentiles_m, strict=True)},
                "below_min_range_share": round(self.below_min_share, 4), "min_range_m": self.min_range_m,
                "min_range_source": self.min_range_source, "warning": self.warning, "unread": self.unread}


def depth_range(depths: Iterable[np.ndarray], stream: str, min_range_m: float, min_range_source: str) -> DepthRange:
    """Percentiles and shares of the depth images (metres, NaN or 0 = no data), each sampled on a pixel grid."""
    samples = [d[::SAMPLE_STRIDE_PX, ::SAMPLE_STRIDE_PX].ravel() for d in depths]
    frames = len(samples)
    pooled = np.concatenate(samples) if samples else np.zeros(0, np.float32)
    valid = pooled[np.isfinite(pooled) & (pooled > 0)]
    pct = tuple(float(v) for v in np.percentile(valid, PERCENTILES)) if len(valid) else (float("nan"),) * 3
    below = float((valid < min_range_m).mean()) if len(valid) else 0.0
    share = len(valid) / len(pooled) if len(pooled) else 0.0
    return DepthRange(stream, frames, share, pct, below, min_range_m, min_range_source)


def implausible(r: DepthRange, cfg: DepthCheckCfg, unit_hint: str) -> str:
    """Why the depth cannot be the camera's, with what to check (``unit_hint``: where the unit is set); "" if none."""
    if not r.frames or not np.isfinite(r.percentiles_m[1]):
        return ""
    median = r.percentiles_m[1]
    if r.below_min_share > cfg.below_min_share:
        return (f"{r.below_min_share:.0%} of the depth is nearer than the camera's minimum range {r.min_range_m:g} m "
                f"({r.min_range_source}; median {median:.3g} m over {r.frames} frame(s)): a stereo camera measures "
                f"little there; the depth unit may be wrong ({unit_hint})")
    if median > cfg.max_median_m:
        return (f"median depth {median:.3g} m over {r.frames} frame(s) is beyond sources.depth_check.max_median_m "
                f"{cfg.max_median_m:g} m: the depth unit may be wrong ({unit_hint})")
    return ""


def unit_hint(info: RecordingInfo) -> str:
    """Where this recording's depth unit is set, for the warning."""
    if info.format == "tum folder":
        return ("a TUM folder's depth scale: camera.yaml depth_scale, counts per metre, 1000 for millimetre PNGs; "
                "else sources.tum_depth_scale")
    return "16-bit depth: sources.depth_unit_16u_m, m per count (REP 118: 0.001)"


def min_range_of(info: RecordingInfo, cfg: DepthCheckCfg) -> tuple[float, str]:
    """The camera's minimum range: its preset's, else the config's."""
    preset = get_preset(info.camera_preset) if info.camera_preset else None
    if preset is not None and preset.min_range_m is not None:
        return preset.min_range_m, f"camera preset {preset.name}"
    return cfg.min_range_m, "sources.depth_check.min_range_m"


def sampling_config(config: Config, paired: int) -> Config:
    """``config`` with its window thinned to about ``sources.depth_check.frames`` pairs spread over it."""
    n = config.sources.depth_check.frames
    w = config.sources.window
    step = max(1, paired // n)
    window = dataclasses.replace(w, stride=w.stride * step, max_frames=n)
    return dataclasses.replace(config, sources=dataclasses.replace(config.sources, window=window))


def check_depth(path: Path, config: Config, info: RecordingInfo) -> DepthRange | None:
    """Decode a few frames of the recording and judge their depth (None: no frame pairs)."""
    from slzcli.sources import open_recording  # sources/__init__ imports the readers

    if info.pairing.paired == 0:
        return None
    cfg = config.sources.depth_check
    stream = next((c.topic for c in info.choices if c.role == "depth"), None) or "depth"
    lo, source = min_range_of(info, cfg)
    try:
        with open_recording(path, sampling_config(config, info.pairing.paired)) as rec:
            depths = [f.depth_m for f in islice(rec.frames(), cfg.frames)]
    except SlzError as err:   # info lists and pairs without decoding; a frame it cannot decode is said, not fatal
        return dataclasses.replace(depth_range([], stream, lo, source), unread=str(err))
    r = depth_range(depths, stream, lo, source)
    return dataclasses.replace(r, warning=implausible(r, cfg, unit_hint(info)))
