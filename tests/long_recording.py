"""Long recordings without rendering every frame: a short synth hover played forwards and backwards.

Rendering costs ~0.4 s a frame, so 10,000 frames would take 45 min. Ping-pong order keeps the
camera motion continuous (SLAM keeps tracking, no jump back to the start); frames are restamped
at ``rate_hz``. Shared by tests/pipeline/test_limits.py and benchmarks/long_run.py.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from slzcli.config import Config
from slzcli.outputs.recording import RecordingWriter
from slzcli.sources import open_recording


def write_ping_pong(seed: Path, out: Path, length: int, config: Config, *, rate_hz: float = 20.0,
                    color_encoding: str = "rgb8", depth_encoding: str = "16UC1") -> Path:
    """``length`` frames of the recording ``seed`` in ping-pong order, as a new MCAP ``out``."""
    with open_recording(seed, config) as rec:
        frames = list(rec.frames())
    cycle = frames + frames[-2:0:-1] if len(frames) > 2 else frames
    t0 = frames[0].stamp_ns
    with RecordingWriter(out, "mcap", color_encoding=color_encoding, depth_encoding=depth_encoding) as w:
        for i in range(length):
            w.write_frame(replace(cycle[i % len(cycle)], index=i, stamp_ns=t0 + round(i * 1e9 / rate_hz)))
    return out
