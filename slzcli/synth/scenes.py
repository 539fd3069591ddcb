"""Scene definitions for ``slz synth``: YAML files in ``slzcli/synth/scenes/`` -> frozen dataclasses.

``datasets/scenes/`` at the top of the repo is a link to that folder.

A scene is data: a ground (plane with an optional gentle slope and smooth undulation),
materials, and primitives (box, cylinder, cone, sphere, ramp, stairs). Primitives that share
an ``object`` name form one object (one id in the ground-truth object image). ``repeat``
replicates a primitive on a grid (rows of cars, clutter). Variants (``scene:sand+low_light``)
swap the ground material or the illumination; they are defined in ``_common.yaml`` and may
be extended per scene. Unknown keys are rejected with the file and the key path.
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, TypeVar

import numpy as np
import yaml

from slzcli.config import package_dir, read_yaml_text, safe_yaml_load
from slzcli.errors import ConfigError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

_D = TypeVar("_D", bound="DataclassInstance")

SCENES_DIR = package_dir("synth", "scenes")
COMMON_FILE = "_common.yaml"

TextureKind = Literal["plain", "noise", "tiles", "stripes"]


class SceneError(ConfigError):
    """A scene file, key or value is wrong; names the file and the key path."""


# ----------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class Material:
    """Base colour (linear RGB in [0, 1]) and a procedural texture evaluated in world coordinates."""

    color: tuple[float, ...]
    color2: tuple[float, ...] | None = None   # second colour mixed in by low-frequency noise
    texture: TextureKind = "noise"
    scale_m: float = 0.4                       # size of the coarsest texture feature
    octaves: int = 4
    persistence: float = 0.5                   # amplitude ratio of each octave to the previous one
    contrast: float = 0.3                      # +- fraction of brightness the texture varies
    grain: float = 0.0                         # +- brightness of sharp-edged specks (stones, blades)
    grain_scale_m: float = 0.05                # size of those specks


@dataclass(frozen=True)
class Illumination:
    """Scene lighting: global gain and contrast (about mid-grey) applied after shading."""

    gain: float = 1.0
    contrast: float = 1.0


@dataclass(frozen=True)
class Ground:
    """A square-ish ground patch: plane through (center, base_z) rising slope_deg towards azimuth."""

    size_m: tuple[float, ...]
    center_m: tuple[float, ...] = (0.0, 0.0)
    base_z_m: float = 0.0
    slope_deg: float = 0.0
    slope_azimuth_deg: float = 0.0             # direction of ascent, from world +x towards +y
    undulation_m: float = 0.0                  # amplitude of smooth bumps
    undulation_scale_m: float = 4.0
    mesh_step_m: float = 0.25
    material: str = "asphalt"
    seed: int = 0

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height z(x, y), vectorised; smooth so its slope stays gentle."""
        az = np.deg2rad(self.slope_azimuth_deg)
        cx, cy = self.center_m
        along = (x - cx) * np.cos(az) + (y - cy) * np.sin(az)
        z = self.base_z_m + np.tan(np.deg2rad(self.slope_deg)) * along
        if self.undulation_m > 0:
            rng = np.random.default_rng(self.seed)
            ph = rng.uniform(0, 2 * np.pi, 4)
            k = 2 * np.pi / self.undulation_scale_m
            z = z + 0.5 * self.undulation_m * (
                np.sin(k * x + ph[0]) * np.cos(0.7 * k * y + ph[1])
                + np.sin(0.6 * k * (x + y) + ph[2]) * np.cos(0.9 * k * x - 0.4 * k * y + ph[3]))
        return z


@dataclass(frozen=True)
class Repeat:
    """Replicate a primitive on a count[0] x count[1] grid with pitch, seeded jitter and yaw jitter."""

    count: tuple[int, ...]
    pitch_m: tuple[float, ...]
    jitter_m: float = 0.0
    yaw_jitter_deg: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class Primitive:
    """One solid. ``at_m`` = (x, y[, dz]): base centre, dz above the ground there (0 = standing on it).

    Sizes by kind: box size_m (sx, sy, sz); cylinder/cone radius_m, height_m; sphere radius_m;
    ramp size_m (run along local x, width, unused) and angle_deg (rises towards local +x);
    stairs steps, rise_m, run_m, width_m (ascending towards local +x).
    """

    kind: Literal["box", "cylinder", "cone", "sphere", "ramp", "stairs"]
    at_m: tuple[float, ...]
    material: str
    name: str = ""
    object: str = ""                           # primitives with the same object name share an id
    landable: bool | None = None               # default: ramps and stairs treads no, see below
    yaw_deg: float = 0.0
    size_m: tuple[float, ...] = ()
    radius_m: float = 0.0
    height_m: float = 0.0
    angle_deg: float = 0.0
    steps: int = 0
    rise_m: float = 0.0
    run_m: float = 0.0
    width_m: float = 0.0
    repeat: Repeat | None = None

    @property
    def is_landable(self) -> bool:
        """Only surfaces a UAV may sit on count: the ground and ramps (their slope decides)."""
        if self.landable is not None:
            return self.landable
        return self.kind == "ramp"


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    ground: Ground
    materials: dict[str, Material]
    primitives: tuple[Primitive, ...]
    illumination: Illumination = Illumination()
    variants: tuple[str, ...] = ()             # applied variants, e.g. ("sand", "low_light")
    available_variants: tuple[str, ...] = ()
    source: str = ""
    scenario: int = 1                          # paper start (synth.scenarios) used when none is given


@dataclass(frozen=True)
class Variant:
    description: str
    ground_material: str | None = None
    illumination: Illumination | None = None


# ----------------------------------------------------------------------------- loading
def scene_names(scenes_dir: Path = SCENES_DIR) -> list[str]:
    """Scene names available in ``scenes_dir`` (files starting with ``_`` are shared data)."""
    return sorted(p.stem for p in scenes_dir.glob("*.yaml") if not p.name.startswith("_"))


def list_scenes(scenes_dir: Path = SCENES_DIR) -> list[tuple[str, str, tuple[str, ...]]]:
    """(name, one-line description, variants) of every scene."""
    out = []
    for name in scene_names(scenes_dir):
        scene = load_scene(name, scenes_dir=scenes_dir)
        out.append((name, scene.description, scene.available_variants))
    return out


def split_spec(spec: str) -> tuple[str, tuple[str, ...]]:
    """``parking_lot:sand+low_light`` -> ("parking_lot", ("sand", "low_light"))."""
    name, _, rest = spec.partition(":")
    variants = tuple(v for v in rest.replace(",", "+").split("+") if v)
    return name, variants


def load_scene(spec: str | Path, variants: typing.Sequence[str] = (), scenes_dir: Path = SCENES_DIR) -> Scene:
    """Load a scene by name (``name[:variant+variant]``) or by path, and apply variants."""
    spec_s = str(spec)
    spec_variants: tuple[str, ...]
    if spec_s.endswith((".yaml", ".yml")) and Path(spec_s).is_file():
        path, spec_variants = Path(spec_s), ()
    else:
        name, spec_variants = split_spec(spec_s)
        path = scenes_dir / f"{name}.yaml"
        if not path.is_file():
            known = scene_names(scenes_dir)
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SceneError("", f"unknown scene {name!r}{hint}; known: {', '.join(known)}",
                             source=str(scenes_dir))
    common_path = path.parent / COMMON_FILE
    common = _read(common_path) if common_path.is_file() else {}
    _only_keys(common, {"materials", "variants"}, "", str(common_path))
    data = _read(path)
    _only_keys(data, {"description", "scenario", "ground", "materials", "objects", "illumination", "variants"},
               "", str(path))
    scenario = data.get("scenario", 1)
    if scenario not in (1, 2, 3, 4):
        raise SceneError("scenario", f"must be 1, 2, 3 or 4 (synth.scenarios), got {scenario!r}", source=str(path))
    for key in ("description", "ground", "objects"):
        if key not in data:
            raise SceneError(key, "missing key", source=str(path))

    materials = {k: _build(Material, v, f"materials.{k}", str(common_path))
                 for k, v in _mapping(common.get("materials"), "materials", str(common_path)).items()}
    materials.update({k: _build(Material, v, f"materials.{k}", str(path))
                      for k, v in _mapping(data.get("materials"), "materials", str(path)).items()})
    variant_defs = {k: _build(Variant, v, f"variants.{k}", str(common_path))
                    for k, v in _mapping(common.get("variants"), "variants", str(common_path)).items()}
    variant_defs.update({k: _build(Variant, v, f"variants.{k}", str(path))
                         for k, v in _mapping(data.get("variants"), "variants", str(path)).items()})

    ground = _build(Ground, data["ground"], "ground", str(path))
    illum = _build(Illumination, data.get("illumination") or {}, "illumination", str(path))
    objects = data["objects"]
    if not isinstance(objects, list):
        raise SceneError("objects", "expected a list of primitives", source=str(path))
    prims = tuple(_build(Primitive, o, f"objects[{i}]", str(path)) for i, o in enumerate(objects))
    prims = tuple(_named(p, i) for i, p in enumerate(prims))
    for i, p in enumerate(prims):
        _check_primitive(p, f"objects[{i}]", materials, str(path))
    if ground.material not in materials:
        raise SceneError("ground.material", f"unknown material {ground.material!r}", source=str(path))

    applied = tuple(spec_variants) + tuple(variants)
    for v in applied:
        if v not in variant_defs:
            raise SceneError("variant", f"unknown variant {v!r} of scene {path.stem!r}; "
                             f"known: {', '.join(sorted(variant_defs))}", source=str(path))
        vd = variant_defs[v]
        if vd.ground_material is not None:
            if vd.ground_material not in materials:
                raise SceneError(f"variants.{v}.ground_material", f"unknown material {vd.ground_material!r}",
                                 source=str(path))
            ground = dataclasses.replace(ground, material=vd.ground_material)
        if vd.illumination is not None:
            illum = vd.illumination
    return Scene(name=path.stem, description=str(data["description"]).strip(), ground=ground,
                 materials=materials, primitives=prims, illumination=illum, variants=applied,
                 available_variants=tuple(sorted(variant_defs)), source=str(path), scenario=scenario)


def _named(p: Primitive, i: int) -> Primitive:
    name = p.name or f"{p.kind}_{i}"
    return dataclasses.replace(p, name=name, object=p.object or name)


def _check_primitive(p: Primitive, where: str, materials: dict[str, Material], source: str) -> None:
    if p.material not in materials:
        raise SceneError(f"{where}.material", f"unknown material {p.material!r}", source=source)
    if len(p.at_m) not in (2, 3):
        raise SceneError(f"{where}.at_m", "expected [x, y] or [x, y, dz]", source=source)
    need = {"box": ("size_m",), "cylinder": ("radius_m", "height_m"), "cone": ("radius_m", "height_m"),
            "sphere": ("radius_m",), "ramp": ("size_m", "angle_deg"),
            "stairs": ("steps", "rise_m", "run_m", "width_m")}[p.kind]
    for key in need:
        value = getattr(p, key)
        if key == "size_m":
            if len(value) < (3 if p.kind == "box" else 2) or min(value) <= 0:
                raise SceneError(f"{where}.size_m", f"a {p.kind} needs positive sizes, got {list(value)}", source)
        elif not value or value <= 0:
            raise SceneError(f"{where}.{key}", f"a {p.kind} needs a positive {key}", source)
    if p.kind == "ramp" and not 0 < p.angle_deg < 80:
        raise SceneError(f"{where}.angle_deg", "a ramp angle must be in (0, 80) degrees", source)


def _read(path: Path) -> dict[str, object]:
    try:
        data = safe_yaml_load(read_yaml_text(path))
    except yaml.YAMLError as err:
        raise SceneError("", f"cannot read scene file ({str(err).splitlines()[0]})", source=str(path)) from err
    if not isinstance(data, dict):
        raise SceneError("", "a scene file must be a mapping", source=str(path))
    return data


def _mapping(value: object, where: str, source: str) -> Mapping[str, object]:
    """A section of names (``materials``, ``variants``); nothing is an empty one."""
    if not value:
        return {}
    if not isinstance(value, dict):
        raise SceneError(where, f"expected a mapping of names, got {type(value).__name__}", source=source)
    return value


def _only_keys(data: Mapping[str, object], allowed: set[str], where: str, source: str) -> None:
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), sorted(allowed), n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SceneError(f"{where}{key}", f"unknown key{hint}", source=source)


def _build(cls: type[_D], data: object, where: str, source: str) -> _D:
    """Validate a mapping into dataclass ``cls`` (defaults allowed, unknown keys rejected)."""
    if not isinstance(data, dict):
        raise SceneError(where, f"expected a mapping, got {type(data).__name__}", source=source)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    _only_keys(data, set(fields), f"{where}.", source)
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, object] = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SceneError(f"{where}.{name}", "missing key", source=source)
            continue
        kwargs[name] = _value(hints[name], data[name], f"{where}.{name}", source)
    return cls(**kwargs)


def _value(tp: object, value: object, where: str, source: str) -> object:
    """``value`` (untrusted YAML) as the type ``tp`` of a scene field."""
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _build(tp, value, where, source)
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            return None
        return _value(next(a for a in typing.get_args(tp) if a is not type(None)), value, where, source)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise SceneError(where, f"must be one of {', '.join(typing.get_args(tp))}; got {value!r}", source)
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SceneError(where, f"expected a list, got {type(value).__name__}", source=source)
        item = typing.get_args(tp)[0]
        return tuple(_value(item, v, f"{where}[{i}]", source) for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise SceneError(where, f"expected true or false, got {value!r}", source=source)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(where, f"expected an integer, got {value!r}", source=source)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(where, f"expected a number, got {value!r}", source=source)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise SceneError(where, f"expected a string, got {value!r}", source=source)
        return value
    raise SceneError(where, f"unsupported field type {tp}", source=source)  # pragma: no cover
