"""One writer per output, and the clean-up of what a killed writer left behind.

``output_dir.build`` makes ``RUN`` as ``.RUN.<random>.partial`` beside it and puts it in place at
the end; a process killed in between leaves that folder (and, while swapping an old run out,
``.RUN.<random>.old``). ``slz synth`` leaves its ``.OUT.<random>.tmp`` staging folder (recording,
truth spool and sidecar inside) and, while swapping a rosbag2 folder, ``.OUT.<random>.old``.
Nothing trusts those: ``run.json`` is only read from ``RUN`` itself. The next writer removes them,
but only while it holds ``.RUN.lock``: an ``flock`` that the kernel releases when its holder dies,
so holding it proves no living process is writing that output. Only folders that carry slz's
temporary marker (``safe_output.TEMP_MARKER``, written the moment the folder is made) are
removed: a user's ``.RUN.old/`` or ``.RUN.x.partial/`` is left alone. The lock file holds
``LOCK_MARK`` from the moment it exists (made under another name and linked into place); a
``.RUN.lock`` without it is a user's file, refused and never opened for writing or removed. The
lock file is removed on release. Without ``fcntl`` (Windows) there is no lock and no clean-up.

The ``filelock`` package was weighed for this: it keeps the lock file in place after release by
design (waiters share its inode), which would leave a ``.RUN.lock`` beside every output, and it
has no notion of a file that is not its own; the dozen lines below do both.
"""

from __future__ import annotations

import errno
import glob
import logging
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

from slzcli.errors import OutputError
from slzcli.outputs.safe_output import is_temp_dir

log = logging.getLogger(__name__)

LOCK_MARK = b"slz output lock\n"


def lock_path(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.lock"


RUN_LEFTOVERS = ("*.partial", "*.old")  # what output_dir.build leaves beside RUN: .RUN.*.partial, .RUN.*.old
SYNTH_LEFTOVERS = ("*.tmp", "*.old")  # synth: .OUT.*.tmp staging, .OUT.*.old


def stale_paths(run_dir: Path, leftovers: tuple[str, ...] = RUN_LEFTOVERS) -> list[Path]:
    """Temporaries of ``run_dir`` that exist now: marked folders ``.NAME.<pattern>`` beside it."""
    found: set[Path] = set()
    for pattern in leftovers:
        found.update(Path(p) for p in glob.glob(str(run_dir.parent / f".{glob.escape(run_dir.name)}.{pattern}")))
    return sorted(p for p in found if is_temp_dir(p))


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
            shutil.rmtree(p, ignore_errors=True)
        yield removed
    finally:
        try:
            if os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                path.unlink()  # before the unlock: a waiter that opened it re-checks the inode
        except OSError:
            pass
        os.close(fd)


def _create_marked(path: Path) -> None:
    """Make ``path`` holding LOCK_MARK, atomically (a file linked into place): FileExistsError if it is there."""
    fd, tmp = tempfile.mkstemp(prefix=f"{path.name}.", suffix=".new", dir=path.parent)
    try:
        os.write(fd, LOCK_MARK)
        os.close(fd)
        try:
            os.link(tmp, path)
        except OSError as err:
            if err.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
                raise
            new = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
            os.write(new, LOCK_MARK)  # no hard links here: created then marked
            os.close(new)
    finally:
        os.unlink(tmp)


def _open_marked(path: Path) -> int:
    """Open the lock file, refusing one that is not slz's (a user's file, a link, a FIFO)."""
    try:
        _create_marked(path)
    except FileExistsError:
        pass
    except OSError as err:
        raise OutputError(path.parent / path.name[1:-len(".lock")], f"cannot write ({err.strerror}) (its lock file "
                                                                   f"{path.name} cannot be made)") from err
    try:
        fd = os.open(path, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        return -1  # its holder removed it between our create and open: try again
    except OSError as err:
        raise OutputError(path, f"exists and is not a lock file of slz ({err.strerror}); slz does not remove it: "
                                "move it away") from err
    if not stat.S_ISREG(os.fstat(fd).st_mode) or os.pread(fd, len(LOCK_MARK) + 1, 0) != LOCK_MARK:
        os.close(fd)
        raise OutputError(path, "exists and is not a lock file of slz; slz does not remove it: move it away")
    return fd


def _acquire(path: Path, run_dir: Path, fcntl: ModuleType, wait: bool) -> int:
    while True:
        fd = _open_marked(path)
        if fd < 0:
            continue
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
            current = os.stat(path, follow_symlinks=False).st_ino
        except FileNotFoundError:
            current = None
        if current == os.fstat(fd).st_ino:  # else the last holder removed it between our open and flock
            return fd
        os.close(fd)
