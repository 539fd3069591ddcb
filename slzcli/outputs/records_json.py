"""The records of ``slzcli/records.py`` to JSON objects and back: the one codec of landing.json, run.json and
the run summary.

A record's fields, in their declared order, are its JSON keys in that order; ``records.OMIT_NONE``/
``OMIT_FALSE`` fields are left out when None/False and a ``FLATTEN`` field's keys are written into its
holder's. Values are written as they are (tuples as lists): ``files.json_text`` takes care of numpy
scalars and non-finite floats. Reading back (a finished run's run.json and landing.json) follows the type
hints: nested records and tuples are rebuilt, a missing key takes the field's default (a file written by
an earlier slz), keys the record does not know are ignored.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import TypeVar

R = TypeVar("R")


def to_json(value: object) -> object:
    """``value`` as plain JSON values (dicts, lists, scalars), records by their fields (see the docstring)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, object] = {}
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            mode = f.metadata.get("json")
            if (mode == "omit_none" and v is None) or (mode == "omit_false" and v is False):
                continue
            if mode == "flatten":
                if v is not None:
                    out.update(typing.cast(dict[str, object], to_json(v)))
                continue
            out[f.name] = to_json(v)
        return out
    if isinstance(value, Mapping):
        return {k: to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    return value


def to_json_object(record: object) -> dict[str, object]:
    """A record as its JSON object (``to_json`` of a dataclass instance)."""
    out = to_json(record)
    if not isinstance(out, dict):
        raise TypeError(f"{type(record).__name__} is not a record")
    return out


def from_json(cls: type[R], data: Mapping[str, object]) -> R:
    """The record ``cls`` from a JSON object ``to_json`` wrote (see the docstring)."""
    hints = _hints(cls)
    kwargs: dict[str, object] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        hint = hints[f.name]
        if f.metadata.get("json") == "flatten":
            sub = _optional(hint)
            first = dataclasses.fields(sub)[0].name
            kwargs[f.name] = from_json(sub, data) if first in data else None
        elif f.name in data:
            kwargs[f.name] = _value(hint, data[f.name])
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            kwargs[f.name] = None  # a key an earlier slz did not write
    return cls(**kwargs)


def _hints(cls: object) -> dict[str, object]:
    return typing.get_type_hints(cls)


def _optional(hint: object) -> typing.Any:
    """``X`` of ``X | None`` (else ``hint``)."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and len(args) == 1:
        return args[0]
    return hint


def _value(hint: object, v: object) -> object:
    if v is None:
        return None
    hint = _optional(hint)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(v, Mapping):
        return from_json(hint, v)
    if typing.get_origin(hint) is Mapping and isinstance(v, Mapping):  # Mapping[str, X]: its values as X
        return {k: _value(typing.get_args(hint)[1], x) for k, x in v.items()}
    if typing.get_origin(hint) is tuple and isinstance(v, list):
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_value(args[0], x) for x in v)
        return tuple(_value(a, x) for a, x in zip(args, v, strict=False))
    return v
