"""Output folders slz owns (a ``slz detect`` run folder, a ``slz compare`` folder): slz deletes only what it wrote.

A folder is slz's when its marker file (``run.json``, ``compare.json``) carries ``slz_output``:
the kind of folder, its state (``finished``, or ``replacing`` while a run swaps its files in)
and the manifest: the names slz wrote at the folder's top level. Anything else in the folder
(``ibvs*/`` of ``slz land simulate``, a user's notes) is not slz's and is never moved or
removed. Folders written before the manifest existed are recognised by their marker's keys and
their kind's fixed list of names.

``build`` makes a folder under a temporary name beside it (``.NAME.<random>.partial``, marked as
slz's temporary: ``safe_output``) and puts
it in place at the end: renamed whole when ``NAME`` does not exist (or is an empty folder), else
swapped name by name: the marker first becomes ``replacing`` (listing the old and the new names,
so a run killed half-way leaves a folder the next run recognises and redoes), the old names move
to a marked ``.NAME.<random>.old``, the new ones move in, the finished marker last. An existing path that is not
a folder of the same kind is refused with a one-line reason; it is never emptied. The
temporary folders are removed by ``run_lock.claim`` when a writer was killed.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from slzcli.errors import OutputError, SlzError
from slzcli.outputs import files, safe_output

MARKER_KEY = "slz_output"
FINISHED, REPLACING = "finished", "replacing"


@dataclass(frozen=True)
class Kind:
    """One kind of output folder: its marker file, the names it may hold, and how older folders are told apart."""

    name: str                                # "detect", "compare": stored in the marker
    label: str                               # for messages: "slz detect run folder"
    marker: str                              # run.json, compare.json
    names: tuple[str, ...]                   # top-level names a run of this kind always may write
    legacy_keys: tuple[str, ...]             # a marker without slz_output but with these keys: an older slz's
    legacy_names: Callable[[Mapping[str, object]], tuple[str, ...]]  # what that older slz wrote, from its marker
    cohabits: tuple[str, ...] = ()           # kinds whose folder this kind may share (disjoint names)


@dataclass(frozen=True)
class Existing:
    """What is at an output path now: slz's names there, whether it is a finished folder, its marker."""

    path: Path
    names: tuple[str, ...] = ()
    finished: bool = False
    marker: dict[str, Any] | None = None  # as read (JSON); pipeline.run and fingerprint read a run.json's keys

    @property
    def empty(self) -> bool:
        return not self.names and self.marker is None


def read_marker(path: Path, kind: Kind) -> dict[str, object] | None:
    """The marker document of ``path`` when it is a folder of ``kind`` (any state), else None."""
    from slzcli.bounds import load_json

    try:
        doc = load_json(Path(path) / kind.marker, kind.marker)
    except SlzError:  # missing, not JSON, not a file, too large or deep: not slz's
        return None
    if not isinstance(doc, dict):
        return None
    mark = doc.get(MARKER_KEY)
    if isinstance(mark, dict):
        return doc if mark.get("kind") == kind.name and isinstance(mark.get("files"), list) else None
    return doc if all(k in doc for k in kind.legacy_keys) else None


def inspect(path: Path, kind: Kind) -> Existing:
    """What is at ``path``; OutputError (one line, naming it) when it is there but not slz's of this kind."""
    path = Path(path)
    if not os.path.lexists(path):
        return Existing(path)
    if not path.is_dir():
        raise OutputError(path, f"exists and is not a folder; an {kind.label} goes here: move it away or choose "
                                "another -o")
    doc = read_marker(path, kind)
    if doc is None:
        if not any(path.iterdir()):
            return Existing(path)
        if any(read_marker(path, KINDS[k]) is not None for k in kind.cohabits):
            return Existing(path)  # the other kind's files stay; check_names keeps the new names off them
        other = next((k for k in KINDS.values() if k is not kind and read_marker(path, k) is not None), None)
        what = f"an {other.label}, not an {kind.label}" if other else f"not an {kind.label} (no {kind.marker} of slz)"
        raise OutputError(path, f"exists and is {what}; slz does not write into it: choose another -o")
    mark = doc.get(MARKER_KEY)
    if isinstance(mark, dict):
        names = tuple(str(n) for n in mark["files"])
        return Existing(path, names, mark.get("state") == FINISHED, doc)
    return Existing(path, tuple(n for n in kind.legacy_names(doc) if os.path.lexists(path / n)), True, doc)


def refuse_inputs(out: Path, inputs: Sequence[Path]) -> None:
    """OutputError when ``out`` is one of the inputs or holds one (writing there could remove it)."""
    safe_output.refuse_inputs(out, inputs)


def check_names(existing: Existing, new: Sequence[str]) -> None:
    """OutputError when a name slz is about to write is already taken by something slz did not write there."""
    taken = [n for n in new if n not in existing.names and os.path.lexists(existing.path / n)]
    if taken:
        raise OutputError(existing.path / taken[0], "exists and was not written by slz; move it away or choose "
                                                    "another -o")


@contextmanager
def build(path: Path, kind: Kind, *, replace: bool) -> Iterator[Path]:
    """Yield a temporary folder to write into; on success put it at ``path`` (see the module docstring).

    ``replace``: a finished folder of this kind at ``path`` may be replaced (``--force``, or the caller
    decided it is outdated); an unfinished one (a killed swap) always may. Nothing is changed when the
    yielded block fails: the temporary folder is removed.
    """
    path = Path(path)
    existing = inspect(path, kind)
    if existing.finished and not replace:
        raise OutputError(path, f"already holds a finished {kind.label} (use --force to replace it, or another -o)")
    check_names(existing, kind.names)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = safe_output.make_temp_dir(path, ".partial")
    except OSError as err:
        raise OutputError(path, f"cannot create output folder ({err.strerror})") from err
    try:
        try:
            yield tmp
        except OutputError as err:  # name the folder's own path, not its temporary name
            raise OutputError(err.path.replace(str(tmp), str(path), 1), err.reason) from err
        except OSError as err:
            if err.errno not in files.WRITE_ERRNOS:
                raise
            where = err.filename.replace(str(tmp), str(path), 1) if isinstance(err.filename, str) else path
            raise OutputError(where, f"cannot write ({err.strerror or err})") from err
        with files.naming_write_errors(path):
            os.chmod(tmp, 0o777 & ~files.UMASK)  # mkdtemp makes 0700; a finished folder gets the user's usual mode
            new = safe_output.entries(tmp)
            _mark(tmp / kind.marker, kind, FINISHED, new)
        _commit(tmp, path, kind, new)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _mark(marker: Path, kind: Kind, state: str, names: Sequence[str], doc: dict[str, object] | None = None) -> None:
    """Write the marker with slz_output first: the kind, the state and the manifest."""
    if doc is None:
        doc = json.loads(marker.read_text()) if marker.is_file() else {}
    doc.pop(MARKER_KEY, None)
    files.write_json(marker, {MARKER_KEY: {"kind": kind.name, "state": state, "files": list(names)}, **doc})


def _commit(tmp: Path, path: Path, kind: Kind, new: list[str]) -> None:
    existing = inspect(path, kind)  # again: the user may have put something there while the run worked
    check_names(existing, new)
    try:
        if existing.empty and not path.is_symlink() and not (path.is_dir() and any(path.iterdir())):
            safe_output.unmark(tmp)
            os.replace(tmp, path)  # a missing path, or an empty folder (rename replaces an empty directory)
            return
        trash = safe_output.make_temp_dir(path, ".old")
        _mark(path / kind.marker, kind, REPLACING, sorted(set(existing.names) | set(new)), doc={})
        for name in existing.names:
            if name != kind.marker and os.path.lexists(path / name):
                os.replace(path / name, trash / name)
        for name in new:
            if name != kind.marker:
                os.replace(tmp / name, path / name)
        os.replace(tmp / kind.marker, path / kind.marker)  # the switch: from here it is the new finished folder
        shutil.rmtree(trash, ignore_errors=True)
        safe_output.unmark(tmp)
        tmp.rmdir()
    except OSError as err:
        raise OutputError(path, f"cannot put the results in place ({err.strerror or err})") from err


# ----------------------------------------------------------------------------- the kinds
DETECT_NAMES = ("run.json", "landing.json", "sites.csv", "points.ply", "trajectory.tum", "keyframes.npz",
                "results.mcap", "frames", "report.html")
COMPARE_NAMES = ("compare.json", "compare.csv", "report.html")


def _objects(value: object) -> list[dict[str, object]]:
    """The JSON objects in a list read from a marker (none when it is not a list)."""
    return [r for r in value if isinstance(r, dict)] if isinstance(value, list) else []


def _compare_legacy(doc: Mapping[str, object]) -> tuple[str, ...]:
    """A compare folder of an older slz: its fixed files, one figure folder per recording, the variants."""
    recs = [r.get("name") for r in _objects(doc.get("recordings"))]
    bases = {r.get("recording") for r in _objects(doc.get("variant_table"))}
    return (*COMPARE_NAMES, "variants", *(str(n) for n in recs if n), *(f"variants_{b}.png" for b in bases if b))


DETECT = Kind("detect", "slz detect run folder", "run.json", DETECT_NAMES, ("config_hash", "summary", "input"),
              lambda doc: DETECT_NAMES)
COMPARE = Kind("compare", "slz compare folder", "compare.json", COMPARE_NAMES, ("methods", "recordings", "config_hash"),
               _compare_legacy)
SIMULATE_NAMES = ("metrics.json", "trajectory.csv", "features.csv", "image_plane.png", "feature_error.png",
                  "trajectory_3d.png")
MONTECARLO_NAMES = ("montecarlo.json", "montecarlo_runs.csv", "montecarlo_hist.png")
SIMULATE = Kind("simulate", "slz land simulate folder", "metrics.json", SIMULATE_NAMES,
                ("success", "reason", "landing_time_s"), lambda doc: SIMULATE_NAMES, cohabits=("montecarlo",))
MONTECARLO = Kind("montecarlo", "slz land simulate --runs folder", "montecarlo.json", MONTECARLO_NAMES,
                  ("runs", "success_rate", "reasons"), lambda doc: MONTECARLO_NAMES, cohabits=("simulate",))
KINDS = {k.name: k for k in (DETECT, COMPARE, SIMULATE, MONTECARLO)}
