"""A landing.json written by hand: the input of the `slz land` commands without a detection run before them."""

from __future__ import annotations

import json
from pathlib import Path


def write_landing(folder: Path, status: str = "site") -> Path:
    """``folder``/landing.json with a committed 0.656 m site at (1, -0.5, 0.1), or a "no site" one for any
    other ``status``."""
    folder.mkdir(parents=True, exist_ok=True)
    doc: dict = {"status": status, "method": "fuzzy", "source": "flight.mcap",
                 "frame": {"index": 3, "stamp_ns": 1}, "world_frame": "test", "timings_ms": {}}
    if status == "site":
        c = [1.0, -0.5, 0.1]
        doc["site"] = {"pixel": [320, 240], "center_camera": [0, 0, 5], "center_world": c,
                       "corners_world": [[c[0] + sx * 0.656, c[1] + sy * 0.656, c[2]]
                                         for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1))],
                       "normal_world": [0, 0, 1], "cluster": {}, "score": 0.9}
    else:
        doc["reason"] = "no cluster meets the 0.656 x 0.656 m footprint"
    path = folder / "landing.json"
    path.write_text(json.dumps(doc))
    return path
