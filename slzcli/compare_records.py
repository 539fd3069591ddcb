"""What ``slz compare`` reports, as frozen records: per recording and method, per pair of methods, per
recording, per variant, and the comparison as a whole (compare.json); the rows of ``--profiles``.

Built by ``slzcli.compare``; only ``slzcli/outputs/`` turns them into compare.json, compare.csv, report.html,
the figures, the stdout table and the ``--json`` summary (``outputs/records_json.py``: a record's fields in
their declared order are its JSON keys in that order, so reordering a field here reorders compare.json).
The arrays the figures draw (``ComparisonFigures``) are no part of the JSON.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from slzcli.records import (
    FLATTEN,
    OMIT_NONE,
    AcceptanceRecord,
    JsonObject,
    Status,
    SupportRecord,
    UntrackedRecord,
)


# ----------------------------------------------------------------------------- per recording x method
@dataclass(frozen=True)
class StageTimes:
    """``timings_ms[stage]``: median and 90th percentile (ms) over the detection frames; None without any."""

    median_ms: float | None
    p90_ms: float | None


@dataclass(frozen=True)
class CompareSite:
    """A method's committed site in compare.json (the fields ``slz detect``'s landing.json has, flat)."""

    frame: int
    stamp_ns: int
    center_world: tuple[float, float, float]
    center_camera: tuple[float, float, float]
    score: float
    cluster_points: int
    acceptance: AcceptanceRecord
    support: SupportRecord
    map_segment: int


@dataclass(frozen=True)
class InputDigest:
    """What a method was given on one detection frame: the frame and digests of its map points and maps."""

    frame: int
    stamp_ns: int
    points: str
    maps: str


@dataclass(frozen=True)
class MaskTruth:
    """A method's masks against the true safe mask, counted over every pixel of every detection frame."""

    precision: float | None
    recall: float | None
    iou: float | None
    tp: int
    fp: int
    fn: int
    tn: int


@dataclass(frozen=True)
class MethodTruth:
    """A method against the ground truth: its masks (micro-averaged counts), its site, the sweep's area."""

    mask: MaskTruth
    site: JsonObject | None                 # evaluate.truth.SiteTruth.as_dict
    pr_auc: float | None
    false_safe_rate: float | None


@dataclass(frozen=True)
class MethodComparison:
    """One recording x one method: detections, the committed site or why none, times, inputs, truth."""

    method: str
    detections: int
    sites_found: int
    status: Status
    reason: str | None
    timings_ms: Mapping[str, StageTimes]  # slam, maps, score, mask, select, frame
    site_world: tuple[float, float, float] | None  # as slz detect names it
    site: CompareSite | None
    mask_fraction: float | None
    detections_not_vouched: int
    inputs: tuple[InputDigest, ...]
    ground_truth: MethodTruth | None = field(default=None, metadata=OMIT_NONE)


# ----------------------------------------------------------------------------- per pair
@dataclass(frozen=True)
class FrameDistances:
    """The distance of the two methods' sites on the frames where both found one (mean, m)."""

    mean: float | None
    frames: int


@dataclass(frozen=True)
class PairComparison:
    """Two methods on one recording: their committed sites' distance and their masks' agreement."""

    methods: tuple[str, str]
    site_distance_m: float | None  # None: a site missing, or the two in different SLAM map segments
    per_frame_site_distance_m: FrameDistances
    mask_iou: float | None
    masks_empty: bool  # both masks empty in every frame: agreement says nothing
    mask_agreement: float


# ----------------------------------------------------------------------------- per recording
@dataclass(frozen=True)
class CompareSlam:
    """``slam`` of a compared recording: its map segments, ATE against the truth, a digest of its frames."""

    maps: int
    ate_rmse_m: float | None
    frames_digest: str
    untracked: UntrackedRecord = field(default_factory=UntrackedRecord, metadata=FLATTEN)


@dataclass(frozen=True)
class SceneRecord:
    """The ``slz synth`` scene of a recording with ground truth."""

    name: str | None
    variants: tuple[str, ...]
    seed: int | None


@dataclass(frozen=True)
class MapTruth:
    """One terrain map alone against the ground truth: the sweep's area, its mean on safe and unsafe pixels."""

    pr_auc: float | None
    mean_safe: float | None
    mean_unsafe: float | None


@dataclass(frozen=True)
class RecordingComparison:
    """One recording (or a rendered variant of one): every method on the same frames."""

    source: str
    name: str
    frames: int
    detections: int
    slam_backend: str
    tracking: Mapping[str, int]
    keyframes: int
    slam: CompareSlam
    inputs_identical: bool
    methods: Mapping[str, MethodComparison]
    pairs: tuple[PairComparison, ...]
    wall_s: float
    ground_truth: bool
    depth_noise: JsonObject  # terrain.noise summary
    scene: SceneRecord | None = field(default=None, metadata=OMIT_NONE)
    maps: Mapping[str, MapTruth] | None = field(default=None, metadata=OMIT_NONE)
    variant_of: str | None = field(default=None, metadata=OMIT_NONE)  # a variant: its base recording's name


# ----------------------------------------------------------------------------- figures
@dataclass(frozen=True, eq=False)  # holds arrays
class MethodView:
    """What the Figure 6 panel draws of one method on one frame (kept small: float16 score)."""

    score: NDArray[np.float16]
    mask: NDArray[np.bool_]
    projected: NDArray[np.floating] | None  # the SLAM map points in the image (px), N x 2
    kept: NDArray[np.bool_] | None          # the points the mask keeps
    labels: NDArray[np.integer] | None
    corners_px: NDArray[np.floating] | None  # the site's square in the image, 4 x 2


@dataclass(frozen=True, eq=False)  # holds arrays
class FigureFrame:
    """The arrays of one detection frame for the Figure 6 panel."""

    index: int
    rgb: NDArray[np.uint8]
    per_method: Mapping[str, MethodView]


Curve = tuple[NDArray[np.float64], NDArray[np.float64]]  # (precision, recall) per threshold


@dataclass(frozen=True, eq=False)  # holds arrays
class ComparisonFigures:
    """The arrays of one recording's figures (not JSON): the Figure 6 frame, PR curves, timing samples."""

    figure_frame: FigureFrame | None
    curves: Mapping[str, Curve]  # per method, and per terrain map as ``map:NAME``; empty without ground truth
    timings: Mapping[str, Mapping[str, list[float]]]  # per method and stage: ms per detection frame


@dataclass(frozen=True, eq=False)  # holds arrays
class Compared:
    """One recording compared: its record (compare.json) and its figures' arrays."""

    record: RecordingComparison
    figures: ComparisonFigures


# ----------------------------------------------------------------------------- per variant
@dataclass(frozen=True)
class VariantMethod:
    """``variant_table[].methods[m]``: one method's figures on one variant."""

    precision: float | None
    recall: float | None
    iou: float | None
    pr_auc: float | None
    status: Status
    site_safe: object  # SiteTruth ``safe`` (bool), None without a site
    clearance_m: object
    frame_median_ms: float | None


@dataclass(frozen=True)
class MapMeans:
    safe: float | None
    unsafe: float | None


@dataclass(frozen=True)
class VariantChange:
    """A variant's figures minus the base recording's (None where either is missing)."""

    methods: Mapping[str, Mapping[str, float | None]]  # per method: precision, recall, pr_auc
    maps: Mapping[str, float | None]


@dataclass(frozen=True)
class VariantRow:
    """A row of ``variant_table``: one base recording or one of its variants; ``change`` against the base."""

    recording: str
    variant: str
    methods: Mapping[str, VariantMethod]
    maps: Mapping[str, float | None]  # each terrain map's PR AUC
    map_means: Mapping[str, MapMeans]
    site_distance_m: float | None
    mask_iou: float | None
    change: VariantChange | None = field(default=None, metadata=OMIT_NONE)


# ----------------------------------------------------------------------------- the comparison
@dataclass(frozen=True)
class Comparison:
    """``slz compare``: compare.json (with the config) and the ``--json`` summary (with the output folder)."""

    methods: tuple[str, ...]
    config_hash: str
    recordings: tuple[RecordingComparison, ...]
    variants: tuple[RecordingComparison, ...]
    variant_table: tuple[VariantRow, ...]


# ----------------------------------------------------------------------------- --profiles
@dataclass(frozen=True)
class ProfileRow:
    """One recording under one profile: what ``slz compare --profiles`` and benchmarks/ablation.py report."""

    recording: str
    profile: str
    method: str
    frames: int
    detections: int
    slam_backend: str
    tracking: Mapping[str, int]
    slam_maps: int
    ate_rmse_m: float | None
    precision: float | None
    recall: float | None
    iou: float | None
    pr_auc: float | None
    status: Status
    reason: str | None
    site_safe: object
    clearance_m: object
    frame_ms_median: float | None
    maps_ms_median: float | None
    slam_ms_median: float | None


@dataclass(frozen=True)
class ProfileComparison:
    """``slz compare --profiles``: compare.json (with the configs) and the ``--json`` summary."""

    profiles: tuple[str, ...]
    config_hashes: Mapping[str, str]
    recordings: tuple[str, ...]
    rows: tuple[ProfileRow, ...]
