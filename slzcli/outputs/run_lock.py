"""One writer per output, and the clean-up of what a killed writer left behind.

``output_dir.build`` makes ``RUN`` as ``.RUN.<random>.partial`` beside it and puts it in place at
the end; a process killed in between leaves that folder (and, while swapping an old run out,
``.RUN.old``). ``slz synth`` leaves its ``.OUT.*.tmp`` staging folder (recording, truth spool
and sidecar inside) and, while swapping a rosbag2 folder, ``.OUT.PID.old``. Nothing trusts
those: ``run.json`` is only read from ``RUN`` itself. The next writer removes them, but only
while it holds ``.RUN.lock``: an ``flock`` that the kernel releases when its holder dies, so
holding it proves no living process is writing that output. Only those names are removed, and
only when they are what slz makes there (a folder, or a file with the suffix slz gives its
temporary files). The lock file is removed on release. Without ``fcntl`` (Windows) there is no
lock and no clean-up.
"""

from __future__ import annotations

import glob
import logging
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from slzcli.errors import OutputError

log = logging.getLogger(__name__)


def lock_path(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.lock"


RUN_LEFTOVERS = ("*.partial", "old")  # what output_dir.build leaves beside RUN: .RUN.*.partial, .RUN.old
SYNTH_LEFTOVERS = ("*.tmp", "*.old", "preview.png.tmp-*")  # synth: .OUT.*.tmp staging, .OUT.PID.old, the preview's
_FILE_LEFTOVERS = (".png",)  # the one temporary that is a file (the preview's, files.atomic_path)


def stale_paths(run_dir: Path, leftovers: tuple[str, ...] = RUN_LEFTOVERS) -> list[Path]:
    """Temporaries of ``run_dir`` that exist now: ``.NAME.<pattern>`` beside it, for each pattern."""
    found: set[Path] = set()
    for pattern in leftovers:
        found.update(Path(p) for p in glob.glob(str(run_dir.parent / f".{glob.escape(run_dir.name)}.{pattern}")))
    return sorted(p for p in found if p.is_dir() or (p.is_file() and p.name.endswith(_FILE_LEFTOVERS)))


@contextmanager
def claim(run_dir: Path, *, wait: bool = False, leftovers: tuple[str, ...] = RUN_LEFTOVERS) -> Iterator[list[Path]]:
    """Hold ``run_dir``'s lock and remove its stale temporaries (``leftovers``); yields the ones removed.

    Another process holding the lock is writing that output now: with ``wait`` this one waits
    until it is done (the caller then finds its result), else it raises OutputError.
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
    fd = _acquire(path, run_dir, fcntl, wait)
    try:
        removed = stale_paths(run_dir, leftovers)
        for p in removed:
            log.info("removing %s, left by an interrupted run", p)
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
        yield removed
    finally:
        path.unlink(missing_ok=True)  # before the unlock: a waiter that opened it re-checks the inode
        os.close(fd)


def _acquire(path: Path, run_dir: Path, fcntl: Any, wait: bool) -> int:
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as err:
            raise OutputError(path, f"cannot create lock file ({err.strerror})") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not wait:
                os.close(fd)
                raise OutputError(run_dir, f"another slz process is writing this output (lock {path.name})") from None
            log.warning("%s: another slz process is writing it; waiting for it to finish", run_dir)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)  # Ctrl-C, SIGTERM and --timeout still interrupt the wait
            except BaseException:
                os.close(fd)
                raise
        try:
            current = os.stat(path).st_ino
        except FileNotFoundError:
            current = None
        if current == os.fstat(fd).st_ino:  # else the last holder removed it between our open and flock
            return fd
        os.close(fd)
