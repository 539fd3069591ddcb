"""Atomic file writes (whole output folders: ``output_dir.py``): a reader never sees a half-written result.

Every file goes to a temporary name in the same folder and is renamed into place
(``os.replace`` is atomic on one filesystem), so a crash or Ctrl-C leaves either the old
file, the new file, or a ``.tmp`` file that nothing trusts.
"""

from __future__ import annotations

import errno
import io
import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import numpy.typing as npt

from slzcli.errors import OutputError

UMASK = os.umask(0)
os.umask(UMASK)  # read once: mkstemp makes 0600 files, outputs get the user's usual mode


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


# errno values that only a write gives: an OSError carrying one is named as the output's, wherever it surfaced.
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


@contextmanager
def naming_write_errors(path: Path) -> Iterator[None]:
    """An OSError (disk full, no permission, read-only) while writing ``path`` -> OutputError naming it."""
    try:
        yield
    except OSError as err:
        raise OutputError(path, f"cannot write ({err.strerror or err})") from err


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it into place, else remove it."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(path.parent, f"cannot create folder ({err.strerror})") from err
    # The real suffix is kept last so that writers that pick a format by extension still work.
    with naming_write_errors(path):
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.tmp-", suffix=path.suffix, dir=path.parent)
        os.close(fd)
    tmp = Path(tmp_name)
    try:
        with naming_write_errors(path):
            yield tmp
            os.chmod(tmp, 0o666 & ~UMASK)
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: Path, text: str) -> None:
    write_bytes(path, text.encode())


def finite_json(obj: object) -> object:
    """``obj`` with every NaN or infinite float replaced by None: in slz's JSON, null means "no value"
    (not computed, or not a number). Bare ``NaN`` / ``Infinity`` are not JSON and break other readers."""
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def json_text(obj: object, indent: int | None = 2, sort_keys: bool = False) -> str:
    """Strict JSON (``allow_nan=False``) of ``obj`` after ``finite_json``: every JSON slz writes goes through here."""
    return json.dumps(finite_json(obj), indent=indent, default=_json_default, allow_nan=False, sort_keys=sort_keys)


def write_json(path: Path, obj: object) -> None:
    write_text(path, json_text(obj) + "\n")


def write_npz(path: Path, **arrays: np.ndarray) -> None:
    """A deflated ``.npz`` like ``np.savez_compressed``, but safe to interrupt (see ``_zip_for_writing``)."""
    write_npz_streamed(path, dict(arrays))


ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)  # fixed member time: the same arrays give the same bytes
_COPY_BUFFER_BYTES = 1 << 20


def write_npz_streamed(path: Path, members: Mapping[str, np.ndarray | Path],
                       stored: frozenset[str] = frozenset()) -> None:
    """An ``.npz`` (readable by ``np.load``) from arrays and from ``.npy`` files copied in chunks.

    Members named in ``stored`` are not compressed (a reader can memory-map them); the rest are
    deflated. Memory holds one chunk of a file member, never the whole array.
    """
    with atomic_path(path) as tmp, _zip_for_writing(tmp) as zf:
        for name, member in members.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_STORED if name in stored else zipfile.ZIP_DEFLATED
            if isinstance(member, Path):
                size = member.stat().st_size
                info.file_size = size
                with open(member, "rb") as src, zf.open(info, "w", force_zip64=size > zipfile.ZIP64_LIMIT) as dst:
                    shutil.copyfileobj(src, dst, _COPY_BUFFER_BYTES)
            else:
                _write_npy_member(zf, info, np.asarray(member))


def _write_npy_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, array: np.ndarray) -> None:
    """One array as a ``.npy`` member, the bytes ``np.save`` gives, written from the array's own memory: no
    copy into a BytesIO and out of it again (~5.5 MB a detection frame; ``np.lib.format.write_array`` on a
    non-file handle copies it through a buffer too)."""
    if array.dtype.hasobject:
        raise ValueError("object arrays cannot go into an .npz without pickling")
    array = np.asarray(array, order="C")  # keeps a 0-d array 0-d (ascontiguousarray would not)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(array))
    info.file_size = header.tell() + array.nbytes
    with zf.open(info, "w", force_zip64=info.file_size > zipfile.ZIP64_LIMIT) as dst:
        dst.write(header.getvalue())
        dst.write(array.reshape(-1).view(np.uint8).data)


@contextmanager
def _zip_for_writing(path: Path) -> Iterator[zipfile.ZipFile]:
    """A ZipFile for writing that an interrupt can abandon cleanly.

    Ctrl-C or SIGTERM (KeyboardInterrupt) or ``--timeout`` landing while a member is being closed left
    the ZipFile with an open writing handle: its close() then raised ValueError, which replaced the
    interrupt, and ZipFile.__del__ later printed "Exception ignored ... Traceback". On any exception the
    archive is dropped here instead (the caller removes the temporary file), so nothing is left to finish.
    """
    with open(path, "wb") as fh:
        zf = zipfile.ZipFile(fh, "w")
        try:
            yield zf
        except BaseException:
            zf.fp = None  # abandoned: close() and __del__ have nothing to write
            raise
        zf.close()


class ArraySpool:
    """Arrays that grow by rows on disk, not in memory, until they go into an ``.npz``.

    ``spec``: member name -> (dtype, shape of one row). ``append`` adds rows to every member it
    names; ``npy`` turns a member into a complete ``.npy`` file (header + rows) for
    ``write_npz_streamed`` or ``np.load(mmap_mode="r")``. The folder is the caller's to remove.
    """

    def __init__(self, folder: Path, spec: Mapping[str, tuple[npt.DTypeLike, tuple[int, ...]]]) -> None:
        self.folder = Path(folder)
        self.spec = {k: (np.dtype(d), tuple(shape)) for k, (d, shape) in spec.items()}
        self.rows = dict.fromkeys(spec, 0)
        self._npy_rows: dict[str, int] = {}  # row count each finished .npy was written with
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(self.folder, f"cannot create spool folder ({err.strerror})") from err

    def append(self, **rows: npt.ArrayLike) -> None:
        for name, values in rows.items():
            dtype, shape = self.spec[name]
            block = np.ascontiguousarray(values, dtype=dtype).reshape((-1, *shape))
            with naming_write_errors(self.folder / f"{name}.bin"), open(self.folder / f"{name}.bin", "ab") as fh:
                fh.write(block.tobytes())
            self.rows[name] += len(block)

    def npy(self, name: str) -> Path:
        """The member as a ``.npy`` file, written once per row count: rewriting it in place would
        truncate a file an earlier caller may still have memory-mapped."""
        dtype, shape = self.spec[name]
        raw, out = self.folder / f"{name}.bin", self.folder / f"{name}.npy"
        if self._npy_rows.get(name) == self.rows[name]:
            return out
        self._npy_rows[name] = self.rows[name]
        with naming_write_errors(out), open(out, "wb") as dst:
            np.lib.format.write_array_header_1_0(dst, {"descr": np.lib.format.dtype_to_descr(dtype),
                                                       "fortran_order": False, "shape": (self.rows[name], *shape)})
            if raw.exists():
                with open(raw, "rb") as src:
                    shutil.copyfileobj(src, dst, _COPY_BUFFER_BYTES)
        return out
