"""One writer per run folder, and the clean-up of what a killed writer left behind.

``files.atomic_dir`` builds ``RUN`` as ``.RUN.<random>.partial`` beside it and renames it into
place at the end; a process killed in between leaves that folder (and, while swapping an old run
out, ``.RUN.old``). Nothing trusts those: ``run.json`` is only read from ``RUN`` itself. The
next writer removes them, but only while it holds ``.RUN.lock``: an ``flock`` that the kernel
releases when its holder dies, so holding it proves no living process is building that folder.
The lock file is removed on release. Without ``fcntl`` (Windows) there is no lock and no clean-up.
"""

from __future__ import annotations

import glob
import logging
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from slzcli.errors import OutputError

log = logging.getLogger(__name__)


def lock_path(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.lock"


def stale_paths(run_dir: Path) -> list[Path]:
    """Temporary folders of ``run_dir`` (``.RUN.*.partial``, ``.RUN.old``) that exist now."""
    pattern = str(run_dir.parent / f".{glob.escape(run_dir.name)}.*.partial")
    return sorted(Path(p) for p in glob.glob(pattern)) + [p for p in [run_dir.parent / f".{run_dir.name}.old"]
                                                          if p.exists()]


@contextmanager
def claim(run_dir: Path) -> Iterator[list[Path]]:
    """Hold ``run_dir``'s lock and remove its stale temporary folders; yields the ones removed.

    Raises OutputError when another process holds the lock (it is building that run now).
    """
    run_dir = Path(run_dir)
    try:
        run_dir.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(run_dir.parent, f"cannot create output folder ({err.strerror})") from err
    try:
        import fcntl
    except ImportError:  # no flock: no proof that a partial folder is stale, so leave them
        yield []
        return
    path = lock_path(run_dir)
    fd = _acquire(path, run_dir, fcntl)
    try:
        removed = stale_paths(run_dir)
        for p in removed:
            log.info("removing %s, left by an interrupted run", p)
            shutil.rmtree(p, ignore_errors=True)
        yield removed
    finally:
        path.unlink(missing_ok=True)  # before the unlock: a waiter that opened it re-checks the inode
        os.close(fd)


def _acquire(path: Path, run_dir: Path, fcntl: Any) -> int:
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as err:
            raise OutputError(path, f"cannot create lock file ({err.strerror})") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputError(run_dir, f"another slz process is writing this run folder (lock {path.name})") from None
        try:
            current = os.stat(path).st_ino
        except FileNotFoundError:
            current = None
        if current == os.fstat(fd).st_ino:  # else the last holder removed it between our open and flock
            return fd
        os.close(fd)
