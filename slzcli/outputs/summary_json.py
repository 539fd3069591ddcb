"""The ``--json`` summaries of ``slz detect``, a batch and ``slz compare``: one versioned schema.

``slzcli/schemas/summary.schema.json`` (JSON Schema 2020-12, packaged) describes all three and the
error object; ``SCHEMA_VERSION`` is its ``schema_version``: the major number changes when a field is
removed or changes meaning, the minor number when one is added. Floats are rounded here
(``rounded``) so that float noise (``19.999999999999996``) never reaches a script: at most
``DECIMALS`` decimals (micrometres, microseconds, millionths of a degree), and below 1 at most
``SIGNIFICANT`` significant digits so that small values (depth noise ``a`` in 1/m, variances)
keep their precision.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, overload

from slzcli.outputs.records_json import from_json, to_json_object
from slzcli.records import RunSummary

if TYPE_CHECKING:  # the compare records hold numpy arrays; the command line imports this module without numpy
    from slzcli.compare_records import Comparison, ProfileComparison

SCHEMA_VERSION = "1.3"
DECIMALS = 6       # digits after the point for |x| >= 1; project decision (1 um, 1 us)
SIGNIFICANT = 10   # significant digits for |x| < 1; project decision (keeps 1e-7 variances)


def schema_path() -> Path:
    """The packaged JSON Schema file."""
    from slzcli.config import package_dir

    return package_dir("schemas", "summary.schema.json")


def round_float(x: float) -> float:
    """``x`` without float noise (see the module docstring); NaN and inf unchanged (``json_text`` nulls them)."""
    if not math.isfinite(x) or x == 0:
        return x
    if abs(x) >= 1:
        return round(x, DECIMALS)
    return float(f"{x:.{SIGNIFICANT}g}")


class Exact(dict[str, object]):
    """A JSON object printed unrounded: values a user feeds back (``slz config dump --json``) must round-trip."""


@overload
def rounded(obj: dict[str, object]) -> dict[str, object]: ...
@overload
def rounded(obj: object) -> object: ...


def rounded(obj: object) -> object:
    """``obj`` with every float (in dicts, lists, tuples) rounded by ``round_float``; ints and bools kept."""
    if isinstance(obj, Exact):
        return obj
    if isinstance(obj, float):
        return round_float(obj)
    if isinstance(obj, dict):
        return {k: rounded(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [rounded(v) for v in obj]
    return obj


def summary_json(summary: RunSummary) -> dict[str, object]:
    """A run's summary as run.json's ``summary`` and ``slz detect --json`` (before ``envelope``) hold it."""
    return to_json_object(summary)


def read_summary(data: Mapping[str, object]) -> RunSummary:
    """The summary of a finished run's run.json (a rerun with the same key gives it back, marked ``skipped``)."""
    return from_json(RunSummary, data)


def compare_summary(comparison: Comparison | ProfileComparison, output: str) -> dict[str, object]:
    """``slz compare --json`` (before ``envelope``): the comparison as compare.json has it, then the output folder."""
    return {**to_json_object(comparison), "output": output}


def envelope(command: str, summary: Mapping[str, object]) -> dict[str, object]:
    """The summary with ``schema_version`` and ``command`` first, floats rounded."""
    return rounded({"schema_version": SCHEMA_VERSION, "command": command, **summary})


def error_object(message: str, exit_code: int, err: BaseException | None = None) -> dict[str, object]:
    """A failure under ``--json``: ``{"schema_version", "error": {"message", "exit_code", "kind", "file", "key"}}``.

    ``err`` None: a usage error. An error may carry ``detail`` ({"kind", "file", "key"}) when it was
    raised elsewhere (a batch worker) and only its text and detail came back.
    """
    body: dict[str, object] = {"message": message, "exit_code": exit_code,
                            "kind": "usage" if err is None else type(err).__name__}
    path, key = getattr(err, "path", None), getattr(err, "key", None)
    if isinstance(path, str):
        body["file"] = path
    if isinstance(key, str) and key:
        body["key"] = key
    detail = getattr(err, "detail", None)
    if isinstance(detail, dict):
        body.update({k: str(v) for k, v in detail.items() if k in ("kind", "file", "key")})
    return {"schema_version": SCHEMA_VERSION, "error": body}
