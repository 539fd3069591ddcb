"""Every input format slz reads, by name: how a path is recognised as one, how it is opened, which files
it is made of (the rerun key, ``fingerprint.py``), what its name ends in (run folders, ``batch.py``) and
the magic bytes its files start with (what ``outputs/safe_output.py`` recognises as a recording).

Adding a format is one reader module and one line in ``FORMATS``. Recognition is by path alone, in two
passes so that no order among the lines decides between a file and a folder: a folder is the first
format with one of its ``Folder.markers`` in it; a file is the format whose ``suffixes`` hold its
suffix (lower case), else the format of the folder around it when its suffix is one of the folder's
``Folder.members`` (a rosbag2 ``.db3`` stands for its bag folder). The reader checks the content
(magic bytes, metadata) when it opens the recording, and says what is wrong with it.

``open`` and ``files`` are ``"module:function"`` (imported at first use, so recognising a path imports
no reader and this module imports nothing of slzcli but errors) or the function itself.
"""

from __future__ import annotations

import errno
import importlib
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

from slzcli.errors import DatasetError

if TYPE_CHECKING:
    from slzcli.config import Config
    from slzcli.sources.recording import Recording

MCAP_MAGIC = b"\x89MCAP0\r\n"  # the MCAP spec's magic: a bare .mcap file and a rosbag2 mcap storage file
ROS1_MAGIC = b"#ROSBAG V2.0\n"  # a ROS 1 bag, format version 2.0 (the one rosbag writes since ROS C Turtle)


@dataclass(frozen=True)
class Folder:
    """A format that is a folder, recognised by a file in it; the three names are those of its messages."""

    markers: tuple[str, ...]  # a folder holding one of these files is of the format
    kind: str  # in "a recording is a file (.bag, .mcap) or a folder (rosbag2, TUM)"
    noun: str  # in "expected .bag, .mcap, a ROS 2 bag folder or ..."
    without: str  # in "folder is neither a ROS 2 bag (no metadata.yaml) nor ..."
    members: tuple[str, ...] = ()  # a file with one of these suffixes in such a folder names the folder


@dataclass(frozen=True)
class Format:
    """One input format. ``open``: (root path, config) -> a ``Recording`` (not yet opened); ``files``: (root
    path) -> the files its reader reads, None for the path itself; ``suffixes``: the suffixes (lower case)
    of a file of the format; ``run_suffixes``: removed from a recording's name to name its run folder;
    ``magic``: the bytes every file of the format starts with (b"": no magic)."""

    open: str | Callable[[Path, Config], Recording]
    files: str | Callable[[Path], list[Path]] | None = None
    suffixes: tuple[str, ...] = ()
    folder: Folder | None = None
    run_suffixes: tuple[str, ...] = ()
    magic: bytes = b""


FORMATS: dict[str, Format] = {
    "mcap": Format("slzcli.sources.mcap:open_mcap", suffixes=(".mcap",), run_suffixes=(".mcap",), magic=MCAP_MAGIC),
    "ros1": Format("slzcli.sources.rosbag:open_ros1", suffixes=(".bag",), run_suffixes=(".bag",), magic=ROS1_MAGIC),
    "ros2": Format("slzcli.sources.rosbag:open_ros2", "slzcli.sources.rosbag:bag_folder_files",
                   folder=Folder(("metadata.yaml",), "rosbag2", "a ROS 2 bag folder", "a ROS 2 bag",
                                 members=(".db3", ".yaml")),
                   run_suffixes=(".db3",)),
    "tum": Format("slzcli.sources.tum:TumRecording", "slzcli.sources.tum:tum_files",
                  folder=Folder(("rgb.txt", "depth.txt"), "TUM", "a TUM RGB-D folder", "a TUM RGB-D folder")),
}


def _resolve(target: str | Callable[..., object]) -> Callable[..., object]:
    if isinstance(target, str):
        module, attr = target.split(":")
        return cast("Callable[..., object]", getattr(importlib.import_module(module), attr))
    return target


def _folders() -> list[Folder]:
    return [f.folder for f in FORMATS.values() if f.folder is not None]


def _file_suffixes() -> list[str]:
    return sorted(s for f in FORMATS.values() for s in f.suffixes)


def check_readable(path: Path) -> None:
    """DatasetError naming ``path`` when it is missing, a broken or looping link, or unreadable."""
    try:
        st = os.stat(path)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise DatasetError(path, "symbolic link loop (the link leads back to itself)") from err
        if path.is_symlink():
            raise DatasetError(path, f"broken symbolic link (to {os.readlink(path)!r}: no such file)") from err
        if err.errno in (errno.ENOENT, errno.ENOTDIR):
            raise DatasetError(path, "no such file or folder") from err
        raise DatasetError(path, f"cannot read ({err.strerror or err})") from err
    if not (stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)):  # opening a FIFO waits for a writer
        from slzcli.bounds import file_kind

        raise DatasetError(path, f"not a regular file or folder ({file_kind(st.st_mode)}); a recording is a file "
                                 f"({', '.join(_file_suffixes())}) or a folder "
                                 f"({', '.join(f.kind for f in _folders())})")
    try:
        if stat.S_ISDIR(st.st_mode):
            os.listdir(path)
        else:
            with open(path, "rb"):
                pass
    except OSError as err:
        raise DatasetError(path, f"cannot read ({err.strerror or err})") from err


def recognise(path: Path) -> tuple[str, Path]:
    """(format name, the recording's root: the folder for a file inside a bag folder); DatasetError naming
    the path when it is none of ``FORMATS``."""
    check_readable(path)
    if path.is_dir():
        for name, fmt in FORMATS.items():
            if fmt.folder is not None and any((path / m).is_file() for m in fmt.folder.markers):
                return name, path
        raise DatasetError(path, "folder is neither " + " nor ".join(
            f"{f.without} (no {f.markers[0]})" for f in _folders()))
    if path.stat().st_size == 0:
        raise DatasetError(path, "empty file (0 bytes)")
    suffix = path.suffix.lower()
    for name, fmt in FORMATS.items():
        if suffix in fmt.suffixes:
            return name, path
    for name, fmt in FORMATS.items():
        folder = fmt.folder
        if folder is not None and suffix in folder.members and any((path.parent / m).is_file() for m in folder.markers):
            return name, path.parent
    expected = [*_file_suffixes(), *(f.noun for f in _folders())]
    raise DatasetError(path, f"unknown recording type {suffix or '(no suffix)'!r}: expected "
                             f"{', '.join(expected[:-1])} or {expected[-1]}")


def open_format(path: Path, config: Config) -> Recording:
    """The reader of ``path``'s format on its root (not yet opened)."""
    name, root = recognise(path)
    return cast("Recording", _resolve(FORMATS[name].open)(root, config))


def files_of(path: Path) -> list[Path]:
    """The files the reader of ``path`` reads; a path that is no recording: itself if it is a file, else
    none (the reader says what is wrong when it opens it)."""
    try:
        name, root = recognise(path)
    except DatasetError:
        return [path] if path.is_file() else []
    target = FORMATS[name].files
    return [root] if target is None else cast("list[Path]", _resolve(target)(root))


def run_suffixes() -> tuple[str, ...]:
    """Every format's ``run_suffixes``, in registry order (removed in turn from a recording's name)."""
    return tuple(s for f in FORMATS.values() for s in f.run_suffixes)


def starts_with_magic(head: bytes) -> bool:
    """``head`` (a file's first bytes) starts with one format's magic."""
    return any(f.magic and head.startswith(f.magic) for f in FORMATS.values())
