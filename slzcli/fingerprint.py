"""What a ``slz detect`` run depends on, by content: the key that decides whether a rerun is skipped.

The key is a sha256 over the resolved config's values, the fusion method, slz's version (and
pyorbslam3's when ORB-SLAM3 may run: installing it changes what ``slam.backend: auto`` picks), and
the bytes of every file the run reads: the recording (its format's ``files`` in ``sources/formats.py``:
for a rosbag2 folder ``metadata.yaml`` and the storage files it lists, for a TUM folder its lists,
``camera.yaml`` and the images the lists name: not the run folders or notes a user keeps beside them),
its ``slz synth`` ground-truth sidecars when both are there, the fuzzy rules file, and the ORB
vocabulary when ORB-SLAM3 may run.

Every file is hashed whole (sha256, streamed in ``HASH_BLOCK`` pieces: memory does not grow with
the file). The digests are kept in run.json with each file's identity (resolved path, size,
mtime_ns, ctime_ns, inode), and a rerun re-hashes only a file whose identity changed: a 5 GB bag
is read once, not on every rerun. ctime is set by the kernel on every write and no user tool sets
it back (``touch -d``, ``cp -p`` and ``rsync -t`` set mtime only), so an edit that keeps the size
and mtime still invalidates the cached digest.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections.abc import Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TypedDict, cast

from slzcli.config import Config
from slzcli.scoring.rules import resolve_rules_path
from slzcli.slam.vocabulary import DEFAULT_VOCABULARY
from slzcli.sources.formats import files_of
from slzcli.synth.groundtruth import BINDING_KEY, sidecar_paths
from slzcli.version import __version__

HASH_BLOCK = 1 << 20  # bytes read per step while hashing; I/O housekeeping, not tuning
_IDENTITY = ("size", "mtime_ns", "ctime_ns", "inode")


class Entry(TypedDict):
    """A file a run read: its identity and content (run.json's ``key.inputs`` rows)."""

    path: str        # resolved
    size: int
    mtime_ns: int
    ctime_ns: int
    inode: int
    sha256: str


def sha256_of(path: Path) -> str:
    """The sha256 of a file, read in blocks into one reused buffer."""
    h = hashlib.sha256()
    buf = bytearray(HASH_BLOCK)
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as fh:
        while n := fh.readinto(buf):
            h.update(view[:n])
    return h.hexdigest()


def digest(path: Path, cache: dict[str, Entry]) -> Entry:
    """A file's identity and sha256; the cached sha256 when the identity is the one recorded."""
    p = Path(path).resolve()
    st = p.stat()
    identity = {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "ctime_ns": st.st_ctime_ns, "inode": st.st_ino}
    old = cache.get(str(p))
    same = old is not None and all(old.get(k) == identity[k] for k in _IDENTITY) and isinstance(old.get("sha256"), str)
    sha = old["sha256"] if same and old is not None else sha256_of(p)
    return Entry(path=str(p), size=st.st_size, mtime_ns=st.st_mtime_ns, ctime_ns=st.st_ctime_ns, inode=st.st_ino,
                 sha256=sha)


def recording_files(path: Path) -> list[Path]:
    """The files a recording's reader reads (its format's ``files`` in ``sources/formats.py``); [] when there
    is nothing to read."""
    return files_of(Path(path))


def run_inputs(recording: Path, config: Config, cache: dict[str, Entry]) -> dict[str, list[Entry]]:
    """Every file the run reads, by role, with its identity and sha256."""
    sidecars = sidecar_paths(recording)
    roles: dict[str, list[Path]] = {
        "recording": recording_files(recording),
        "ground_truth": list(sidecars) if all(q.is_file() for q in sidecars) else [],
        "rules": [q for q in [resolve_rules_path(config.scoring.fuzzy.rules)] if q.is_file()],
        "vocabulary": [q for q in [_vocabulary(config)] if q is not None and q.is_file()],
    }
    return {role: [digest(q, cache) for q in paths] for role, paths in roles.items()}


class PendingInputs:
    """``run_inputs`` taken in a thread of its own, for a run whose key is only recorded (no finished run in
    its folder to compare the key with): the recording is hashed while the run opens it, instead of before.
    sha256 lets go of the GIL on each block, so the hashing takes the core the run's start leaves idle.
    A daemon thread: a run that fails first does not wait for it to finish."""

    def __init__(self, recording: Path, config: Config, cache: dict[str, Entry]) -> None:
        self._inputs: dict[str, list[Entry]] | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._take, args=(recording, config, cache),
                                        name="slz-hash-inputs", daemon=True)
        self._thread.start()

    def _take(self, recording: Path, config: Config, cache: dict[str, Entry]) -> None:
        try:
            self._inputs = run_inputs(recording, config, cache)
        except BaseException as err:  # raised again by result(), in the run's thread
            self._error = err

    def result(self) -> dict[str, list[Entry]]:
        """The inputs once hashed (waits); what hashing them raised."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._inputs is not None
        return self._inputs


def _may_use_orbslam3(config: Config) -> bool:
    return config.slam.backend in ("auto", "orbslam3")


def _vocabulary(config: Config) -> Path | None:
    if not _may_use_orbslam3(config):
        return None
    return Path(config.slam.vocabulary or DEFAULT_VOCABULARY).expanduser()


def versions(config: Config) -> dict[str, str | None]:
    """The versions in the key: slz's, and pyorbslam3's when the backend may be ORB-SLAM3."""
    out: dict[str, str | None] = {"slz": __version__}
    if _may_use_orbslam3(config):
        try:
            out["pyorbslam3"] = version("pyorbslam3")
        except PackageNotFoundError:
            out["pyorbslam3"] = None
    return out


def run_key(config: Config, method: str, inputs: dict[str, list[Entry]], vers: dict[str, str | None]) -> str:
    """The skip key: equal keys mean the same config values, method, versions and file contents."""
    content = {role: [(e["path"], e["sha256"]) for e in entries] for role, entries in inputs.items()}
    doc = {"config": config.to_dict(), "method": method, "versions": vers, "inputs": content}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


class Binding(TypedDict):
    """A file a ground-truth sidecar is bound to (the sidecar header's ``BINDING_KEY`` rows)."""

    size: int
    sha256: str


def _section(value: object) -> Mapping[str, object]:
    """A JSON object of a file read back, or an empty one when it is missing or not an object."""
    return value if isinstance(value, dict) else {}


def cache_of(run: Mapping[str, object] | None) -> dict[str, Entry]:
    """The digests a previous run.json recorded, by resolved path (empty when there are none). Rows as read:
    ``digest`` trusts one only when its identity fields equal the file's and its sha256 is a string."""
    inputs = _section(_section(run).get("key")).get("inputs")
    if not isinstance(inputs, dict):
        return {}
    return {e["path"]: cast(Entry, e) for entries in inputs.values() if isinstance(entries, list)
            for e in entries if isinstance(e, dict) and isinstance(e.get("path"), str)}


def what_changed(run: Mapping[str, object], config: Config, method: str, inputs: dict[str, list[Entry]],
                 vers: dict[str, str | None]) -> str:
    """Why a previous run's key differs from this one, in a few words (for the refusal message)."""
    key = run.get("key")
    if not isinstance(key, dict):
        return "it was made by an older slz"
    # the config the key was made of: run.json's own "config" is the one that ran, with what the recording
    # decided (the camera preset's noise prior, the frame period for ORB-SLAM3) filled in
    old_cfg = key.get("config", run.get("config"))
    if isinstance(old_cfg, dict):
        diff = _first_difference(old_cfg, json.loads(json.dumps(config.to_dict())))  # tuples as JSON lists
        if diff:
            return f"config {diff}"
    old_method = _section(run.get("summary")).get("method")
    if old_method not in (None, method):
        return f"method {old_method} -> {method}"
    if key.get("versions") != vers:
        return f"versions {key.get('versions')} -> {vers}"
    old_inputs = key.get("inputs") or {}
    for role, entries in inputs.items():
        before = [(e.get("path"), e.get("sha256")) for e in old_inputs.get(role, []) if isinstance(e, dict)]
        now = [(e["path"], e["sha256"]) for e in entries]
        if before != now:
            changed = _changed_paths(before, now)
            return f"{role.replace('_', ' ')} {changed} changed" if changed else f"{role.replace('_', ' ')} changed"
    return "its key differs"


def _changed_paths(before: Sequence[tuple[object, object]], now: Sequence[tuple[object, object]]) -> str:
    old = dict(before)
    diff = [p for p, h in now if old.get(p) != h] + [p for p in old if p not in dict(now)]
    return "" if not diff else (Path(str(diff[0])).name + (f" (+{len(diff) - 1} more)" if len(diff) > 1 else ""))


def _first_difference(a: object, b: object, prefix: str = "") -> str:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            d = _first_difference(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else str(k))
            if d:
                return d
        return ""
    return "" if a == b else f"{prefix} {a!r} -> {b!r}"


# ----------------------------------------------------------------------------- ground-truth sidecars
def recording_binding(recording: Path, cache: dict[str, Entry] | None = None) -> list[Binding]:
    """What binds a sidecar to its recording: size and sha256 of every file the recording's reader reads
    (``fingerprint.recording_files``), sorted by digest (names are left out: renaming a recording and its
    sidecars together keeps them bound). ``cache``: digests already taken (``fingerprint.digest``)."""
    entries = [digest(q, cache or {}) for q in recording_files(Path(recording))]
    return sorted((Binding(size=int(e["size"]), sha256=str(e["sha256"])) for e in entries),
                  key=lambda e: (e["sha256"], e["size"]))


def binding_problem(header: Mapping[str, object], recording: Path, cache: dict[str, Entry] | None = None) -> str | None:
    """Why the sidecar with ``header`` is not the ground truth of ``recording`` (None: it is bound to it).

    A sidecar without a binding (written before slz bound them) cannot be checked: None, and the
    caller warns (``UNBOUND``)."""
    bound = header.get(BINDING_KEY)
    if bound is None:
        return None
    now = recording_binding(recording, cache)
    if bound == now:
        return None
    def short(entries: object) -> str:
        if not isinstance(entries, list):
            return "unreadable"
        try:
            return ", ".join(f"{e['sha256'][:12]} ({e['size']} B)" for e in entries) or "no file"
        except (TypeError, KeyError, IndexError):
            return "unreadable"
    return (f"ground truth of another recording: it was written for {header.get('recording', '?')!r} of scene "
            f"{header.get('scene', '?')!r} (files {short(bound)}), and this recording's files are {short(now)}; "
            "move the sidecar away, or write both again with slz synth")
