"""Recordings -> Iterator[Frame]: the reader is guessed from the path.

``.bag`` -> ROS 1 bag; ``.mcap`` -> bare MCAP; a folder with ``metadata.yaml`` -> ROS 2
bag (sqlite3 or mcap storage); a folder with ``rgb.txt`` -> TUM RGB-D. Use as::

    with open_recording(path, config) as rec:
        print(rec.info())
        for frame in rec.frames(): ...
        print(rec.report)
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from slzcli.config import Config
from slzcli.errors import DatasetError
from slzcli.sources.recording import Recording, RecordingInfo

__all__ = ["Recording", "RecordingInfo", "check_readable", "guess_format", "open_recording"]


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
                                 "(.bag, .mcap) or a folder (rosbag2, TUM)")
    try:
        if stat.S_ISDIR(st.st_mode):
            os.listdir(path)
        else:
            with open(path, "rb"):
                pass
    except OSError as err:
        raise DatasetError(path, f"cannot read ({err.strerror or err})") from err


def guess_format(path: Path) -> str:
    """'ros1', 'mcap', 'ros2' or 'tum'; DatasetError naming the path when it is none of them."""
    check_readable(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        if (path / "rgb.txt").is_file() or (path / "depth.txt").is_file():
            return "tum"
        raise DatasetError(path, "folder is neither a ROS 2 bag (no metadata.yaml) nor a TUM RGB-D folder (no rgb.txt)")
    if path.stat().st_size == 0:
        raise DatasetError(path, "empty file (0 bytes)")
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix == ".mcap":
        return "mcap"
    if suffix in (".db3", ".yaml") and (path.parent / "metadata.yaml").is_file():
        return "ros2"
    raise DatasetError(path, f"unknown recording type {suffix or '(no suffix)'!r}: expected .bag, .mcap, "
                             "a ROS 2 bag folder or a TUM RGB-D folder")


def open_recording(path: str | Path, config: Config) -> Recording:
    """A Recording for ``path`` (not yet opened: use it in a ``with`` block)."""
    p = Path(path)
    fmt = guess_format(p)
    if fmt == "ros2" and not p.is_dir():
        p = p.parent
    if fmt == "tum":
        from slzcli.sources.tum import TumRecording
        return TumRecording(p, config)
    from slzcli.sources.messages import MessageRecording
    if fmt == "mcap":
        from slzcli.sources.mcap import McapLog
        return MessageRecording(McapLog(p), config)
    from slzcli.sources.rosbag import RosbagLog
    return MessageRecording(RosbagLog(p), config)
