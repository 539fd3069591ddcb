"""A run against the ground truth of its `slz synth` recording: the sidecar, true poses, the site's truth, ATE/RPE.

The sidecar is loaded here (not by detection, which never imports ``synth/``); the run folder
only writes what these functions return (run.json ``summary.ground_truth``, landing.json
``site.ground_truth``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from slzcli.config import Config
from slzcli.errors import DatasetError
from slzcli.evaluate.safety import MaskCounts, SiteTruth, site_truth, total, visible_cells
from slzcli.evaluate.slam import ate_by_segment, rpe
from slzcli.synth.groundtruth import GroundTruth, load_ground_truth, sidecar_paths


def ground_truth_of(path: Path, config: Config) -> GroundTruth | None:
    """The `slz synth` ground truth beside a recording, or None when it has no sidecar.

    Its frames are looked up by stamp within ``synth.ground_truth.stamp_tolerance_ms``.
    """
    if not all(p.is_file() for p in sidecar_paths(path)):
        return None
    tolerance_ns = round(config.synth.ground_truth.stamp_tolerance_ms * 1e6)
    return replace(load_ground_truth(path), stamp_tolerance_ns=tolerance_ns)


def true_pose(truth: Any, stamp_ns: int) -> np.ndarray | None:
    """The true ``T_world_camera`` of the frame at ``stamp_ns``, or None when the truth has no such frame."""
    try:
        return truth.T_world_camera[truth.index_of(stamp_ns)]
    except DatasetError:
        return None


def site_truth_of(truth: Any, frame: Any, center_camera: tuple[float, float, float]) -> SiteTruth:
    """The site in the ground-truth world: through the TRUE pose of its frame (not SLAM's)."""
    T = truth.T_world_camera[truth.index_of(frame.stamp_ns)]
    p = T[:3, :3] @ np.asarray(center_camera) + T[:3, 3]
    visible = visible_cells(truth.raster, T, frame.K, frame.shape)
    return site_truth(truth.raster, (float(p[0]), float(p[1])), visible)


def truth_summary(masks: Sequence[MaskCounts], estimated: Sequence[np.ndarray | None],
                  true: Sequence[np.ndarray | None], segments: Sequence[int],
                  site: dict[str, Any] | None) -> dict[str, Any]:
    """run.json ``summary.ground_truth``: mask counts, ATE per map segment and RPE, the site's truth.

    ``site``: landing.json ``site`` (None: no site), whose ``ground_truth`` is reported.
    """
    out: dict[str, Any] = {"mask": total(masks).as_dict() if masks else None}
    try:
        res = ate_by_segment(estimated, true, segments)  # each map segment aligned on its own
    except ValueError:  # fewer than 3 frames with both poses in every segment
        res = None
    if res is not None:
        out["slam_ate_rmse_m"] = res.rmse_m
        out["slam_ate_segments"] = [{"segment": k, "rmse_m": r.rmse_m, "frames": r.n}
                                    for k, r in res.per_segment.items()]
        try:
            rel = rpe(estimated, true, segments=segments)  # consecutive frames of one segment; lost frames skipped
            out["slam_rpe"] = {"trans_rmse_m": rel.trans_rmse_m, "rot_rmse_deg": rel.rot_rmse_deg, "pairs": rel.n}
        except ValueError:  # no two consecutive frames with all four poses
            out["slam_rpe"] = None
    if site is not None:
        out["site"] = site.get("ground_truth")
    return out
