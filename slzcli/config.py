"""Configuration: ``configs/default.yaml`` -> frozen dataclasses, checked at every level.

The YAML file holds every value with its unit and source; the dataclasses here hold
only the schema (types, ranges, choices), so a value lives in exactly one place.
Layering: defaults <- ``--config FILE`` <- ``--set a.b=v``. Unknown keys are rejected
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from slzcli.errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "default.yaml"

Normalise = Literal["absolute", "frame"]


def rng(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
        odd: bool = False, n: int | None = None) -> Any:
    """A schema field with a range: ``lo <= v <= hi`` (``lo < v`` when lo_open), odd ints, list length n."""
    return field(metadata={"lo": lo, "hi": hi, "lo_open": lo_open, "odd": odd, "n": n})


# ----------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class Mount:
    pitch_deg: float = rng(-90, 90)
    roll_deg: float = rng(-90, 90)


@dataclass(frozen=True)
class CameraCfg:
    fx: float = rng(0, lo_open=True)
    fy: float = rng(0, lo_open=True)
    cx: float = rng(0)
    cy: float = rng(0)
    width: int = rng(1)
    height: int = rng(1)
    mount: Mount


@dataclass(frozen=True)
class Topics:
    color: str
    depth: str
    camera_info: str
    pose: str


@dataclass(frozen=True)
class SourcesCfg:
    topics: Topics
    pose_frame: str
    use_ground_truth_pose: bool
    sync_tolerance_ms: float = rng(0, lo_open=True)
    pose_tolerance_ms: float = rng(0, lo_open=True)
    depth_unit_16u_m: float = rng(0, lo_open=True)
    tum_depth_scale: float = rng(0, lo_open=True)
    max_depth_m: float = rng(0)


@dataclass(frozen=True)
class DepthVarianceCfg:
    kernel_px: int = rng(3, 99, odd=True)
    s0_m: float = rng(0, lo_open=True)
    normalise: Normalise = "absolute"


@dataclass(frozen=True)
class FlatnessCfg:
    canny_low: float = rng(0, 255)
    canny_high: float = rng(0, 255)
    metres_per_level: float = rng(0, lo_open=True)
    blur_px: int = rng(1, 31, odd=True)
    distance_mask: int = rng(3, 5, odd=True)
    clearance_m: float = rng(0, lo_open=True)
    normalise: Normalise = "absolute"


@dataclass(frozen=True)
class InclinationCfg:
    radius_m: float = rng(0, lo_open=True)
    curvature_ref: float = rng(0, 1 / 3, lo_open=True)
    work_px: int = rng(16, 4096)
    min_points: int = rng(3)
    normalise: Normalise = "absolute"


@dataclass(frozen=True)
class SteepnessCfg:
    normal_px: int = rng(3, 31, odd=True)
    slope_limit_deg: float = rng(0, 90, lo_open=True)
    normalise: Normalise = "absolute"


@dataclass(frozen=True)
class TerrainCfg:
    depth_variance: DepthVarianceCfg
    flatness: FlatnessCfg
    inclination: InclinationCfg
    steepness: SteepnessCfg


@dataclass(frozen=True)
class FuzzyCfg:
    rules: str
    evaluator: Literal["compiled", "exact"]
    lut_levels: int = rng(2, 257)
    centroid_samples: int = rng(11, 10001)


@dataclass(frozen=True)
class BayesCfg:
    prior: float = rng(0, 1, lo_open=True)
    eps: float = rng(0, 0.5, lo_open=True)
    threshold: float = rng(0, 1)


@dataclass(frozen=True)
class ScoringCfg:
    method: Literal["fuzzy", "bayes"]
    fuzzy: FuzzyCfg
    bayes: BayesCfg


@dataclass(frozen=True)
class MaskCfg:
    threshold: float = rng(0, 1)
    margin_factor: float = rng(0)


@dataclass(frozen=True)
class UavCfg:
    mass_kg: float = rng(0, lo_open=True)
    inertia_kg_m2: tuple[float, ...] = rng(0, lo_open=True, n=3)
    size_m: tuple[float, ...] = rng(0, lo_open=True, n=3)
    footprint_m: tuple[float, ...] = rng(0, lo_open=True, n=2)
    max_slope_deg: float = rng(0, 90, lo_open=True)


@dataclass(frozen=True)
class LandingCfg:
    every_nth_frame: int = rng(1)
    kmeans_k: int = rng(1, 100)
    normal_radius_m: float = rng(0, lo_open=True)
    min_cluster_points: int = rng(3)
    min_extent_factor: float = rng(0)
    bayes_min_extent_factor: float = rng(0)
    seed: int = rng(0)
    edge_clearance_factor: float = rng(0)
    max_tilt_deg: float = rng(0, 90)


@dataclass(frozen=True)
class ControlCfg:
    K_e: tuple[float, ...] = rng(0, lo_open=True, n=3)
    K_i: tuple[float, ...] = rng(0, n=3)
    K_p: tuple[float, ...] = rng(0, lo_open=True, n=3)
    k_psi: float = rng(0)
    beta: tuple[float, ...] = rng(0, n=2)
    mu: tuple[float, ...] = rng(0, n=2)
    desired_depth_m: float = rng(0, lo_open=True)
    gravity_m_s2: float = rng(0, lo_open=True)


@dataclass(frozen=True)
class Config:
    camera: CameraCfg
    sources: SourcesCfg
    terrain: TerrainCfg
    scoring: ScoringCfg
    mask: MaskCfg
    uav: UavCfg
    landing: LandingCfg
    control: ControlCfg

    def to_dict(self) -> dict[str, Any]:
        return _to_plain(self)

    def hash(self) -> str:
        """Stable hash of the resolved config, for skipping work already done."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- loading
def load_config(config_file: str | Path | None = None, overrides: typing.Sequence[str] = ()) -> Config:
    """Defaults, then the user's file, then ``--set`` overrides; validated into ``Config``."""
    data = read_yaml_mapping(DEFAULT_CONFIG)
    if config_file is not None:
        user = read_yaml_mapping(Path(config_file))
        data = merge(data, user, source=str(config_file))
    for item in overrides:
        key, value = parse_override(item)
        data = merge(data, _nest(key, value), source="--set")
    return build(Config, data, "", source=str(config_file) if config_file else None)


def read_yaml_mapping(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise ConfigError("", "config file not found", source=str(path))
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ConfigError("", f"not valid YAML ({_yaml_where(err)})", source=str(path)) from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError("", "the top level must be a mapping of sections", source=str(path))
    return data


def parse_override(item: str) -> tuple[str, Any]:
    """``a.b=v`` -> (``a.b``, YAML-parsed ``v``)."""
    if "=" not in item:
        raise ConfigError(item, "--set needs KEY=VALUE, e.g. --set mask.threshold=0.6")
    key, _, text = item.partition("=")
    key = key.strip()
    if not re.fullmatch(r"[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*", key):
        raise ConfigError(key, "not a dotted key path")
    try:
        value = yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError as err:
        raise ConfigError(key, f"value {text!r} is not valid YAML") from err
    return key, value


def merge(base: dict[str, Any], over: dict[str, Any], source: str, prefix: str = "") -> dict[str, Any]:
    """Deep merge; a key unknown to ``base`` is an error (caught here so the source is named)."""
    out = dict(base)
    for key, value in over.items():
        path = f"{prefix}{key}"
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


def build(cls: type, data: Any, path: str, source: str | None = None) -> Any:
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


def _check(tp: Any, value: Any, path: str, meta: Any, source: str | None) -> Any:
    if dataclasses.is_dataclass(tp):
        return build(tp, value, path, source)
    origin = typing.get_origin(tp)
    if origin is Literal:
        choices = typing.get_args(tp)
        if value not in choices:
            raise ConfigError(path, f"must be one of {', '.join(map(str, choices))}; got {value!r}"
                              f"{_did_you_mean(str(value), choices)}", source)
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
        return _check(args[0], value, path, meta, source)
    return _scalar(tp, value, path, meta, source)


def _scalar(tp: Any, value: Any, path: str, meta: Any, source: str | None) -> Any:
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(path, f"expected true or false, got {_kind(value)} {value!r}", source)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(path, f"expected an integer, got {_kind(value)} {value!r}", source)
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(path, f"expected a number, got {_kind(value)} {value!r}", source)
        value = float(value)
        if value != value:
            raise ConfigError(path, "NaN is not allowed", source)
    elif tp is str:
        if not isinstance(value, str):
            raise ConfigError(path, f"expected a string, got {_kind(value)} {value!r}", source)
        return value
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and (value <= lo if meta.get("lo_open") else value < lo):
        raise ConfigError(path, f"must be {'>' if meta.get('lo_open') else '>='} {lo}, got {value}", source)
    if hi is not None and value > hi:
        raise ConfigError(path, f"must be <= {hi:g}, got {value}", source)
    if meta.get("odd") and int(value) % 2 != 1:
        raise ConfigError(path, f"must be odd, got {value}", source)
    return value


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
def dump(config: Config) -> str:
    """The resolved config as YAML, keeping default.yaml's comments (unit and source of every key).

    default.yaml keeps one leaf per line, so each leaf line's value is replaced in place.
    """
    values = config.to_dict()
    out: list[str] = []
    stack: list[tuple[int, str]] = []
    line_re = re.compile(r"^(\s*)([A-Za-z_]\w*):(\s*)([^#]*?)(\s*)(#.*)?$")
    for line in DEFAULT_CONFIG.read_text().splitlines():
        m = line_re.match(line)
        if not m:
            out.append(line)
            continue
        indent, key, _, value, _, comment = m.groups()
        while stack and stack[-1][0] >= len(indent):
            stack.pop()
        if value == "":
            stack.append((len(indent), key))
            out.append(line)
            continue
        node: Any = values
        for _, k in stack:
            node = node[k]
        new = _yaml_scalar(node[key])
        text = f"{indent}{key}: {new}"
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
    return repr(value) if isinstance(value, float) else str(value)
