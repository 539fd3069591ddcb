"""Configuration: ``configs/default.yaml`` -> frozen dataclasses, checked at every level.

The YAML file holds every value with its unit and source; the dataclasses here hold
only the schema (types, ranges, choices), so a value lives in exactly one place.
Layering: defaults <- ``--profile NAME`` (``configs/profiles/NAME.yaml``) <- ``--config FILE`` <-
``--set a.b=v``. Unknown keys are rejected
with the dotted path and a "did you mean"; wrong types and out-of-range values too.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import re
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from slzcli.errors import ConfigError, short_repr
from slzcli.methods import registry as method_registry


def package_dir(*parts: str) -> Path:
    """A data folder shipped inside the installed package (wheels unpack to real files).

    The repo's ``configs/`` and ``datasets/scenes/`` are links to these folders, so an
    editable checkout and an installed wheel read the same files the same way.
    """
    path = resources.files("slzcli").joinpath(*parts)
    return Path(str(path))


CONFIG_DIR = package_dir("configs")
DEFAULT_CONFIG = CONFIG_DIR / "default.yaml"
PROFILE_DIR = CONFIG_DIR / "profiles"

Normalise = Literal["absolute", "frame"]
OutputLevel = Literal["summary", "maps", "all"]  # output.level / slz detect --outputs


def rng(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
        odd: bool = False, n: int | None = None) -> Any:
    """A schema field with a range: ``lo <= v <= hi`` (``lo < v`` when lo_open), odd ints, list length n."""
    return field(metadata={"lo": lo, "hi": hi, "lo_open": lo_open, "odd": odd, "n": n})


def one_of(names: typing.Callable[[], tuple[str, ...]]) -> Any:
    """A string field (or each string of a list) that must be one of ``names()``, a registry read at check time."""
    return field(metadata={"one_of": names})


_C = typing.TypeVar("_C")
_D = typing.TypeVar("_D", bound="DataclassInstance")

if typing.TYPE_CHECKING:
    from _typeshed import DataclassInstance
    from typing_extensions import dataclass_transform
else:
    def dataclass_transform(**_kwargs: Any) -> Any:
        """At run time a no-op: the marker only tells type checkers what ``schema`` does."""
        return lambda decorator: decorator


@dataclass_transform(frozen_default=True, field_specifiers=(field, rng, one_of))
def schema(cls: type[_C]) -> type[_C]:
    """``@dataclass(frozen=True)``, declared so that type checkers read ``rng(...)`` as a field without a default."""
    return dataclass(frozen=True)(cls)


# ----------------------------------------------------------------------------- schema
@schema
class Mount:
    pitch_deg: float = rng(-90, 90)
    roll_deg: float = rng(-90, 90)


@schema
class CameraCfg:
    fx: float = rng(0, lo_open=True)
    fy: float = rng(0, lo_open=True)
    cx: float = rng(0)
    cy: float = rng(0)
    width: int = rng(1)
    height: int = rng(1)
    mount: Mount
    preset: str


@schema
class Topics:
    color: str
    depth: str
    camera_info: str
    pose: str
    depth_info: str


@schema
class IntrinsicsCheckCfg:
    min_fov_deg: float = rng(0, 180, lo_open=True)
    max_fov_deg: float = rng(0, 180, lo_open=True)
    aspect_tolerance: float = rng(0, 1)


@schema
class WindowCfg:
    start_s: float | None = rng(0)
    end_s: float | None = rng(0, lo_open=True)
    start_stamp_s: float | None = rng(0)
    end_stamp_s: float | None = rng(0, lo_open=True)
    stride: int = rng(1)
    max_frames: int = rng(0)


@schema
class DepthCheckCfg:
    frames: int = rng(1, 1000)
    min_range_m: float = rng(0, lo_open=True)
    below_min_share: float = rng(0, 1)
    max_median_m: float = rng(0, lo_open=True)


@schema
class SourcesCfg:
    topics: Topics
    intrinsics: IntrinsicsCheckCfg
    pose_frame: str
    use_ground_truth_pose: bool
    sync_tolerance_ms: float = rng(0, lo_open=True)
    pose_tolerance_ms: float = rng(0, lo_open=True)
    reorder_window_ms: float = rng(0, lo_open=True)
    depth_unit_16u_m: float = rng(0, lo_open=True)
    tum_depth_scale: float = rng(0, lo_open=True)
    max_depth_m: float = rng(0)
    min_image_px: tuple[int, ...] = rng(1, n=2)
    max_image_px: int = rng(1, 2**30)   # OpenCV refuses to decode more (CV_IO_MAX_IMAGE_PIXELS)
    window: WindowCfg
    read_ahead_frames: int = rng(0, 64)
    depth_check: DepthCheckCfg


@schema
class DepthVarianceCfg:
    kernel_px: int = rng(3, 99, odd=True)
    s0_m: float = rng(0, lo_open=True)
    min_valid_fraction: float = rng(0, 1, lo_open=True)
    normalise: Normalise = "absolute"
    statistic: Literal["plane", "std"] = "plane"


@schema
class FlatnessCfg:
    canny_low: float = rng(0, 255)
    canny_high: float = rng(0, 255)
    blur_px: int = rng(1, 31, odd=True)
    detrend_px: int = rng(0, 255)
    distance_mask: int = rng(3, 5, odd=True)
    clearance_m: float = rng(0, lo_open=True)
    hole_min_m: float = rng(0)
    normalise: Normalise = "absolute"


@schema
class InclinationCfg:
    radius_m: float = rng(0, lo_open=True)
    curvature_ref: float = rng(0, 1 / 3, lo_open=True)
    work_px: int = rng(16, 4096)
    min_points: int = rng(3)
    normalise: Normalise = "absolute"


@schema
class SteepnessCfg:
    normal_px: int = rng(3, 31, odd=True)
    normal_size_m: float = rng(0)
    normal_max_px: int = rng(3, 255, odd=True)
    min_valid_fraction: float = rng(0, 1, lo_open=True)
    normalise: Normalise = "absolute"


@schema
class NoiseEstimateCfg:
    frames: int = rng(1, 1000)
    min_residuals: int = rng(10)
    prior_a_per_m: float = rng(0, lo_open=True)


@schema
class LimitsCfg:
    confidence_sigma: float = rng(0, lo_open=True)
    blocks_per_footprint: float = rng(1)
    finest_block_m: float = rng(0)
    target_margin: float = rng(1)


@schema
class FusionCfg:
    cells_per_footprint: float = rng(1, 64)
    window_m: float = rng(1, lo_open=False)
    samples_per_cell: float = rng(1)
    white_fraction: float = rng(0, 1)
    fixed_fraction: float = rng(0, 1)
    decorrelation_px: float = rng(0, lo_open=True)
    gate_sigma: float = rng(0, lo_open=True)
    two_heights_fraction: float = rng(0, 1, lo_open=True)
    pose_sigma_m: float = rng(0)
    pose_sigma_deg: float = rng(0)


@schema
class TerrainCfg:
    noise: Literal["auto"] | float = rng(0)
    noise_estimate: NoiseEstimateCfg
    limits: LimitsCfg
    fusion: FusionCfg
    depth_variance: DepthVarianceCfg
    flatness: FlatnessCfg
    inclination: InclinationCfg
    steepness: SteepnessCfg


@schema
class FuzzyCfg:
    rules: str
    evaluator: Literal["compiled", "exact"]
    lut_levels: int = rng(3, 128)


@schema
class BayesCfg:
    prior: float = rng(0, 1, lo_open=True)
    eps: float = rng(0, 0.5, lo_open=True)
    threshold: float = rng(0, 1)


@schema
class Px4SlpCfg:  # the ranges of upstream's SafeLandingPlannerNode.cfg / WaypointGeneratorNode.cfg
    grid_size_m: float = rng(1, 20)
    cell_size_m: float = rng(0.1, 10)
    n_points_threshold: float = rng(0, 5000)
    std_dev_threshold_m: float = rng(0, 1)
    smoothing_size: int = rng(-1, 100)
    mean_diff_thr_m: float = rng(0, 1)
    max_n_mean_diff_cells: int = rng(0, 100)
    min_n_land_cells: int = rng(0, 100)
    alpha: float = rng(0, 1)
    beta: float = rng(0, 1)
    can_land_thr: float = rng(0, 1)
    smoothing_land_cell: int = rng(0, 100)
    warm_start: bool


@schema
class ScoringCfg:
    method: str = one_of(method_registry.names)
    fuzzy: FuzzyCfg
    bayes: BayesCfg
    px4slp: Px4SlpCfg


@schema
class MaskCfg:
    threshold: float = rng(0, 1)
    margin_factor: float = rng(0)
    smooth_m: float = rng(0)
    clearance: Literal["plan", "image"]
    plan_cells_per_footprint: float = rng(1, 64)
    plan_samples_per_cell: float = rng(0)


@schema
class UavCfg:
    mass_kg: float = rng(0, lo_open=True)
    inertia_kg_m2: tuple[float, ...] = rng(0, lo_open=True, n=3)
    size_m: tuple[float, ...] = rng(0, lo_open=True, n=3)
    footprint_m: tuple[float, ...] = rng(0, lo_open=True, n=2)
    max_slope_deg: float = rng(0, 90, lo_open=True)
    max_step_m: float = rng(0, lo_open=True)
    margin_m: float = rng(0)
    touchdown_dispersion_m: float = rng(0)
    thrust_min_n: float = rng(0)
    thrust_max_n: float = rng(0, lo_open=True)
    torque_max_n_m: tuple[float, ...] = rng(0, lo_open=True, n=3)
    camera_offset_m: tuple[float, ...] = rng(n=3)
    camera_yaw_deg: float = rng(-180, 180)

    @property
    def clearance_m(self) -> float:
        """Clearance beyond the footprint on every side: the fixed margin plus the measured landing dispersion."""
        return self.margin_m + self.touchdown_dispersion_m


@schema
class LandingCfg:
    every_nth_frame: int = rng(1)
    kmeans_k: int = rng(1, 100)
    normal_radius_m: float = rng(0, lo_open=True)
    min_cluster_points: int = rng(3)
    min_extent_factor: float = rng(0)
    bayes_min_extent_factor: float = rng(0)
    seed: int = rng(0, 2**32 - 1)  # scipy's kmeans2 takes seeds below 2^32 only
    detect_on: Literal["keyframes", "every_nth"]
    depth_points_stride_px: int = rng(1, 256)
    edge_clearance_factor: float = rng(0)
    commit_radius_factor: float = rng(0)
    commit_score_band: float = rng(0, 1)
    max_normal_pairs: int = rng(1)
    commit: Literal["agree", "latest"] = "agree"


@schema
class SimCfg:
    dynamics_dt_s: float = rng(0, 0.1, lo_open=True)
    control_dt_s: float = rng(0, 1, lo_open=True)
    attitude: Literal["dynamic", "ideal"]
    visibility: Literal["virtual", "real"]
    switch_error_px: float = rng(0, lo_open=True)
    stable_error_px: float = rng(0, lo_open=True)
    settling_fraction: float = rng(0, 1, lo_open=True)
    switch_hold_s: float = rng(0)
    error_filter_s: float = rng(0)
    descent_speed_m_s: float = rng(0, lo_open=True)
    timeout_s: float = rng(0, lo_open=True)
    abort_tilt_deg: float = rng(0, 180, lo_open=True)
    success_radius_m: float = rng(0, lo_open=True)
    start_offset_m: tuple[float, ...] = rng(n=3)
    target_tolerance: float = rng(0, 0.5, lo_open=True)
    max_steps_per_run: int = rng(1)


@schema
class NoiseCfg:
    seed: int = rng(0)
    position_sigma_m: float = rng(0)
    attitude_sigma_deg: float = rng(0)
    velocity_sigma_m_s: float = rng(0)
    position_drift_m_sqrt_s: float = rng(0)
    yaw_drift_deg_sqrt_s: float = rng(0)


@schema
class WindCfg:
    mean_m_s: tuple[float, ...] = rng(n=3)
    gust_m_s: float = rng(0)
    gust_tau_s: float = rng(0, lo_open=True)
    drag_kg_s: float = rng(0)


@schema
class MonteCarloCfg:
    start_radius_m: float = rng(0)
    start_dz_m: float = rng(0)
    start_yaw_deg: float = rng(0, 180)
    position_sigma_m: float = rng(0)
    attitude_sigma_deg: float = rng(0)
    velocity_sigma_m_s: float = rng(0)
    position_drift_m_sqrt_s: float = rng(0)
    yaw_drift_deg_sqrt_s: float = rng(0)
    gust_m_s: float = rng(0)
    switch_error_px: float = rng(0, lo_open=True)
    chunk_runs: int = rng(1, 1_000_000)
    max_runs: int = rng(1)
    max_total_steps: int = rng(1)


@schema
class TunedGainsCfg:
    K_e: tuple[float, ...] = rng(0, lo_open=True, n=3)
    K_i: tuple[float, ...] = rng(0, n=3)
    K_p: tuple[float, ...] = rng(0, lo_open=True, n=3)


@schema
class ApproachCfg:
    enabled: bool
    view_margin: float = rng(0, 0.45)
    min_height_m: float = rng(0, lo_open=True)
    speed_m_s: float = rng(0, lo_open=True)
    climb_speed_m_s: float = rng(0, lo_open=True)
    k_pos_1_s: float = rng(0, lo_open=True)
    k_vel_1_s: float = rng(0, lo_open=True)


@schema
class DisturbanceCfg:
    observer: bool
    bandwidth_rad_s: float = rng(0, lo_open=True)


@schema
class ControlCfg:
    K_e: tuple[float, ...] = rng(0, lo_open=True, n=3)
    K_i: tuple[float, ...] = rng(0, n=3)
    K_p: tuple[float, ...] = rng(0, lo_open=True, n=3)
    k_psi: float = rng(0)
    beta: tuple[float, ...] = rng(0, n=2)
    mu: tuple[float, ...] = rng(0, n=2)
    desired_depth_m: float = rng(0, lo_open=True)
    gravity_m_s2: float = rng(0, lo_open=True)
    k_psi_d: float = rng(0)
    yaw_feature_deg: float = rng(-180, 180)
    max_tilt_cmd_deg: float = rng(0, 89, lo_open=True)
    integral_zone_px: float = rng(0)
    yaw_symmetry_deg: float = rng(0, 360)
    gain_set: Literal["paper", "tuned"]
    tuned: TunedGainsCfg
    approach: ApproachCfg
    disturbance: DisturbanceCfg
    sim: SimCfg
    noise: NoiseCfg
    wind: WindCfg
    montecarlo: MonteCarloCfg


@schema
class ScenariosCfg:
    s1_m: tuple[float, ...] = rng(n=3)
    s2_m: tuple[float, ...] = rng(n=3)
    s3_m: tuple[float, ...] = rng(n=3)
    s4_m: tuple[float, ...] = rng(n=3)


@schema
class FlightCfg:
    drift_m: float = rng(0)
    drift_period_s: float = rng(0, lo_open=True)
    altitude_wobble_m: float = rng(0)
    tilt_deg: float = rng(0, 30)
    tilt_period_s: float = rng(0, lo_open=True)
    yaw_deg: float = rng(-360, 360)
    yaw_rate_deg_s: float = rng(-90, 90)
    descent_m_s: float = rng(0)
    speed_m_s: float = rng(0, 30)
    heading_deg: float = rng(-360, 360)
    min_altitude_m: float = rng(0, lo_open=True)


@schema
class LightCfg:
    sun_dir: tuple[float, ...] = rng(n=3)
    ambient: float = rng(0, 1)
    shadows: bool
    shadow_bias_m: float = rng(0)
    sky_rgb: tuple[float, ...] = rng(0, 1, n=3)


@schema
class SgbmCfg:
    mode: Literal["sgbm", "sgbm_3way", "hh", "hh4"]
    block_px: int = rng(1, 11, odd=True)
    p1_per_px2: float = rng(0)
    p2_per_px2: float = rng(0)
    uniqueness_pct: int = rng(0, 100)
    lr_max_diff_px: int = rng(-1, 64)
    speckle_window_px: int = rng(0)
    speckle_range_px: int = rng(0, 64)
    prefilter_cap: int = rng(1, 63)


@schema
class StereoCfg:
    emitter: bool
    subpixel: Literal["sgbm", "refine"]
    sgbm: SgbmCfg
    ir_width_px: int = rng(32, 4096)
    ir_height_px: int = rng(16, 4096)
    exposure_fill: float = rng(0, 1, lo_open=True)
    sun_irradiance_w_m2: float = rng(0, lo_open=True)
    pattern_seed: int = rng(0)
    supersample_x: int = rng(1, 8)
    refine_block_px: int = rng(3, 31, odd=True)
    refine_iterations: int = rng(1, 10)


@schema
class StereoPresetCfg:
    baseline_m: float = rng(0, lo_open=True)
    focal_length_mm: float = rng(0, lo_open=True)
    pixel_um: float = rng(0, lo_open=True)
    sensor_width_px: int = rng(1)
    min_z_m: float = rng(0, lo_open=True)
    color_offset_m: tuple[float, ...] = rng(n=3)
    projector_offset_m: tuple[float, ...] = rng(n=3)
    projector_hfov_deg: float = rng(0, 170, lo_open=True)
    projector_vfov_deg: float = rng(0, 170, lo_open=True)
    projector_power_w: float = rng(0)
    projector_dots: int = rng(1, 10_000_000)
    dot_sigma_mrad: float = rng(0, lo_open=True)
    full_well_e: float = rng(1)
    read_noise_e: float = rng(0)


@schema
class StereoPresetsCfg:
    d435: StereoPresetCfg
    d455: StereoPresetCfg


@schema
class SensorCfg:
    model: Literal["ideal", "gaussian", "stereo"]
    preset: Literal["d435", "d455"]
    stereo: StereoCfg
    presets: StereoPresetsCfg
    depth_sigma_a: float = rng(0)
    edge_jump_m: float = rng(0, lo_open=True)
    edge_hole_prob: float = rng(0, 1)
    min_range_m: float = rng(0)
    max_range_m: float = rng(0, lo_open=True)
    color_noise: float = rng(0, 64)

    @property
    def camera(self) -> StereoPresetCfg:
        """The preset camera the stereo model renders."""
        preset: StereoPresetCfg = getattr(self.presets, self.preset)
        return preset


@schema
class GroundTruthCfg:
    raster_m: float = rng(0.005, 1.0)
    step_m: float = rng(0, lo_open=True)
    slope_tolerance_deg: float = rng(0, 1)
    stamp_tolerance_ms: float = rng(0, 1000)
    max_cells: int = rng(1)


@schema
class SynthCfg:
    frames: int = rng(1)
    max_frames: int = rng(1)
    rate_hz: float = rng(1, 200)
    path: Literal["hover", "descent", "transect"]
    seed: int = rng(0)
    start_stamp_ns: int = rng(0)
    embed_m: float = rng(0)
    scenarios: ScenariosCfg
    flight: FlightCfg
    light: LightCfg
    sensor: SensorCfg
    ground_truth: GroundTruthCfg


# --- slam (slam helper) ---
@schema
class OrbCfg:
    n_features: int = rng(50, 20000)
    n_levels: int = rng(1, 16)
    scale_factor: float = rng(1, 2, lo_open=True)
    fast_threshold: int = rng(1, 255)
    fast_min_threshold: int = rng(1, 255)


@schema
class SlamKeyframeCfg:
    min_translation_m: float = rng(0, lo_open=True)
    min_rotation_deg: float = rng(0, 180, lo_open=True)
    min_tracked_ratio: float = rng(0, 1)


@schema
class OrbSlam3Cfg:
    sensor: Literal["rgbd", "monocular"]
    scale_min_points: int = rng(1)
    init_warn_frames: int = rng(1)
    close_depth_m: float = rng(0, lo_open=True)
    baseline_m: float = rng(0, lo_open=True)
    nominal_period_s: Literal["auto"] | float = rng(0, lo_open=True)
    load_timeout_s: float = rng(0, lo_open=True)
    frame_timeout_s: float = rng(0, lo_open=True)


@schema
class OdometryCfg:
    ratio_test: float = rng(0, 1, lo_open=True)
    search_radius_px: float = rng(0, lo_open=True)
    pnp_reprojection_px: float = rng(0, lo_open=True)
    pnp_iterations: int = rng(10, 100000)
    pnp_confidence: float = rng(0, 1, lo_open=True)
    min_inliers: int = rng(6)
    min_depth_m: float = rng(0)
    max_depth_m: float = rng(0, lo_open=True)
    local_keyframes: int = rng(1, 1000)
    min_parallax_deg: float = rng(0)
    max_triangulation_error_px: float = rng(0, lo_open=True)
    reinit_after_frames: int = rng(1)
    ba_keyframes: int = rng(0, 100)
    ba_depth_sigma_rel: float = rng(0, lo_open=True)
    ba_huber: float = rng(0, lo_open=True)
    ba_iterations: int = rng(1, 1000)
    ba_outlier_px: float = rng(0, lo_open=True)


@schema
class VocabCfg:
    k: int = rng(2, 20)
    levels: int = rng(1, 10)
    iterations: int = rng(1, 100)
    max_frames: int = rng(1)
    seed: int = rng(0)


@schema
class SlamCfg:
    backend: Literal["auto", "orbslam3", "odometry", "recorded"]
    vocabulary: str
    points_topic: str
    track_ahead: bool
    max_untracked_share: float = rng(0, 1)
    orb: OrbCfg
    keyframe: SlamKeyframeCfg
    orbslam3: OrbSlam3Cfg
    odometry: OdometryCfg
    vocab: VocabCfg
# --- end slam ---


@schema
class CompareCfg:
    methods: tuple[str, ...] = one_of(method_registry.names)
    pr_levels: int = rng(2, 10001)
    variants: tuple[str, ...]
# --- end compare ---


@schema
class OutputCfg:
    level: OutputLevel
    reverse_colormap: bool
    results_mcap: bool
    mask_cloud_stride_px: int = rng(1, 256)
    map_frame: str
    progress_every_s: float = rng(0)
    write_queue: int = rng(0, 64)


@schema
class Config:
    camera: CameraCfg
    sources: SourcesCfg
    terrain: TerrainCfg
    scoring: ScoringCfg
    mask: MaskCfg
    uav: UavCfg
    landing: LandingCfg
    control: ControlCfg
    synth: SynthCfg
    slam: SlamCfg
    compare: CompareCfg
    output: OutputCfg

    def to_dict(self) -> dict[str, Any]:
        return _to_plain(self)

    def hash(self) -> str:
        """Stable hash of the resolved config, for skipping work already done."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- loading
def load_config(config_file: str | Path | None = None, overrides: typing.Sequence[str] = (),
                profile: str | None = None) -> Config:
    """Defaults, then the profile, then the user's file, then ``--set`` overrides; validated into ``Config``."""
    data = read_yaml_mapping(DEFAULT_CONFIG)
    profile_file = profile_path(profile)
    if profile_file is not None:
        data = merge(data, read_yaml_mapping(profile_file), source=str(profile_file))
    if config_file is not None:
        user = read_yaml_mapping(Path(config_file))
        data = merge(data, user, source=str(config_file))
    changed = []
    for item in overrides:
        key, value = parse_override(item)
        changed.append(key)
        data = merge(data, _nest(key, value), source="--set")
    where = str(config_file) if config_file else (str(profile_file) if profile_file else None)
    config = build(Config, data, "", source=where)
    validate_pairs(config, where or ("--set" if overrides else None), frozenset(changed))
    return config


# ----------------------------------------------------------------------------- profiles
# A profile is a named layer between default.yaml and --config: configs/profiles/NAME.yaml, in
# default.yaml's style (one leaf per line, each with its unit and source). "default" is no layer.
DEFAULT_PROFILE = "default"


def profile_names() -> list[str]:
    """Every profile ``--profile`` accepts: ``default`` and the files in configs/profiles/."""
    shipped = sorted(p.stem for p in PROFILE_DIR.glob("*.yaml")) if PROFILE_DIR.is_dir() else []
    return [DEFAULT_PROFILE, *(n for n in shipped if n != DEFAULT_PROFILE)]


def profile_path(name: str | None) -> Path | None:
    """The file of profile ``name`` (None for no profile or ``default``); ConfigError naming the known ones."""
    if name is None or name == DEFAULT_PROFILE:
        return None
    known = profile_names()
    if name not in known:
        raise ConfigError("--profile", f"unknown profile {short_repr(name)}{_did_you_mean(name, known)}; "
                                       f"known: {', '.join(known)}")
    return PROFILE_DIR / f"{name}.yaml"


def layer_sources(profile: str | None = None, config_file: str | Path | None = None,
                  overrides: typing.Sequence[str] = ()) -> dict[str, str]:
    """Dotted key -> where its value comes from, for every key a layer above default.yaml sets.

    The text is the layer (``profile paper``, ``--config FILE``, ``--set``) and the comment the
    layer's file writes beside the key, so ``slz config dump`` shows each value's source. The last
    layer setting a key wins, as in ``load_config``.
    """
    out: dict[str, str] = {}
    layers: list[tuple[str, Path]] = []
    profile_file = profile_path(profile)
    if profile_file is not None:
        layers.append((f"profile {profile}", profile_file))
    if config_file is not None:
        layers.append((f"--config {config_file}", Path(config_file)))
    for label, path in layers:
        comments = _leaf_comments(read_yaml_text(path))
        for key in _leaves(read_yaml_mapping(path)):
            note = comments.get(key, "")
            out[key] = f"{label}: {note}" if note else label
    for item in overrides:
        key, _ = parse_override(item)
        for leaf in [k for k in out if k == key or k.startswith(key + ".")]:
            del out[leaf]
        out[key] = "--set"
    return out


def _leaves(data: Mapping[str, Any], prefix: str = "") -> list[str]:
    keys: list[str] = []
    for key, value in data.items():
        path = f"{prefix}{key}"
        keys.extend(_leaves(value, f"{path}.") if isinstance(value, dict) else [path])
    return keys


_LINE_RE = re.compile(r"^(\s*)([A-Za-z_]\w*):(\s*)([^#]*?)(\s*)(#.*)?$")


@dataclass(frozen=True)
class _LeafLine:
    """A ``key: value  # comment`` line of a file in default.yaml's style (one leaf per line)."""

    indent: str
    sections: tuple[str, ...]   # the keys of the sections it is in, outermost first
    key: str
    comment: str                # "# ..." or ""

    @property
    def dotted(self) -> str:
        return ".".join((*self.sections, self.key))


def _yaml_lines(text: str) -> Iterator[tuple[str, _LeafLine | None]]:
    """Every line of a file in default.yaml's style with its leaf (None for sections, comments, blanks):
    what the comment reader and ``dump`` both walk."""
    stack: list[tuple[int, str]] = []
    for line in text.splitlines():
        m = _LINE_RE.match(line)
        if not m:
            yield line, None
            continue
        indent, key, _, value, _, comment = m.groups()
        while stack and stack[-1][0] >= len(indent):
            stack.pop()
        if value == "":
            stack.append((len(indent), key))
            yield line, None
            continue
        yield line, _LeafLine(indent, tuple(k for _, k in stack), key, comment or "")


def _leaf_comments(text: str) -> dict[str, str]:
    """Dotted key -> the comment on its line (without ``#``), for a file in default.yaml's style."""
    return {leaf.dotted: leaf.comment.lstrip("#").strip() for _, leaf in _yaml_lines(text) if leaf and leaf.comment}


# ----------------------------------------------------------------------------- bounded YAML
# Limits of the reader itself (a config cannot set them: they guard reading the config). Configs
# are small: default.yaml is ~21 KB, ~330 values, 4 levels deep, no aliases; a scene file ~6 KB.
MAX_YAML_BYTES = 1 << 20     # 1 MiB
# Magnitudes no parameter means: past them a value is a unit mistake, and arithmetic on it overflows
# (a 1e300 ms tolerance in ns, a noise coefficient squared). The largest float a default holds is
# sources' stamp window in Unix seconds (~1.7e9); the largest int a stamp in ns (1.7e18).
MAX_FLOAT_MAGNITUDE = 1e10
MAX_INT_MAGNITUDE = 2**63 - 1
MAX_YAML_ALIASES = 100       # anchors may be reused, but not a billion times
MAX_YAML_VALUES = 100_000    # values once every alias is expanded (what a loop over the data visits)
MAX_YAML_DEPTH = 32          # nesting of mappings and lists


class YamlLimitError(yaml.YAMLError):
    """A YAML text over one of the reader's bounds (size, aliases, expanded values, depth)."""

    def __init__(self, reason: str, mark: Any = None) -> None:
        self.reason, self.problem_mark = reason, mark
        super().__init__(reason)


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that counts aliases, expanded values and depth while composing.

    PyYAML shares an aliased node instead of copying it, so a 300-byte "billion laughs" loads
    in microseconds; what explodes is any code that walks the result (validation, ``str()``,
    an error message): 9 levels of 9 aliases are 387 million values. The expanded size of each
    node is summed bottom-up as it is composed, so the bound costs one pass over the text.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                raise YamlLimitError(f"more than {MAX_YAML_ALIASES} aliases", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise YamlLimitError(f"nested more than {MAX_YAML_DEPTH} levels deep", self.peek_event().start_mark)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if node is None:
            return node
        if isinstance(node, yaml.SequenceNode):
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        else:
            children = []
        size = 1 + sum(self._sizes.get(id(c), 1) for c in children)
        if size > MAX_YAML_VALUES:
            raise YamlLimitError(f"more than {MAX_YAML_VALUES} values once its aliases are expanded",
                                 node.start_mark)
        self._sizes[id(node)] = size
        return node


# YAML 1.2 floats: PyYAML (YAML 1.1) reads `1e-9` and `1e6` as strings, so `--set a.b=1e-9` was
# refused as "a string"; with a dot (`1.0e-9`) both agree. Strings that look like numbers are not
# config values anywhere (topics start with '/', methods are words).
_FLOAT_WITH_EXPONENT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
_BoundedLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_WITH_EXPONENT, list("-+0123456789."))


def safe_yaml_load(text: str) -> Any:
    """``yaml.safe_load`` within the bounds above; ``YamlLimitError`` (a ``yaml.YAMLError``) past them."""
    if len(text) > MAX_YAML_BYTES:
        raise YamlLimitError(f"{len(text)} characters, more than {MAX_YAML_BYTES} (a config is a few KB)")
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    except (ValueError, OverflowError) as err:  # e.g. int() of 5,000 digits, a date like 2024-13-45
        raise YamlLimitError(f"a value cannot be read ({short_repr(str(err), 60)})", loader.get_mark()) from err
    finally:
        loader.dispose()


def read_yaml_text(path: Path) -> str:
    """A YAML file's text, refused unread when larger than ``MAX_YAML_BYTES`` (reads at most that much)."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_YAML_BYTES + 1)
    except OSError as err:
        raise ConfigError("", f"cannot read ({err.strerror or err})", source=str(path)) from err
    if len(raw) > MAX_YAML_BYTES:
        raise ConfigError("", f"file is larger than {MAX_YAML_BYTES // 1024} KiB; a config is a few KB "
                              "(is this the right file?)", source=str(path))
    try:
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):   # UTF-16 with its byte-order mark (YAML 1.1 allows it)
            return raw.decode("utf-16")
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError("", f"not UTF-8 text (nor UTF-16 with a byte-order mark): {err.reason} at position "
                              f"{err.start}; save it as UTF-8", source=str(path)) from err


def read_yaml_mapping(path: Path) -> dict[str, Any]:
    if not path.is_file():
        what = "not a regular file (a FIFO, device or folder)" if path.exists() else "config file not found"
        raise ConfigError("", what, source=str(path))
    data = _load_yaml_file(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError("", "the top level must be a mapping of sections", source=str(path))
    return data


def _load_yaml_file(path: Path) -> Any:
    """A YAML file's content within the loader's bounds; ConfigError naming the file otherwise."""
    text = read_yaml_text(path)
    try:
        return safe_yaml_load(text)
    except YamlLimitError as err:
        if "levels deep" in err.reason:
            raise ConfigError("", f"not a usable config: nested too deeply for the YAML parser ({err.reason})",
                              source=str(path)) from err
        raise ConfigError("", f"YAML refused: {err.reason} ({_yaml_where(err)})", source=str(path)) from err
    except yaml.reader.ReaderError as err:   # e.g. UTF-16 without its byte-order mark: NULs between letters
        raise ConfigError("", f"not UTF-8 text (nor UTF-16 with a byte-order mark): {err.reason} at position "
                              f"{err.position}; save it as UTF-8", source=str(path)) from err
    except yaml.YAMLError as err:
        raise ConfigError("", f"not valid YAML ({_yaml_where(err)})", source=str(path)) from err
    except RecursionError as err:
        raise ConfigError("", "not a usable config: nested too deeply for the YAML parser", source=str(path)) from err


def split_override(item: str) -> tuple[str, str]:
    """``a.b=v`` -> (``a.b``, ``v`` unparsed); ConfigError when it is not KEY=VALUE with a dotted key
    (the CLI makes this a usage error, exit 2; a value the YAML parser refuses stays a config error)."""
    if "=" not in item:
        raise ConfigError(item, "--set needs KEY=VALUE, e.g. --set mask.threshold=0.6")
    key, _, text = item.partition("=")
    key = key.strip()
    if not re.fullmatch(r"[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*", key):
        raise ConfigError(key or item, "not a dotted key path")  # name what was typed, even an empty key
    return key, text


def parse_override(item: str) -> tuple[str, Any]:
    """``a.b=v`` -> (``a.b``, YAML-parsed ``v``)."""
    key, text = split_override(item)
    try:
        value = safe_yaml_load(text) if text.strip() else ""
    except YamlLimitError as err:
        if "levels deep" in err.reason:
            raise ConfigError(key, f"value is nested too deeply for the YAML parser ({err.reason})",
                              source="--set") from err
        raise ConfigError(key, f"value refused: {err.reason}", source="--set") from err
    except yaml.YAMLError as err:
        raise ConfigError(key, f"value {short_repr(text)} is not valid YAML") from err
    except RecursionError as err:
        raise ConfigError(key, "value is nested too deeply for the YAML parser") from err
    return key, value


# Keys that were removed, with the key that replaced them: a config that still sets one is refused
# with the replacement named (a silently ignored or "unknown" key would hide a changed limit).
RENAMED_KEYS: dict[str, str] = {
    "terrain.steepness.slope_limit_deg": "uav.max_slope_deg",  # one slope limit (issue: duplicated keys)
    "landing.max_tilt_deg": "uav.max_slope_deg",
}


def merge(base: dict[str, Any], over: dict[str, Any], source: str, prefix: str = "") -> dict[str, Any]:
    """Deep merge; a key unknown to ``base`` is an error (caught here so the source is named)."""
    out = dict(base)
    for key, value in over.items():
        path = f"{prefix}{key}"
        if key not in base and path in RENAMED_KEYS:
            raise ConfigError(path, f"removed; set {RENAMED_KEYS[path]} instead (the one key for it now)",
                              source=source)
        if key not in base:
            raise ConfigError(path, f"unknown key{_did_you_mean(str(key), base)}", source=source)
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(path, f"expected a section (mapping), got {_kind(value)}", source=source)
            out[key] = merge(base[key], value, source, prefix=f"{path}.")
        else:
            out[key] = value
    return out


def _nest(key: str, value: Any) -> dict[str, Any]:
    for part in reversed(key.split(".")):
        value = {part: value}
    return value


def build(cls: type[_D], data: Any, path: str, source: str | None = None) -> _D:
    """Validate ``data`` against the dataclass ``cls`` recursively."""
    if not isinstance(data, dict):
        raise ConfigError(path, f"expected a section (mapping), got {_kind(data)}", source)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise ConfigError(_join(path, str(key)), f"unknown key{_did_you_mean(str(key), fields)}", source)
    kwargs = {}
    for name, f in fields.items():
        sub = _join(path, name)
        if name not in data:
            raise ConfigError(sub, "missing key", source)
        kwargs[name] = _check(hints[name], data[name], sub, f.metadata, source)
    return cls(**kwargs)


def _check(tp: Any, value: Any, path: str, meta: Mapping[str, Any], source: str | None) -> Any:
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return build(tp, value, path, source)
    origin = typing.get_origin(tp)
    if origin is Literal:
        choices = typing.get_args(tp)
        if value not in choices:
            hint = _did_you_mean(short_repr(value, 200), choices) if isinstance(value, str) else ""
            raise ConfigError(path, f"must be one of {', '.join(map(str, choices))}; got {short_repr(value)}{hint}",
                              source)
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(path, f"expected a list, got {_kind(value)}", source)
        n = meta.get("n")
        if n is not None and len(value) != n:
            raise ConfigError(path, f"expected {n} values, got {len(value)}", source)
        item_tp = typing.get_args(tp)[0]
        return tuple(_scalar(item_tp, v, f"{path}[{i}]", meta, source) for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        errors = []
        for arg in args:   # the first alternative the value fits (e.g. "auto" or a number)
            try:
                return _check(arg, value, path, meta, source)
            except ConfigError as err:
                errors.append(err)
        if len(args) == 1:
            raise errors[0]
        for arg, refusal in zip(args, errors, strict=True):  # a number out of range: say so, not "expected a number"
            if arg in (int, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
                raise refusal
        raise ConfigError(path, f"expected {_alternatives(args)}, got {_kind(value)} {value!r}", source)
    return _scalar(tp, value, path, meta, source)


def _scalar(tp: Any, value: Any, path: str, meta: Mapping[str, Any], source: str | None) -> Any:
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(path, f"expected true or false, got {_kind(value)} {short_repr(value)}", source)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(path, f"expected an integer, got {_kind(value)} {short_repr(value)}", source)
        if abs(value) > MAX_INT_MAGNITUDE:
            raise ConfigError(path, f"{short_repr(value)} does not fit a 64-bit integer", source)
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(path, f"expected a number, got {_kind(value)} {short_repr(value)}", source)
        value = float(value)
        if value != value:
            raise ConfigError(path, "NaN is not allowed", source)
        if value in (float("inf"), float("-inf")):  # no parameter means "unbounded"; 0 disables where allowed
            raise ConfigError(path, f"must be finite, got {value}", source)
        if abs(value) > MAX_FLOAT_MAGNITUDE:
            raise ConfigError(path, f"{short_repr(value)} is beyond +-{MAX_FLOAT_MAGNITUDE:g}, which no slz parameter "
                                    "means in its unit (a unit mistake?)", source)
    elif tp is str:
        if not isinstance(value, str):
            raise ConfigError(path, f"expected a string, got {_kind(value)} {short_repr(value)}", source)
        names = meta.get("one_of")
        if names is not None and value not in names():
            choices = names()
            raise ConfigError(path, f"must be one of {', '.join(choices)}; got {short_repr(value)}"
                                    f"{_did_you_mean(short_repr(value, 200), choices)}", source)
        return value
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and (value <= lo if meta.get("lo_open") else value < lo):
        raise ConfigError(path, f"must be {'>' if meta.get('lo_open') else '>='} {lo}, got {short_repr(value)}", source)
    if hi is not None and value > hi:
        raise ConfigError(path, f"must be <= {hi if isinstance(hi, int) else format(hi, 'g')}, got {short_repr(value)}",
                          source)
    if meta.get("odd") and int(value) % 2 != 1:
        raise ConfigError(path, f"must be odd, got {short_repr(value)}", source)
    return value


def _alternatives(args: typing.Sequence[Any]) -> str:
    plain = {float: "a number", int: "an integer", str: "a string", bool: "true or false"}
    names: list[str] = []
    for arg in args:
        if typing.get_origin(arg) is Literal:
            names.extend(repr(c) for c in typing.get_args(arg))
        else:
            names.append(plain.get(arg, str(arg)))
    return " or ".join(names)


# ----------------------------------------------------------------------------- cross-field checks
# (smaller, relation, larger, why): values that are each in range but contradict each other.
PAIRS: tuple[tuple[str, str, str, str], ...] = (
    ("terrain.flatness.canny_low", "<=", "terrain.flatness.canny_high", "Canny's hysteresis thresholds"),
    ("terrain.steepness.normal_px", "<=", "terrain.steepness.normal_max_px", "smallest and largest normal window"),
    ("uav.thrust_min_n", "<", "uav.thrust_max_n", "the thrust range"),
    ("synth.sensor.min_range_m", "<", "synth.sensor.max_range_m", "the depth sensor's range"),
    ("slam.odometry.min_depth_m", "<", "slam.odometry.max_depth_m", "the depths used for map points"),
    ("slam.orb.fast_min_threshold", "<=", "slam.orb.fast_threshold", "ORB's FAST thresholds (fallback and first)"),
    ("camera.cx", "<=", "camera.width", "the principal point lies in the image"),
    ("camera.cy", "<=", "camera.height", "the principal point lies in the image"),
    ("sources.intrinsics.min_fov_deg", "<", "sources.intrinsics.max_fov_deg", "the field-of-view range"),
)


def _get(config: Config, key: str) -> Any:
    node: Any = config
    for part in key.split("."):
        node = getattr(node, part)
    return node


_FLIPPED = {"<": ">", "<=": ">="}
_WEIGHT_KEYS = ("uav.mass_kg", "control.gravity_m_s2")


def _check_preset(name: str, source: str | None) -> None:
    """``camera.preset`` names a file of ``configs/camera/`` (or is auto / none)."""
    names = sorted(p.stem for p in (CONFIG_DIR / "camera").glob("*.yaml"))
    if name not in ("auto", "none", *names):
        raise ConfigError("camera.preset", f"no camera preset {name!r} (choices: auto, none, {', '.join(names)})",
                          source)


def validate_pairs(config: Config, source: str | None = None, changed: frozenset[str] = frozenset()) -> None:
    """Refuse values that are fine alone but contradict each other, naming both keys.

    The error is keyed on the one of them the user ``changed`` (``--set``) when only that one was:
    ``--set uav.mass_kg=1`` is about the mass, though the thrust limit is what it contradicts."""
    for small, rel, large, why in PAIRS:
        a, b = _get(config, small), _get(config, large)
        if not (a <= b if rel == "<=" else a < b):
            if large in changed and small not in changed:
                raise ConfigError(large, f"must be {_FLIPPED[rel]} {small} ({why}); got {b:g} and {a:g}", source)
            raise ConfigError(small, f"must be {rel} {large} ({why}); got {a:g} and {b:g}", source)
    _check_preset(config.camera.preset, source)
    uav, weight = config.uav, config.uav.mass_kg * config.control.gravity_m_s2
    weight_key = next((k for k in _WEIGHT_KEYS if k in changed), None)
    for thrust, ok, what, effect in (("uav.thrust_max_n", uav.thrust_max_n > weight, "exceed", "hover"),
                                     ("uav.thrust_min_n", uav.thrust_min_n < weight, "be below", "descend")):
        if ok:
            continue
        value = _get(config, thrust)
        if weight_key is not None and thrust not in changed:
            raise ConfigError(weight_key, f"makes the weight uav.mass_kg x control.gravity_m_s2 = {weight:.3g} N, "
                                          f"which {thrust} = {value:g} must {what} (it could not {effect})", source)
        raise ConfigError(thrust, f"must {what} the weight uav.mass_kg x control.gravity_m_s2 = "
                                  f"{weight:.3g} N (it could not {effect}); got {value:g}", source)
    from slzcli.sources.validate import intrinsics_problem  # here: sources imports this module
    from slzcli.types import Intrinsics

    cam, lim = config.camera, config.sources.intrinsics
    problem = intrinsics_problem(Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height),
                                 lim.min_fov_deg, lim.max_fov_deg)
    if problem is not None:
        raise ConfigError("camera", problem, source)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _kind(value: Any) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean",
            int: "an integer", float: "a number", type(None): "nothing"}.get(type(value), type(value).__name__)


def _did_you_mean(word: str, candidates: typing.Iterable[Any]) -> str:
    close = difflib.get_close_matches(word, [str(c) for c in candidates], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _yaml_where(err: yaml.YAMLError) -> str:
    mark = getattr(err, "problem_mark", None)
    return f"line {mark.line + 1}, column {mark.column + 1}" if mark else str(err).splitlines()[0]


def _to_plain(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [_to_plain(v) for v in obj]
    return obj


# ----------------------------------------------------------------------------- dump
def dump(config: Config, sources: Mapping[str, str] | None = None) -> str:
    """The resolved config as YAML, keeping default.yaml's comments (unit and source of every key).

    default.yaml keeps one leaf per line, so each leaf line's value is replaced in place.
    ``sources`` (``layer_sources``): keys set by a layer above the defaults get that layer's
    source as their comment instead.
    """
    values = config.to_dict()
    out: list[str] = []
    for line, leaf in _yaml_lines(DEFAULT_CONFIG.read_text()):
        if leaf is None:
            out.append(line)
            continue
        node: Any = values
        for k in leaf.sections:
            node = node[k]
        text = f"{leaf.indent}{leaf.key}: {_yaml_scalar(node[leaf.key])}"
        comment = f"# {sources[leaf.dotted]}" if sources and leaf.dotted in sources else leaf.comment
        if comment:
            text = text.ljust(max(len(text) + 1, 32)) + comment
        out.append(text)
    return "\n".join(out) + "\n"


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_yaml_scalar(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value) if value == "" or not re.fullmatch(r"[\w./-]+", value) else value
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:  # an optional key left unset (sources.window.start_s)
        return "null"
    return repr(value) if isinstance(value, float) else str(value)
