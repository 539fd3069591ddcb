"""The one rule every writing command follows: nothing of the user's is overwritten or removed.

- An output that is an input, or a folder holding one, is refused (``refuse_inputs``).
- An existing file is replaced only with ``--force``, and even then only when slz can tell it
  is its own kind of file: a recording by its magic bytes, a vocabulary by its header, a
  preview by the ``Software: slz`` text chunk slz puts in its PNGs, a ground-truth sidecar by
  its format key (``check_file``). Whole output folders carry a marker (``output_dir``).
- Temporary folders slz makes beside an output (``.OUT.<random>.partial``, ``.tmp``, ``.old``)
  hold a marker file (``TEMP_MARKER``) from the moment they exist; the clean-up of a killed
  writer's leftovers (``run_lock.claim``) removes only marked folders, so a user's folder that
  merely has such a name is never touched. Lock files hold ``run_lock.LOCK_MARK`` likewise.
- A failed command leaves nothing partial: everything is written under a temporary name and
  renamed into place at the end (``files.atomic_path``, ``output_dir.build``).
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from slzcli.errors import OutputError
from slzcli.sources.formats import starts_with_magic

TEMP_MARKER = ".slz-temporary"  # a file inside each temporary folder slz makes
_TEMP_TEXT = b"written by slz; removed when the command ends or by the next one on this output\n"

# ----------------------------------------------------------------------------- temporaries

def make_temp_dir(beside: Path, suffix: str) -> Path:
    """A new marked folder ``.NAME.<random><suffix>`` beside ``beside`` (created 0700 by mkdtemp)."""
    beside = Path(beside)
    tmp = Path(tempfile.mkdtemp(prefix=f".{beside.name}.", suffix=suffix, dir=beside.parent))
    try:
        fd = os.open(tmp / TEMP_MARKER, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            os.write(fd, _TEMP_TEXT)
        finally:
            os.close(fd)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


def unmark(tmp: Path) -> None:
    """Remove the marker of a temporary folder that is about to become (part of) an output."""
    Path(tmp, TEMP_MARKER).unlink(missing_ok=True)


def is_temp_dir(path: Path) -> bool:
    """True when ``path`` is a real folder (not a link) holding slz's temporary marker."""
    try:
        if not stat.S_ISDIR(os.lstat(path).st_mode):
            return False
        marker = Path(path, TEMP_MARKER)
        return stat.S_ISREG(os.lstat(marker).st_mode) and marker.read_bytes() == _TEMP_TEXT
    except OSError:
        return False


def entries(folder: Path) -> list[str]:
    """The names in a temporary folder, less its marker."""
    return sorted(n for n in os.listdir(folder) if n != TEMP_MARKER)


# ----------------------------------------------------------------------------- inputs
def refuse_inputs(out: Path, inputs: Sequence[Path], what: str = "-o", label: str = "recording") -> None:
    """OutputError when ``out`` is one of the inputs or holds one (writing there could replace or remove it)."""
    target = _resolved(Path(out))
    for inp in inputs:
        p = _resolved(Path(inp))
        if p == target or target in p.parents:
            why = f"is the input {label}" if p == target else f"holds the input {inp}"
            raise OutputError(out, f"{why}; write the results elsewhere (another {what})")


def _resolved(path: Path) -> Path:
    """``path`` with links resolved; a link loop stays as given (the reader names it, not this check)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return path.absolute()


# ----------------------------------------------------------------------------- what slz recognises as its own
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PNG_SOFTWARE = b"Software\x00slz"  # the tEXt chunk slz's PNG previews carry (see ``tag_png``)
_HEAD_BYTES = 4096


def _head(path: Path, n: int = _HEAD_BYTES) -> bytes:
    """The first bytes of a regular file (b"" for anything else: a FIFO is never opened)."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return b""
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError:
        return b""


def is_recording_file(path: Path) -> bool:
    head = _head(path, 16)
    return starts_with_magic(head)


def is_vocabulary(path: Path) -> bool:
    """A DBoW2 text vocabulary: a header line of four integers (k L scoring weighting), then node lines."""
    lines = _head(path, 512).split(b"\n", 2)
    if len(lines) < 2:
        return False
    header = lines[0].split()
    return len(header) == 4 and all(f.isdigit() for f in header) and lines[1][:2] in (b"0 ", b"1 ")


def is_slz_png(path: Path) -> bool:
    head = _head(path, 256)
    return head.startswith(PNG_MAGIC) and PNG_SOFTWARE in head


def is_json_of_format(path: Path, fmt: str) -> bool:
    """A JSON object whose ``format`` is ``fmt`` (e.g. the ``.gt.json`` header of ``slz synth``)."""
    head = _head(path, 1 << 20)
    try:
        doc = json.loads(head)
    except (ValueError, RecursionError):
        return False
    return isinstance(doc, dict) and doc.get("format") == fmt


def is_ground_truth_arrays(path: Path) -> bool:
    """A ``.gt.npz`` of ``slz synth``: a zip whose first member is one of the sidecar's arrays."""
    head = _head(path, 128)
    return head.startswith(b"PK\x03\x04") and b"stamps_ns.npy" in head


def tag_png(data: bytes) -> bytes:
    """PNG bytes with a ``Software: slz`` tEXt chunk after the IHDR, so a later ``--force`` knows the file."""
    import zlib

    if not data.startswith(PNG_MAGIC):
        return data
    ihdr_end = 8 + 4 + 4 + 13 + 4  # signature, length, type, IHDR data, CRC
    chunk = b"tEXt" + PNG_SOFTWARE
    tagged = len(PNG_SOFTWARE).to_bytes(4, "big") + chunk + zlib.crc32(chunk).to_bytes(4, "big")
    return data[:ihdr_end] + tagged + data[ihdr_end:]


def check_file(path: Path, *, force: bool, ours: Callable[[Path], bool], label: str, option: str = "-o") -> None:
    """OutputError unless ``path`` may be written: it does not exist, or ``force`` and it is slz's ``label``.

    Never a folder, a link, a FIFO or a file slz cannot recognise as its own, whatever ``force`` says.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return
    if path.is_symlink() or not path.is_file():
        kind = "a link" if path.is_symlink() else "a folder" if path.is_dir() else "not a regular file"
        raise OutputError(path, f"exists and is {kind}; slz writes {label} here only where nothing is: "
                                f"choose another {option}")
    if not force:
        raise OutputError(path, f"already exists (use --force to replace {label} slz wrote, or another {option})")
    if not ours(path):
        raise OutputError(path, f"exists and is not {label} of slz; --force replaces only that: move it away or "
                                f"choose another {option}")


def distinct(paths: dict[str, Path]) -> None:
    """OutputError when two outputs of one command are the same file (e.g. ``--contact-sheet`` = ``-o``)."""
    seen: dict[Path, str] = {}
    for what, p in paths.items():
        key = _resolved(Path(p))
        if key in seen:
            raise OutputError(p, f"{what} and {seen[key]} are the same file; give them different paths")
        seen[key] = what
