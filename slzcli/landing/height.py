"""The site's height above the ground and above the start (its words: ``render.height_text``).

The run's world frame has its origin at the first tracked camera (z up), so a site on the ground
below a drone that started 8 m up has z = -8 m. landing.json says what that means: the height
above the start (that z) and above the ground the flight saw (the median height of the SLAM map
points of the site's map: most of what a landing camera sees is ground).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def site_height(center_world: list[float], map_z: np.ndarray, frame_id: str, start_frame: int,
                start_z: float = 0.0) -> dict[str, Any]:
    """landing.json ``site.height``: metres above the start and above the ground, with the frames named.

    ``map_z``: the z of the map points of the site's map segment; ``frame_id``: that map's frame in
    results.mcap (``map``, ``map_1``...); ``start_frame``: the first tracked frame of that map, ``start_z``
    its camera's z (0 for a SLAM map, whose origin that camera is; recorded poses have their own origin).
    """
    z = float(center_world[2])
    ground = float(np.median(map_z)) if len(map_z) else None
    return {
        "above_start_m": round(z - start_z, 3),
        "above_ground_m": None if ground is None else round(z - ground, 3),
        "ground_z_m": None if ground is None else round(ground, 3),
        "frame_id": frame_id,
        "start_frame": start_frame,
        "ground": f"median z of the {len(map_z)} SLAM map points in map frame {frame_id}",
    }
