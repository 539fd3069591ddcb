"""``slz config dump``: the resolved config as YAML with default.yaml's comments (unit and source of every key)."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from typing import Any

from slzcli.config.loader import _yaml_lines
from slzcli.config.schema import DEFAULT_CONFIG, Config


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
