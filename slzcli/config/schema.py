"""The config schema: a frozen dataclass per section (types, ranges, choices); the values and their units
and sources live in ``configs/default.yaml`` only. ``Config.to_dict`` and ``Config.hash`` serve the rerun key."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

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


RULE = "slz.rule"  # the metadata key of a schema field's Rule


class Rule(typing.TypedDict, total=False):
    """What a schema field's metadata may say about its values (``rng``, ``one_of``; read by ``config.check``)."""

    lo: float | None
    hi: float | None
    lo_open: bool
    odd: bool
    n: int | None
    one_of: typing.Callable[[], tuple[str, ...]]


def rng(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
        odd: bool = False, n: int | None = None) -> Any:
    """A schema field with a range: ``lo <= v <= hi`` (``lo < v`` when lo_open), odd ints, list length n.

    Typed as ``dataclasses.field`` without a default is: the field's annotation gives its type."""
    return field(metadata={RULE: Rule(lo=lo, hi=hi, lo_open=lo_open, odd=odd, n=n)})


def one_of(names: typing.Callable[[], tuple[str, ...]]) -> Any:
    """A string field (or each string of a list) that must be one of ``names()``, a registry read at check time."""
    return field(metadata={RULE: Rule(one_of=names)})


_C = typing.TypeVar("_C")
_D = typing.TypeVar("_D", bound="DataclassInstance")

if typing.TYPE_CHECKING:
    from _typeshed import DataclassInstance
    from typing_extensions import dataclass_transform
else:
    def dataclass_transform(**_kwargs: object) -> typing.Callable[[_C], _C]:
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
class ImuGravityCfg:
    topic: str
    block_s: float = rng(0, lo_open=True)
    accel_tolerance_m_s2: float = rng(0, lo_open=True)
    gyro_quiet_rad_s: float = rng(0, lo_open=True)
    window_s: float = rng(0, lo_open=True)
    min_quiet_blocks: int = rng(1)
    max_messages: int = rng(1)


@schema
class SceneGravityCfg:
    frames: int = rng(1, 100)
    stride: int = rng(1)
    sample_px: int = rng(1, 64)
    hypotheses: int = rng(10, 10000)
    inlier_fraction: float = rng(0, 1, lo_open=True)
    min_inlier_share: float = rng(0, 1, lo_open=True)
    max_prior_deg: float = rng(0, 180, lo_open=True)
    frame_prior_deg: float = rng(0, 180, lo_open=True)
    cluster_deg: float = rng(0, 90, lo_open=True)
    mount_level_share: float = rng(0, 1)
    seed: int = rng(0)


@schema
class GravityCfg:
    source: Literal["auto", "imu", "poses", "scene", "mount"]
    max_disagreement_deg: float = rng(0, 180, lo_open=True)
    imu: ImuGravityCfg
    scene: SceneGravityCfg


@schema
class CameraCfg:
    fx: float = rng(0, lo_open=True)
    fy: float = rng(0, lo_open=True)
    cx: float = rng(0)
    cy: float = rng(0)
    width: int = rng(1)
    height: int = rng(1)
    mount: Mount
    gravity: GravityCfg
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
    max_pixel_aspect: float = rng(1)


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
    hover_speed_m_s: float = rng(0)
    gate_sigma: float = rng(0, lo_open=True)
    two_heights_fraction: float = rng(0, 1, lo_open=True)
    column_step_m: float = rng(0, lo_open=True)
    border_sigma: float = rng(0)
    pose_sigma_m: float = rng(0)
    pose_sigma_deg: float = rng(0)
    decided_margin: float = rng(1)
    unsafe_margin: float = rng(1)


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
class RaisedCfg:
    ground_radius_m: float = rng(0, lo_open=True)
    ground_share: float = rng(0, 1, lo_open=True)
    margin_sigma: float = rng(0)
    min_cells: int = rng(1)
    ground_cell_m: float = rng(0, lo_open=True)


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
    raised: RaisedCfg
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
    mount_pitch_deg: float = rng(-90, 90)
    mount_roll_deg: float = rng(-90, 90)


@schema
class SynthImuCfg:
    enabled: bool
    topic: str
    rate_hz: float = rng(1, 2000)
    accel_noise_m_s2: float = rng(0)
    accel_bias_m_s2: float = rng(0)
    vibration_m_s2: float = rng(0)
    gyro_noise_rad_s: float = rng(0)
    gyro_bias_rad_s: float = rng(0)


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
    imu: SynthImuCfg
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
class PoseCheckCfg:
    frames: int = rng(0, 10000)
    min_posed_fraction: float = rng(0, 1)
    min_matches: int = rng(6)
    min_baseline_fraction: float = rng(0, lo_open=True)
    max_scale_ratio: float = rng(1, lo_open=True)
    max_rotation_deg: float = rng(0, 180, lo_open=True)
    max_direction_deg: float = rng(0, 180, lo_open=True)
    max_pose_stamps: int = rng(1, 1000000)


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
    pose_check: PoseCheckCfg
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



def _to_plain(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [_to_plain(v) for v in obj]
    return obj
