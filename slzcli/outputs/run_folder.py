"""The run folder of ``slz detect`` (DESIGN.md "Run folder") and the ``landing.json`` contract.

Files: run.json, landing.json, sites.csv, points.ply, report.html, trajectory.tum (and trajectory.seg<K>.tum
after a SLAM map reset), keyframes.npz,
frames/NNNNNN/ by ``output.level``: nothing (summary), maps.npz + overlay.png (maps, the default),
+ {depth_variance,flatness,inclination,steepness,score,mask}.png (all; the heat maps with a colour bar
to their right, the mask with a safe/unsafe legend: the values are in maps.npz); report.html (``detect_report``).
Everything here writes into the temporary run folder the pipeline hands it; the folder is
put in place only when all of it is written (``output_dir.build``: only the names a run
writes, ``output_dir.DETECT_NAMES``, are ever replaced; ``ibvs/`` and a user's files stay).

SLAM map segments (``slzcli.slam.segments``): landing.json, trajectory.tum and the map points
of points.ply are in the world frame of one segment, the run's (``map_segment`` in
landing.json, ``summary.slam.segment`` in run.json); run.json ``summary.slam`` lists every
segment with its frames, keyframes, TUM file and results.mcap frame id.

Only serialisation: the landing record, the summary, the no-site reason and the ground-truth figures are
computed by ``slzcli.summary`` and ``slzcli.evaluate.truth`` and handed in (``RunResult``, whose records
``outputs/records_json.py`` writes).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.outputs import files, images
from slzcli.outputs.detect_report import write_detect_report
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.points import write_points_ply
from slzcli.outputs.records_json import from_json, to_json_object
from slzcli.outputs.site_log import SiteLog
from slzcli.outputs.trajectory import KeyframeLog, PoseLog, write_trajectories
from slzcli.records import LandingRecord, RunRecord
from slzcli.types import CommittedSite, Detection, RunResult

# maps.npz: members stored, not deflated (deflating ~5.9 MB of float32 took ~0.35-0.46 s a frame against ~6 ms
# stored: benchmarks/writes.py). The maps are float16 (relative error <= 2**-11: +-0.00025 on the [0, 1] maps,
# +-0.03 deg on slope_deg, +-2 mm at 4 m on edge_distance_m, NaN kept); score stays float32 so that
# score >= mask.threshold gives back the mask exactly, mask and valid stay bool.
MAPS_DTYPE = np.float16
LEVELS = ("summary", "maps", "all")  # output.level, each writing what the one before it writes and more


def to_float16(values: np.ndarray) -> np.ndarray:
    """``values.astype(np.float16)`` bit for bit (round to nearest even, infinities kept, overflow to infinity;
    a NaN stays NaN, only a signalling NaN's payload bits may differ), through OpenCV for a float32 map: its F16C
    conversion takes ~0.5 ms for a 640x480 map against ~1.8 ms for numpy's (benchmarks/writes.py; six maps a
    detection frame)."""
    a = np.asarray(values)
    if a.dtype != np.float32 or a.ndim != 2 or a.size == 0:
        return a.astype(np.float16)
    # x * 1.0 is exact (and keeps -0.0): only the cast rounds. OpenCV takes a scalar operand; its stubs do not say so.
    out = cv2.multiply(a, 1.0, dtype=cv2.CV_16F)  # type: ignore[call-overload]
    return np.asarray(out).reshape(a.shape)


def detection_arrays(det: Detection) -> dict[str, np.ndarray]:
    """The members of one detection's maps.npz (precision: ``MAPS_DTYPE`` above)."""
    maps = {k: to_float16(v) for k, v in det.maps.as_dict().items()}
    out = {"score": np.asarray(det.score.score, np.float32), "mask": det.score.mask, "valid": det.maps.valid,
           "slope_deg": to_float16(det.maps.slope_deg)}
    if det.edge_m is not None:
        out["edge_distance_m"] = to_float16(det.edge_m)
    return {**out, **maps}


def write_detection(run_dir: Path, det: Detection, config: Config, overlay: np.ndarray | None = None) -> None:
    """One detection frame's folder at ``output.level``: maps.npz and the overlay (Figure 6 style) at
    ``maps``, the maps, score and mask as heat maps too at ``all``, no folder at ``summary``.

    ``overlay``: the detection's overlay when the caller drew it already (results.mcap carries it too)."""
    level = config.output.level
    if level == "summary":
        return
    folder = run_dir / "frames" / f"{det.frame.index:06d}"
    arrays = detection_arrays(det)
    files.write_npz_streamed(folder / "maps.npz", arrays, stored=frozenset(arrays))
    images.write_png(folder / "overlay.png", detection_overlay_bgr(det) if overlay is None else overlay,
                     images.PHOTO_PNG)
    if level != "all":
        return
    reverse = config.output.reverse_colormap
    valid = det.maps.valid
    for name, values in det.maps.as_dict().items():
        heat = images.heatmap_bgr(values, reverse=reverse, valid=valid)
        images.write_png(folder / f"{name}.png", images.with_colour_bar(heat, reverse=reverse))
    images.write_png(folder / "score.png", images.with_colour_bar(
        images.heatmap_bgr(det.score.score, reverse=reverse, valid=valid), reverse=reverse))
    images.write_png(folder / "mask.png", images.with_mask_legend(images.mask_png(det.score.mask)))


def landing_json(landing: LandingRecord) -> dict[str, object]:
    """landing.json: the contract in DESIGN.md (``records.LandingRecord``)."""
    return to_json_object(landing)


def run_json(run: RunRecord) -> dict[str, object]:
    """run.json: the run summary, config, rerun key, versions, recording, timings and funnel."""
    return to_json_object(run)


def read_run(landing: Mapping[str, object], run: Mapping[str, object],
             committed: CommittedSite | None = None) -> RunResult:
    """The RunResult of a run folder's landing.json and run.json (``committed``: not stored, None unless given)."""
    record = from_json(RunRecord, run)
    slam = record.summary.slam
    primary = None if slam is None else slam.segment
    return RunResult(from_json(LandingRecord, landing), record, committed, primary,
                     primary if slam is not None and slam.maps > 1 else None)


def write_run(run_dir: Path, result: RunResult, sites: SiteLog, trajectory: PoseLog, keyframes: KeyframeLog) -> None:
    """Everything but the per-frame folders: landing.json, sites.csv, trajectory*.tum, keyframes.npz, points.ply,
    report.html, run.json (in that order; the folder is put in place only after all of them). The report links
    and reads the frame folders: they must be written (not queued) by now."""
    files.write_json(run_dir / "landing.json", landing_json(result.landing))
    sites.write_csv(run_dir / "sites.csv")
    write_trajectories(run_dir, trajectory, result.primary_segment)
    keyframes.write_npz(run_dir / "keyframes.npz")
    write_points_ply(run_dir / "points.ply", *points_by_role(sites, keyframes, result.committed, result.points_segment))
    write_detect_report(run_dir, result, sites, trajectory, result.summary.outputs)
    files.write_json(run_dir / "run.json", run_json(result.run))


def points_by_role(sites: SiteLog, keyframes: KeyframeLog, committed: CommittedSite | None,
                   segment: int | None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """points.ply roles and the clusters of the kept points (the committed detection's k-means labels);
    ``segment``: only that map segment's map points (None: all, a run of one segment)."""
    roles: dict[str, np.ndarray] = {"map": keyframes.map_xyz(segment)}
    clusters: dict[str, np.ndarray] = {}
    if committed is not None:
        roles["kept"], roles["chosen"] = sites.points(committed.found)
        clusters["kept"] = sites.kept_clusters(committed.found)
        labels = clusters["kept"][_rows_in(roles["kept"], roles["chosen"])]
        clusters["chosen"] = np.full(len(roles["chosen"]), labels[0] if len(labels) else -1)
        roles["corner"] = np.asarray(committed.site.corners_world)
    return roles, clusters


def _rows_in(xyz: np.ndarray, subset: np.ndarray) -> np.ndarray:
    """Which rows of ``xyz`` (N,3) are rows of ``subset`` (exact coordinates)."""
    if len(xyz) == 0 or len(subset) == 0:
        return np.zeros(len(xyz), bool)
    rows = np.ascontiguousarray(np.asarray(xyz, np.float64)).view([("", np.float64)] * 3).ravel()
    sub = np.ascontiguousarray(np.asarray(subset, np.float64)).view([("", np.float64)] * 3).ravel()
    return np.isin(rows, sub)
