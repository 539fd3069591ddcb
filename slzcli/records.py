"""What a detection run reports, as frozen records: the landing record (landing.json), the run summary
(run.json ``summary``, ``slz detect --json``) and the batch row (``summary.json``, ``summary.csv``).

Built by ``slzcli.summary`` and ``slzcli.batch``; only ``slzcli/outputs/`` turns them into JSON and files
(``outputs/records_json.py``; the batch row: ``outputs/batch_summary.py``). A record's fields in their
declared order are its JSON keys in that order, which is the contract of the files: reordering a field
here reorders a file. A field marked ``OMIT_NONE`` is left out of the JSON when None (landing.json has
``reason`` without a site and ``frame``/``site`` with one); ``FLATTEN``: its fields are written at the
level of the record holding it. Parts another module computes and describes (the ground-truth figures,
the depth noise, the gravity, the depth limits) stay JSON objects of that module (``JsonObject``),
read-only here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

JsonObject = Mapping[str, object]  # a JSON object another module describes (evaluate.truth, terrain.noise, ...)
OMIT_NONE = {"json": "omit_none"}   # left out of the JSON when None
OMIT_FALSE = {"json": "omit_false"}  # left out of the JSON when False
FLATTEN = {"json": "flatten"}        # its fields written into the record holding it (when not None)

Status = Literal["site", "no_safe_site"]


# ----------------------------------------------------------------------------- what would decide
# what chose a landing site (types.Site.source, landing.json site.source, run.json summary.site_source)
SITE_FROM_POINTS = "map points"       # a cluster of the SLAM map points on the landing mask (METHOD 2.5)
SITE_FROM_FUSED = "fused terrain"      # the fused verdict's own safe square, its map points too few (METHOD 2.3.6)
SITE_FROM_PX4SLP = "px4slp grid"       # PX4's safe_landing_planner's land-able disk of its grid (docs/PX4SLP.md)


@dataclass(frozen=True)
class DecideAdvice:
    """What would decide the ground a run could not vouch for (landing.json and summary ``advice``).

    ``source``: ``fused`` (the fused map's best undecided square, ``fusion/advice.py``: more frames at the
    current motion, sideways flight or a lower altitude) or ``depth_limits`` (a per-frame method whose
    frames' depth noise hid what the UAV cannot take: the altitude below which one frame could vouch,
    ``terrain.limits.vouchable_altitude_m``). A None field: that way cannot decide it.
    """

    source: Literal["fused", "depth_limits"]
    text: str
    frames: int | None = None          # more frames at the current motion
    sideways_m: float | None = None    # metres of sideways flight
    descend_to_m: float | None = None  # altitude (m above the ground) from which one frame decides it
    hover: bool = False                # the flight was (nearly) a hover: frames alone cannot decide
    x_m: float | None = None           # where: the undecided square's centre in the map frame (fused)
    y_m: float | None = None


# ----------------------------------------------------------------------------- landing.json
@dataclass(frozen=True)
class FrameStamp:
    """landing.json ``frame``: the detection frame the committed site came from."""

    index: int
    stamp_ns: int


@dataclass(frozen=True)
class ClusterRecord:
    """``site.cluster``: the chosen cluster of SLAM map points."""

    points: int
    normal_variance: float
    extent_m: tuple[float, float]


@dataclass(frozen=True)
class AcceptanceRecord:
    """``site.acceptance``: the site's own acceptance test (tilt, edge clearance)."""

    passed: bool
    reason: str
    tilt_deg: float
    edge_clearance_m: float | None


@dataclass(frozen=True)
class SupportRecord:
    """``site.support``: how many detections confirm the committed site (``pipeline.commit``)."""

    detections_agreeing: int
    detections_with_site: int
    detections_with_site_in_map_segment: int


@dataclass(frozen=True)
class SiteHeight:
    """``site.height``: the site above the start and above the ground, in the site's map frame."""

    above_start_m: float
    above_ground_m: float | None
    ground_z_m: float | None
    frame_id: str
    start_frame: int
    ground: str


@dataclass(frozen=True)
class SiteRecord:
    """landing.json ``site``: the committed site (DESIGN.md "landing.json")."""

    pixel: tuple[float, float]
    center_camera: tuple[float, float, float]
    center_world: tuple[float, float, float]
    corners_world: tuple[tuple[float, float, float], ...]
    normal_world: tuple[float, float, float]
    cluster: ClusterRecord
    score: float
    acceptance: AcceptanceRecord
    support: SupportRecord
    depth_limits: JsonObject | None  # terrain.limits.Working of the site's frame (``Working.as_dict``)
    ground_truth: JsonObject | None = field(default=None, metadata=OMIT_NONE)  # evaluate.truth.site_truth_of
    height: SiteHeight | None = field(default=None, metadata=OMIT_NONE)
    source: str = SITE_FROM_POINTS  # what chose it (types.Site.source)


@dataclass(frozen=True)
class SpreadNote:
    """``site_spread``: how many sites this run could commit and whether another run stays within a footprint."""

    sites: int
    stable: bool
    note: str


@dataclass(frozen=True)
class SpreadRecord:
    """``site_spread_m`` and ``site_spread`` of landing.json (``landing.commit.spread_record``)."""

    site_spread_m: float | None
    site_spread: SpreadNote


@dataclass(frozen=True)
class LandingRecord:
    """landing.json: the committed site, or why there is none; the world frame, map segment and timings."""

    status: Status
    method: str
    source: str
    reason: str | None = field(default=None, metadata=OMIT_NONE)  # without a site: why
    frame: FrameStamp | None = field(default=None, metadata=OMIT_NONE)
    site: SiteRecord | None = field(default=None, metadata=OMIT_NONE)
    spread: SpreadRecord | None = field(default=None, metadata=FLATTEN)
    advice: DecideAdvice | None = None  # without a site: what would decide the ground (null: nothing to say)
    world_frame: str = ""
    map_segment: int | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)  # per stage; the method's under its name


# ----------------------------------------------------------------------------- run.json summary
@dataclass(frozen=True)
class SegmentRecord:
    """``summary.slam.segments[]``: one SLAM map segment of the run."""

    segment: int
    frames_tracked: int
    first_frame: int
    last_frame: int
    keyframes: int
    trajectory: str | None
    mcap_frame: str


@dataclass(frozen=True)
class UntrackedRecord:
    """``summary.slam``'s frames the backend gave no pose, their share, and a warning above the limit."""

    frames_untracked: int = 0
    untracked_share: float = 0.0
    warning: str = ""


@dataclass(frozen=True)
class SlamRecord:
    """``summary.slam``: the maps the backend started and the frames it gave no pose."""

    backend: str
    maps: int
    segment: int | None
    segments: tuple[SegmentRecord, ...]
    untracked: UntrackedRecord = field(default_factory=UntrackedRecord, metadata=FLATTEN)


@dataclass(frozen=True)
class PairingRecord:
    """``summary.pairing``: how the recording's frames paired (``types.PairingReport``)."""

    paired: int
    unpaired_color: int
    unpaired_depth: int
    undecodable: int
    outside_window: int
    notes: tuple[str, ...]


@dataclass(frozen=True)
class RunSummary:
    """run.json ``summary``: what ``slz detect`` prints and ``--json`` gives (schema: summary.schema.json)."""

    source: str
    method: str
    frames: int
    detections: int
    status: Status
    site_world: tuple[float, float, float] | None
    site_height: SiteHeight | None
    reason: str | None
    site_spread_m: float | None
    advice: DecideAdvice | None
    slam_backend: str
    tracking: Mapping[str, int]
    slam: SlamRecord | None
    keyframes: int
    timings_ms: Mapping[str, float]
    wall_s: float
    outputs: str
    gravity: JsonObject | None          # slzcli/gravity.py: source, camera tilt, disagreements
    depth_noise: JsonObject             # terrain.noise summary, detections not vouched
    depth_limits: JsonObject | None     # terrain.limits.Working of the site's frame, or of the worst one
    pairing: PairingRecord | None
    ground_truth: JsonObject | None = field(default=None, metadata=OMIT_NONE)  # evaluate.truth.truth_summary
    skipped: bool = field(default=False, metadata=OMIT_FALSE)  # done before with the same key: read back
    site_source: str | None = field(default=None, metadata=OMIT_NONE)  # what chose the site (types.Site.source)


@dataclass(frozen=True)
class RunRecord:
    """run.json: the summary, the config and its hash, the rerun key, versions, the recording, timings, funnel."""

    summary: RunSummary
    config_hash: str
    key: JsonObject          # fingerprint: the rerun key and the digests of the files it covers
    versions: Mapping[str, str]
    config: JsonObject       # Config.to_dict
    recording: JsonObject    # RecordingInfo.to_dict
    timings: Mapping[str, Mapping[str, float]]  # per stage: median, p90, ... (evaluate.timing)
    funnel: JsonObject       # funnel.FunnelLog.as_dict


# ----------------------------------------------------------------------------- a batch row
@dataclass(frozen=True)
class BatchRow:
    """One recording of a batch of ``slz detect``: a row of ``summary.json`` ``recordings`` and summary.csv.

    ``status``: site, no_safe_site (``summary``: the finished run's), failed (``error``; ``error_detail``: the
    error's class and the file or key it names) or interrupted. ``worker``: host:pid of the worker (None: the
    engine itself failed); ``wall_s`` the worker's wall time for it; ``peak_*_rss_mb``: peak resident memory of
    the worker and of its largest child (the ORB-SLAM3 worker), None where not measured.
    """

    recording: str
    run: str
    status: str
    skipped: bool = False
    worker: str | None = None
    wall_s: float | None = None
    frames_per_s: float | None = None
    peak_rss_mb: float | None = None
    peak_child_rss_mb: float | None = None
    error: str | None = None
    error_detail: Mapping[str, str] | None = None
    summary: RunSummary | None = None

    @property
    def finished(self) -> bool:
        """The run ended with a site or without one (or was done before): it has a summary."""
        return self.summary is not None

    @property
    def frames(self) -> int | None:
        return None if self.summary is None else self.summary.frames

    @property
    def site_world(self) -> tuple[float, float, float] | None:
        return None if self.summary is None else self.summary.site_world


@dataclass(frozen=True)
class BatchTotals:
    """What a batch of ``slz detect`` adds up to: ``summary.json`` ``batch`` and ``--json`` ``batch``.

    ``processed``: the recordings run now (not skipped as done before), whose frames ``frames`` counts;
    the rates are over the batch's wall time (None for a batch that took no time).
    """

    engine: str
    workers: int
    recordings: int
    site: int
    no_safe_site: int
    failed: int
    interrupted: int
    skipped: int
    processed: int
    frames: int
    wall_s: float
    frames_per_s: float | None
    recordings_per_min: float | None
    batch_interrupted: bool


@dataclass(frozen=True)
class BatchSettings:
    """How a batch ran, beside its totals in ``summary.json`` ``batch``."""

    scheduler: str | None
    config_hash: str
    force: bool
    timeout_s: float | None
