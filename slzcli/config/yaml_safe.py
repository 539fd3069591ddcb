"""YAML read within bounds (size, aliases, values, depth): a config file cannot exhaust memory or the stack,
and every refusal names the file."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import yaml

from slzcli.errors import ConfigError, short_repr

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

    def __init__(self, reason: str, mark: yaml.Mark | None = None) -> None:
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

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
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


def safe_yaml_load(text: str) -> object:
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


def read_yaml_mapping(path: Path) -> dict[str, object]:
    if not path.is_file():
        what = "not a regular file (a FIFO, device or folder)" if path.exists() else "config file not found"
        raise ConfigError("", what, source=str(path))
    return yaml_text_mapping(read_yaml_text(path), path)


def yaml_text_mapping(text: str, path: Path) -> dict[str, object]:
    """The mapping of a YAML file's text (read by ``read_yaml_text``); ConfigError naming the file otherwise."""
    data = _load_yaml_text(text, path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError("", "the top level must be a mapping of sections", source=str(path))
    return data


def _load_yaml_text(text: str, path: Path) -> object:
    """A YAML file's content within the loader's bounds; ConfigError naming the file otherwise."""
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



def _yaml_where(err: yaml.YAMLError) -> str:
    mark = getattr(err, "problem_mark", None)
    return f"line {mark.line + 1}, column {mark.column + 1}" if mark else str(err).splitlines()[0]


# ----------------------------------------------------------------------------- reading values of a YAML file
# What float()/int() accept from a YAML document (numbers, numeric strings); TypeError for anything else, as
# float(None) or float([1]) would raise: callers turn it into an error naming their file.
def yaml_mapping(value: object) -> Mapping[str, object]:
    """``value`` when it is a YAML mapping; TypeError otherwise."""
    if not isinstance(value, dict):
        raise TypeError(f"expected a mapping, got {type(value).__name__}")
    return value


def yaml_float(value: object) -> float:
    if isinstance(value, (int, float, str)):
        return float(value)
    raise TypeError(f"expected a number, got {type(value).__name__}")


def yaml_int(value: object) -> int:
    if isinstance(value, (int, float, str)):
        return int(value)
    raise TypeError(f"expected an integer, got {type(value).__name__}")


def yaml_floats(value: object) -> tuple[float, ...]:
    """A list of numbers; nothing (null, an empty list) is ``()``."""
    if not value:
        return ()
    if not isinstance(value, list):
        raise TypeError(f"expected a list of numbers, got {type(value).__name__}")
    return tuple(yaml_float(v) for v in value)
