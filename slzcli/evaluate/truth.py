"""A run against the ground truth of its `slz synth` recording: the sidecar, true poses, the site's truth, ATE/RPE.

The sidecar is loaded here (not by detection, which never imports ``synth/``); the run folder
only writes what these functions return (run.json ``summary.ground_truth``, landing.json
``site.ground_truth``). ``TruthEvaluator`` is a sink of a streaming run: detection never
reads the ground truth, the evaluator is handed every frame's stamp and every detection.
"""

from __future__ import annotations

import logging
from array import array
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np

from slzcli import fingerprint
from slzcli.config import GroundTruthCfg
from slzcli.errors import DatasetError
from slzcli.evaluate.safety import MaskCounts, SiteTruth, mask_counts, site_truth, total, visible_cells
from slzcli.evaluate.slam import ate_by_segment, rpe
from slzcli.synth.groundtruth import BINDING_KEY, UNBOUND, GroundTruth, load_ground_truth, sidecar_paths
from slzcli.types import Frame, FrameRef, ScoreMap

log = logging.getLogger(__name__)


def ground_truth_of(path: Path, cfg: GroundTruthCfg,
                    digests: Callable[[], dict[str, fingerprint.Entry]] | None = None) -> GroundTruth | None:
    """The `slz synth` ground truth beside a recording, or None when it has no sidecar.

    Its frames are looked up by stamp within ``cfg.stamp_tolerance_ms`` (``synth.ground_truth``). A sidecar bound to
    other recording files is refused (DatasetError); ``digests``: the recording's digests a run takes anyway
    (called only for a sidecar bound to its recording).
    """
    if not all(p.is_file() for p in sidecar_paths(path)):
        return None
    tolerance_ns = round(cfg.stamp_tolerance_ms * 1e6)
    gt = load_ground_truth(path)
    json_path = sidecar_paths(path)[1]
    cache = digests() if digests is not None and BINDING_KEY in gt.header else None
    problem = fingerprint.binding_problem(gt.header, Path(path), cache)
    if problem is not None:
        raise DatasetError(json_path, problem)
    if BINDING_KEY not in gt.header:
        log.warning("%s: %s", json_path, UNBOUND)
    return replace(gt, stamp_tolerance_ns=tolerance_ns)


def site_truth_of(truth: GroundTruth, frame: Frame | FrameRef, center_camera: tuple[float, float, float]) -> SiteTruth:
    """The site in the ground-truth world: through the TRUE pose of its frame (not SLAM's)."""
    T = truth.T_world_camera[truth.index_of(frame.stamp_ns)]
    p = T[:3, :3] @ np.asarray(center_camera) + T[:3, 3]
    visible = visible_cells(truth.raster, T, frame.K, frame.shape)
    return site_truth(truth.raster, (float(p[0]), float(p[1])), visible)


def truth_summary(masks: Sequence[MaskCounts], estimated: Sequence[np.ndarray | None],
                  true: Sequence[np.ndarray | None], segments: Sequence[int],
                  site: Mapping[str, object] | None) -> dict[str, object]:
    """run.json ``summary.ground_truth``: mask counts, ATE per map segment and RPE, the site's truth.

    ``site``: landing.json ``site`` (None: no site), whose ``ground_truth`` is reported.
    """
    out: dict[str, object] = {"mask": total(masks).as_dict() if masks else None}
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


class Detected(Protocol):
    """What the evaluator reads of a detection (``pipeline.Detection``)."""

    @property
    def frame(self) -> Frame: ...

    @property
    def score(self) -> ScoreMap: ...


class TruthEvaluator:
    """A run against its ground truth, fed as the run streams: each frame's stamp, each detection.

    Keeps 8 B per frame (the index of its true pose) and one ``MaskCounts`` per detection.
    """

    def __init__(self, truth: GroundTruth) -> None:
        self.truth = truth
        self.masks: list[MaskCounts] = []  # each detection's landing mask against the true safe mask
        self._pose_index = array("q")      # each frame's index in the truth, -1: no true frame at its stamp

    def frame(self, stamp_ns: int) -> None:
        """A frame was tracked: note its true pose, for ATE and RPE."""
        try:
            self._pose_index.append(self.truth.index_of(stamp_ns))
        except DatasetError:
            self._pose_index.append(-1)

    def detection(self, det: Detected) -> MaskCounts:
        """A detection was made: count its landing mask against the true safe mask of its frame."""
        counts = mask_counts(det.score.mask, self.truth.safe_mask(det.frame.stamp_ns))
        self.masks.append(counts)
        return counts

    def true_poses(self) -> list[np.ndarray | None]:
        """The true ``T_world_camera`` of every frame handed in (None: the truth has no frame at its stamp)."""
        T = self.truth.T_world_camera
        return [None if i < 0 else np.asarray(T[i], dtype=np.float64) for i in self._pose_index]

    def summary(self, estimated: Sequence[np.ndarray | None], segments: Sequence[int],
                site: Mapping[str, object] | None) -> dict[str, object]:
        """run.json ``summary.ground_truth`` (``truth_summary``) of the frames and detections handed in."""
        return truth_summary(self.masks, estimated, self.true_poses(), segments, site)
