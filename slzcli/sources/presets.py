"""Camera presets (``configs/camera/*.yaml``): topic layouts, intrinsics and noise priors of known cameras.

A preset is chosen by name (``camera.preset`` / ``--camera NAME``) or guessed: from the topics of a
bag (the first preset, in ``order``, whose colour and depth patterns both match a topic, and whose
``hint`` appears in a topic name when it has one), or from a TUM folder's name (``freiburg1``). What
a preset gives is used only where the recording is silent: ``sources.topics.*`` beats its topics,
a CameraInfo beats its intrinsics. The files document their sources beside each value.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml

from slzcli.config import (
    CONFIG_DIR,
    Config,
    read_yaml_text,
    safe_yaml_load,
    yaml_float,
    yaml_floats,
    yaml_int,
    yaml_mapping,
)
from slzcli.errors import ConfigError
from slzcli.types import Intrinsics

PRESET_DIR = CONFIG_DIR / "camera"
ROLES = ("color", "depth", "camera_info", "depth_info")
AUTO, NONE = "auto", "none"


@dataclass(frozen=True)
class CameraPreset:
    name: str
    description: str
    order: int
    hint: str
    topics: Mapping[str, str]          # role -> regular expression a topic must match in full ("" = none)
    depth_aligned: bool
    folder: str
    intrinsics: Intrinsics | None
    noise_prior_a_per_m: float
    min_range_m: float | None = None   # m; nearest depth the camera measures (None: sources.depth_check.min_range_m)

    def topic_for(self, role: str, topics: Collection[str]) -> str | None:
        """The first topic (sorted) matching the role's pattern, or None."""
        pattern = self.topics.get(role, "")
        if not pattern:
            return None
        rx = re.compile(pattern)
        found = sorted(t for t in topics if rx.fullmatch(t))
        return found[0] if found else None


@dataclass(frozen=True)
class PresetChoice:
    """The preset in use (None: none) and why, for ``slz info`` and run.json."""

    preset: CameraPreset | None
    reason: str

    @property
    def name(self) -> str | None:
        return None if self.preset is None else self.preset.name

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "reason": self.reason,
                "noise_prior_a_per_m": None if self.preset is None else self.preset.noise_prior_a_per_m}


def _load(path: Path) -> CameraPreset:
    try:
        d = yaml_mapping(safe_yaml_load(read_yaml_text(path)))
        k = d.get("intrinsics")
        intr = None
        if k:
            k = yaml_mapping(k)
            intr = Intrinsics(yaml_float(k["fx"]), yaml_float(k["fy"]), yaml_float(k["cx"]), yaml_float(k["cy"]),
                              yaml_int(k["width"]), yaml_int(k["height"]), str(k.get("distortion_model") or ""),
                              yaml_floats(k.get("distortion")))
        roles = yaml_mapping(d["topics"])
        topics = {r: str(roles.get(r) or "") for r in ROLES}
        for pattern in [*topics.values(), str(d.get("hint") or ""), str(d.get("folder") or "")]:
            re.compile(pattern)
        return CameraPreset(str(d["name"]), str(d["description"]), yaml_int(d["order"]), str(d.get("hint") or ""),
                            topics, bool(d["depth_aligned"]), str(d.get("folder") or ""), intr,
                            yaml_float(d["noise_prior_a_per_m"]),
                            None if d["min_range_m"] is None else yaml_float(d["min_range_m"]))
    except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError, re.error) as err:
        raise ConfigError("", f"{path}: not a camera preset ({type(err).__name__}: {err})") from err


@functools.lru_cache(maxsize=1)
def all_presets() -> tuple[CameraPreset, ...]:
    """Every preset shipped, in guessing order."""
    return tuple(sorted((_load(p) for p in PRESET_DIR.glob("*.yaml")), key=lambda p: (p.order, p.name)))


def preset_names() -> list[str]:
    return sorted(p.name for p in all_presets())


def get_preset(name: str) -> CameraPreset:
    """The preset called ``name``; ConfigError naming ``camera.preset`` and the choices otherwise."""
    for p in all_presets():
        if p.name == name:
            return p
    raise ConfigError("camera.preset", f"no camera preset {name!r} (choices: {AUTO}, {NONE}, "
                                       f"{', '.join(preset_names())})")


def guess_from_topics(topics: Collection[str]) -> PresetChoice:
    """The first preset (in order) whose colour and depth patterns, and hint, match the recording's topics."""
    for p in all_presets():
        if not p.topics["color"] or not p.topics["depth"]:
            continue
        color, depth = p.topic_for("color", topics), p.topic_for("depth", topics)
        if color is None or depth is None:
            continue
        if p.hint and not any(re.search(p.hint, t, re.I) for t in topics):
            continue
        why = f"guessed from the topics {color} and {depth}"
        if p.hint:
            why += f" ({p.hint!r} in a topic name)"
        return PresetChoice(p, why)
    return PresetChoice(None, "no preset's topic layout matches (use --camera NAME to pick one)")


def guess_from_folder(path: Path) -> PresetChoice:
    """The TUM preset whose ``folder`` pattern is in the folder's name (rgbd_dataset_freiburg1_xyz -> tum_fr1)."""
    name = path.resolve().name
    for p in all_presets():
        if p.folder and re.search(p.folder, name, re.I):
            return PresetChoice(p, f"guessed from the folder name {name!r}")
    return PresetChoice(None, f"no preset matches the folder name {name!r} (use --camera tum_fr1/2/3 for a TUM "
                              "sequence)")


def choose_preset(setting: str, topics: Collection[str] | None = None, folder: Path | None = None) -> PresetChoice:
    """``camera.preset`` resolved for one recording: a name, ``none``, or ``auto`` (guessed)."""
    if setting == NONE:
        return PresetChoice(None, "camera.preset is none")
    if setting != AUTO:
        return PresetChoice(get_preset(setting), "set by camera.preset / --camera")
    if folder is not None:
        return guess_from_folder(folder)
    return guess_from_topics(topics or ())


@functools.lru_cache(maxsize=1)
def _default_prior() -> float:
    from slzcli.config import load_config

    return load_config().terrain.noise_estimate.prior_a_per_m


def with_noise_prior(config: Config, preset_name: str | None) -> Config:
    """``config`` with the preset's depth noise prior (``terrain.noise_estimate.prior_a_per_m``).

    Only where that key still holds its default: a value the user set (``--set``, ``--config``) wins.
    The prior is used before any frame's own depth could be measured (terrain/noise.py).
    """
    if preset_name is None or config.terrain.noise_estimate.prior_a_per_m != _default_prior():
        return config
    prior = get_preset(preset_name).noise_prior_a_per_m
    est = dataclasses.replace(config.terrain.noise_estimate, prior_a_per_m=prior)
    return dataclasses.replace(config, terrain=dataclasses.replace(config.terrain, noise_estimate=est))
