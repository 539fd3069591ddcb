"""The Figure 6 overlay of one detection, drawn once for its frame folder (overlay.png) and results.mcap
(/slz/overlay/compressed).

Its own module so that both writers share it without one importing the other.
"""

from __future__ import annotations

import numpy as np

from slzcli.geometry import project
from slzcli.outputs import images
from slzcli.types import Detection


def detection_overlay_bgr(det: Detection) -> np.ndarray:
    """The Figure 6 overlay of one detection: mask tint, SLAM points, chosen cluster, Eq. 10 square."""
    sel = det.selection
    chosen = corners_px = None
    if sel is not None and sel.site is not None:
        cluster = sel.chosen_cluster()
        chosen = None if cluster is None else sel.labels == cluster
        assert det.T_world_camera is not None  # a site is chosen in view of a posed frame
        corners_px, _ = project(np.asarray(sel.site.corners_world), det.T_world_camera, det.frame.K,
                                det.score.mask.shape)
    valid = det.maps.valid
    same = valid.shape == det.frame.depth_m.shape
    depth = det.frame.depth_m[valid] if same else np.zeros(0)
    ground_m = float(np.median(depth)) if depth.size else float("nan")
    px_per_m = det.frame.K[0, 0] / ground_m if ground_m > 0 else None  # at the median depth in view (the scale bar)
    label = f"frame {det.frame.index}" + (f", median depth {ground_m:.1f} m" if depth.size else "")
    undecided = ~valid
    work = det.maps.work
    if work is not None and same:  # beyond vouch_depth_m the noise hides what the UAV cannot land on
        with np.errstate(invalid="ignore"):
            undecided = undecided | (det.frame.depth_m > work.vouch_depth_m)
        if not work.vouched:
            label += "; cannot vouch for a site here (depth noise)"
    return images.site_overlay_bgr(det.frame.rgb, det.score.mask, None if sel is None else sel.projected,
                                   None if sel is None else sel.kept, chosen, corners_px, undecided=undecided,
                                   label=label, px_per_m=px_per_m)
