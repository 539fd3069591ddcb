"""The synth flights the detection benchmarks run on: one hover flight per scene, rendered with `slz synth`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCENES = ("clear_field", "parking_lot", "playground", "office", "slopes", "no_site")


def render(folder: Path, frames: int) -> list[Path]:
    """Render every scene into ``folder``; the recordings' paths in SCENES order."""
    out = []
    for scene in SCENES:
        path = folder / f"{scene}.mcap"
        subprocess.run([sys.executable, "-m", "slzcli.cli", "synth", scene, "-o", str(path), "--frames", str(frames)],
                       check=True, stdout=subprocess.DEVNULL)
        out.append(path)
    return out
