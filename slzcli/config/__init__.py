"""Configuration: ``configs/default.yaml`` -> frozen dataclasses, checked at every level.

The YAML file holds every value with its unit and source; the schema holds only types, ranges and
choices, so a value lives in exactly one place. One module per role: ``schema`` (a frozen dataclass per
section), ``loader`` (the layers: defaults <- ``--profile NAME`` <- ``--config FILE`` <- ``--set a.b=v``),
``check`` (types, ranges, registries, cross-field checks), ``yaml_safe`` (YAML read within bounds),
``dump`` (``slz config dump``).
"""

from __future__ import annotations

from slzcli.config.check import PAIRS as PAIRS
from slzcli.config.check import build as build
from slzcli.config.check import validate_pairs as validate_pairs
from slzcli.config.dump import dump as dump
from slzcli.config.loader import DEFAULT_PROFILE as DEFAULT_PROFILE
from slzcli.config.loader import RENAMED_KEYS as RENAMED_KEYS
from slzcli.config.loader import _leaf_comments as _leaf_comments
from slzcli.config.loader import _leaves as _leaves
from slzcli.config.loader import layer_sources as layer_sources
from slzcli.config.loader import load_config as load_config
from slzcli.config.loader import merge as merge
from slzcli.config.loader import parse_override as parse_override
from slzcli.config.loader import profile_names as profile_names
from slzcli.config.loader import profile_path as profile_path
from slzcli.config.loader import split_override as split_override
from slzcli.config.schema import CONFIG_DIR as CONFIG_DIR
from slzcli.config.schema import DEFAULT_CONFIG as DEFAULT_CONFIG
from slzcli.config.schema import PROFILE_DIR as PROFILE_DIR
from slzcli.config.schema import ApproachCfg as ApproachCfg
from slzcli.config.schema import BayesCfg as BayesCfg
from slzcli.config.schema import CameraCfg as CameraCfg
from slzcli.config.schema import CompareCfg as CompareCfg
from slzcli.config.schema import Config as Config
from slzcli.config.schema import ControlCfg as ControlCfg
from slzcli.config.schema import DepthCheckCfg as DepthCheckCfg
from slzcli.config.schema import DepthVarianceCfg as DepthVarianceCfg
from slzcli.config.schema import DisturbanceCfg as DisturbanceCfg
from slzcli.config.schema import FlatnessCfg as FlatnessCfg
from slzcli.config.schema import FlightCfg as FlightCfg
from slzcli.config.schema import FusionCfg as FusionCfg
from slzcli.config.schema import FuzzyCfg as FuzzyCfg
from slzcli.config.schema import GravityCfg as GravityCfg
from slzcli.config.schema import GroundTruthCfg as GroundTruthCfg
from slzcli.config.schema import ImuGravityCfg as ImuGravityCfg
from slzcli.config.schema import InclinationCfg as InclinationCfg
from slzcli.config.schema import IntrinsicsCheckCfg as IntrinsicsCheckCfg
from slzcli.config.schema import LandingCfg as LandingCfg
from slzcli.config.schema import LightCfg as LightCfg
from slzcli.config.schema import LimitsCfg as LimitsCfg
from slzcli.config.schema import MaskCfg as MaskCfg
from slzcli.config.schema import MonteCarloCfg as MonteCarloCfg
from slzcli.config.schema import Mount as Mount
from slzcli.config.schema import NoiseCfg as NoiseCfg
from slzcli.config.schema import NoiseEstimateCfg as NoiseEstimateCfg
from slzcli.config.schema import Normalise as Normalise
from slzcli.config.schema import OdometryCfg as OdometryCfg
from slzcli.config.schema import OrbCfg as OrbCfg
from slzcli.config.schema import OrbSlam3Cfg as OrbSlam3Cfg
from slzcli.config.schema import OutputCfg as OutputCfg
from slzcli.config.schema import OutputLevel as OutputLevel
from slzcli.config.schema import Px4SlpCfg as Px4SlpCfg
from slzcli.config.schema import RaisedCfg as RaisedCfg
from slzcli.config.schema import ScenariosCfg as ScenariosCfg
from slzcli.config.schema import SceneGravityCfg as SceneGravityCfg
from slzcli.config.schema import ScoringCfg as ScoringCfg
from slzcli.config.schema import SensorCfg as SensorCfg
from slzcli.config.schema import SgbmCfg as SgbmCfg
from slzcli.config.schema import SimCfg as SimCfg
from slzcli.config.schema import SlamCfg as SlamCfg
from slzcli.config.schema import SlamKeyframeCfg as SlamKeyframeCfg
from slzcli.config.schema import SourcesCfg as SourcesCfg
from slzcli.config.schema import SteepnessCfg as SteepnessCfg
from slzcli.config.schema import StereoCfg as StereoCfg
from slzcli.config.schema import StereoPresetCfg as StereoPresetCfg
from slzcli.config.schema import StereoPresetsCfg as StereoPresetsCfg
from slzcli.config.schema import SynthCfg as SynthCfg
from slzcli.config.schema import SynthImuCfg as SynthImuCfg
from slzcli.config.schema import TerrainCfg as TerrainCfg
from slzcli.config.schema import Topics as Topics
from slzcli.config.schema import TunedGainsCfg as TunedGainsCfg
from slzcli.config.schema import UavCfg as UavCfg
from slzcli.config.schema import VocabCfg as VocabCfg
from slzcli.config.schema import WindCfg as WindCfg
from slzcli.config.schema import WindowCfg as WindowCfg
from slzcli.config.schema import one_of as one_of
from slzcli.config.schema import package_dir as package_dir
from slzcli.config.schema import rng as rng
from slzcli.config.schema import schema as schema
from slzcli.config.yaml_safe import MAX_FLOAT_MAGNITUDE as MAX_FLOAT_MAGNITUDE
from slzcli.config.yaml_safe import MAX_YAML_ALIASES as MAX_YAML_ALIASES
from slzcli.config.yaml_safe import MAX_YAML_BYTES as MAX_YAML_BYTES
from slzcli.config.yaml_safe import MAX_YAML_DEPTH as MAX_YAML_DEPTH
from slzcli.config.yaml_safe import MAX_YAML_VALUES as MAX_YAML_VALUES
from slzcli.config.yaml_safe import YamlLimitError as YamlLimitError
from slzcli.config.yaml_safe import read_yaml_mapping as read_yaml_mapping
from slzcli.config.yaml_safe import read_yaml_text as read_yaml_text
from slzcli.config.yaml_safe import safe_yaml_load as safe_yaml_load
from slzcli.config.yaml_safe import yaml_float as yaml_float
from slzcli.config.yaml_safe import yaml_floats as yaml_floats
from slzcli.config.yaml_safe import yaml_int as yaml_int
from slzcli.config.yaml_safe import yaml_mapping as yaml_mapping
