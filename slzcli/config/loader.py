"""Loading the config: defaults <- ``--profile NAME`` (``configs/profiles/NAME.yaml``) <- ``--config FILE``
<- ``--set a.b=v``, merged and checked (``check.build``) into a ``Config``; which layer set each key."""

from __future__ import annotations

import copy
import functools
import re
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml

from slzcli.config.check import _did_you_mean, _kind, build, validate_pairs
from slzcli.config.schema import DEFAULT_CONFIG, PROFILE_DIR, Config
from slzcli.config.yaml_safe import (
    YamlLimitError,
    read_yaml_mapping,
    read_yaml_text,
    safe_yaml_load,
    yaml_text_mapping,
)
from slzcli.errors import ConfigError, short_repr


# ----------------------------------------------------------------------------- loading
def load_config(config_file: str | Path | None = None, overrides: typing.Sequence[str] = (),
                profile: str | None = None) -> Config:
    """Defaults, then the profile, then the user's file, then ``--set`` overrides; validated into ``Config``."""
    data = _defaults()
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


def _defaults() -> dict[str, object]:
    """default.yaml's mapping, parsed once per content of the file (a detect run loads the config twice: the
    command's and the default noise prior ``sources.presets`` compares with); a copy each time, so no caller
    changes the parsed one."""
    if not DEFAULT_CONFIG.is_file():
        return read_yaml_mapping(DEFAULT_CONFIG)  # says what is wrong with it
    return copy.deepcopy(_parsed_defaults(read_yaml_text(DEFAULT_CONFIG)))


@functools.lru_cache(maxsize=1)
def _parsed_defaults(text: str) -> dict[str, object]:
    """default.yaml's mapping by its text: reading the few KB is cheap, parsing them is not (~45 ms)."""
    return yaml_text_mapping(text, DEFAULT_CONFIG)


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


def _leaves(data: Mapping[str, object], prefix: str = "") -> list[str]:
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


def parse_override(item: str) -> tuple[str, object]:
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


def merge(base: Mapping[str, object], over: Mapping[str, object], source: str, prefix: str = "") -> dict[str, object]:
    """Deep merge; a key unknown to ``base`` is an error (caught here so the source is named)."""
    out = dict(base)
    for key, value in over.items():
        path = f"{prefix}{key}"
        if key not in base and path in RENAMED_KEYS:
            raise ConfigError(path, f"removed; set {RENAMED_KEYS[path]} instead (the one key for it now)",
                              source=source)
        if key not in base:
            raise ConfigError(path, f"unknown key{_did_you_mean(str(key), base)}", source=source)
        section = base[key]
        if isinstance(section, dict):
            if not isinstance(value, dict):
                raise ConfigError(path, f"expected a section (mapping), got {_kind(value)}", source=source)
            out[key] = merge(section, value, source, prefix=f"{path}.")
        else:
            out[key] = value
    return out


def _nest(key: str, value: object) -> dict[str, object]:
    """``a.b``, v -> ``{"a": {"b": v}}``."""
    *outer, last = key.split(".")
    out: dict[str, object] = {last: value}
    for part in reversed(outer):
        out = {part: out}
    return out
