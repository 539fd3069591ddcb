"""The SlzError family: every failure a user can act on, with the file, topic or key it concerns.

Library code raises these; only ``cli.py`` prints them and chooses the exit code.
Third-party errors are wrapped once, at the boundary where they happen
(``raise DatasetError(path, str(err)) from err``).
"""

from __future__ import annotations

import reprlib
from pathlib import Path


class SlzError(Exception):
    """Base of every error slz reports to a user (exit code 1)."""


class ConfigError(SlzError):
    """A config file, key or value is wrong; the message names the dotted key path."""

    def __init__(self, key: str, reason: str, source: str | None = None) -> None:
        self.key = key
        self.reason = reason
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key}: {reason}" if key else f"{where}{reason}")

    def __reduce__(self) -> tuple[type, tuple[str, str, str | None]]:  # picklable: crosses process pools
        return type(self), (self.key, self.reason, self.source)


class _PathError(SlzError):
    """An error about one path: the message is ``path: reason``; picklable (crosses process pools)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.path, self.reason)


class DatasetError(_PathError):
    """A recording cannot be read or does not hold what slz needs; names the path."""


class DecodeError(SlzError):
    """One message could not be decoded (unsupported encoding, wrong size, ...)."""


class FrameError(SlzError):
    """One frame's content cannot be used (e.g. depth in another unit than its encoding says); the
    detection loop names the recording and the frame."""


class NoSiteFound(SlzError):
    """No landing site qualifies. A result, not a failure: the pipeline reports it as status."""


class OutputError(_PathError):
    """An output folder or file cannot be written."""


class StageTimeout(SlzError):
    """One stage of a run took longer than ``--timeout``; names the recording and the stage.

    Raised inside the stage (see ``slzcli/timeout.py``); the defaults are what a stage interrupted
    from another thread can carry, before ``StageLimit`` replaces it with the full message.
    """

    def __init__(self, where: str = "", stage: str = "a stage", limit_s: float | None = None) -> None:
        self.where, self.stage, self.limit_s = where, stage, limit_s
        limit = f" {limit_s:g} s" if limit_s is not None else ""
        prefix = f"{where}: " if where else ""
        super().__init__(f"{prefix}{stage} took longer than --timeout{limit}; the run was stopped and left no "
                         "output (raise --timeout, or see the README's failure modes)")

    def __reduce__(self) -> tuple[type, tuple[str, str, float | None]]:
        return type(self), (self.where, self.stage, self.limit_s)


# ----------------------------------------------------------------------------- bounded values in messages
def _bounded_repr() -> reprlib.Repr:
    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxtuple, r.maxdict, r.maxset = 3, 6, 6, 4, 6
    r.maxstring, r.maxother, r.maxlong = 200, 200, 40
    return r


_REPR = _bounded_repr()


def short_repr(value: object, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, built without ever making the whole repr.

    A value from a config or a recording can be huge (a YAML alias bomb expands to gigabytes
    when printed; a crafted topic or format string to megabytes): an error line stays one short line.
    """
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: max(limit - 3, 1)] + "..."
