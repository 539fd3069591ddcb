"""Recordings -> Iterator[Frame]: the reader is chosen from the path (``sources/formats.py``).

``.bag`` -> ROS 1 bag; ``.mcap`` -> bare MCAP; a folder with ``metadata.yaml`` -> ROS 2
bag (sqlite3 or mcap storage); a folder with ``rgb.txt`` -> TUM RGB-D. Use as::

    with open_recording(path, config) as rec:
        print(rec.info())
        for frame in rec.frames(): ...
        print(rec.report)
"""

from __future__ import annotations

from pathlib import Path

from slzcli.config import Config
from slzcli.sources.formats import check_readable, open_format
from slzcli.sources.recording import Recording, RecordingInfo

__all__ = ["Recording", "RecordingInfo", "check_readable", "open_recording"]


def open_recording(path: str | Path, config: Config) -> Recording:
    """A Recording for ``path`` (not yet opened: use it in a ``with`` block)."""
    return open_format(Path(path), config)
