"""Checking a merged mapping against the schema: unknown keys with a "did you mean", wrong types, values out
of range, names not in a registry, and values that each fit but contradict each other (``validate_pairs``)."""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from typing import Literal

from slzcli.config.schema import _D, CONFIG_DIR, RULE, Config, Rule
from slzcli.config.yaml_safe import MAX_FLOAT_MAGNITUDE, MAX_INT_MAGNITUDE
from slzcli.errors import ConfigError, short_repr
from slzcli.pinhole import intrinsics_problem


def build(cls: type[_D], data: object, path: str, source: str | None = None) -> _D:
    """Validate ``data`` against the dataclass ``cls`` recursively."""
    if not isinstance(data, dict):
        raise ConfigError(path, f"expected a section (mapping), got {_kind(data)}", source)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise ConfigError(_join(path, str(key)), f"unknown key{_did_you_mean(str(key), fields)}", source)
    kwargs: dict[str, object] = {}
    for name, f in fields.items():
        sub = _join(path, name)
        if name not in data:
            raise ConfigError(sub, "missing key", source)
        kwargs[name] = _check(hints[name], data[name], sub, f.metadata.get(RULE, Rule()), source)
    return cls(**kwargs)


def _check(tp: object, value: object, path: str, meta: Rule, source: str | None) -> object:
    """``value`` (untrusted YAML) as the type ``tp`` of a schema field, whose ``meta`` says its range."""
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


def _scalar(tp: object, value: object, path: str, meta: Rule, source: str | None) -> object:
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
    if isinstance(value, (int, float)):   # a number here: within its field's range
        _in_range(value, path, meta, source)
    return value


def _in_range(value: float, path: str, meta: Rule, source: str | None) -> None:
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and (value <= lo if meta.get("lo_open") else value < lo):
        raise ConfigError(path, f"must be {'>' if meta.get('lo_open') else '>='} {lo}, got {short_repr(value)}", source)
    if hi is not None and value > hi:
        raise ConfigError(path, f"must be <= {hi if isinstance(hi, int) else format(hi, 'g')}, got {short_repr(value)}",
                          source)
    if meta.get("odd") and int(value) % 2 != 1:
        raise ConfigError(path, f"must be odd, got {short_repr(value)}", source)


def _alternatives(args: typing.Sequence[object]) -> str:
    plain: dict[object, str] = {float: "a number", int: "an integer", str: "a string", bool: "true or false"}
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


def _get(config: Config, key: str) -> float:
    """The number at the dotted ``key`` (the keys of ``PAIRS`` and the thrust limits)."""
    node: object = config
    for part in key.split("."):
        node = getattr(node, part)
    if isinstance(node, bool) or not isinstance(node, (int, float)):
        raise TypeError(f"{key} is not a number in the schema")
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
    cam, lim = config.camera, config.sources.intrinsics
    problem = intrinsics_problem(cam, lim.min_fov_deg, lim.max_fov_deg)
    if problem is not None:
        raise ConfigError("camera", problem, source)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _kind(value: object) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean",
            int: "an integer", float: "a number", type(None): "nothing"}.get(type(value), type(value).__name__)


def _did_you_mean(word: str, candidates: typing.Iterable[object]) -> str:
    close = difflib.get_close_matches(word, [str(c) for c in candidates], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""
