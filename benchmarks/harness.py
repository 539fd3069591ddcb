"""What every benchmark shares: its arguments, the machine it ran on, where its results go, and a run of
the code as it was at another commit (a reference to compare the current code against).

A benchmark is a script: ``sys.path`` holds its own folder, so ``import harness`` finds this module.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
RESULTS_DIR = REPO / "benchmarks" / "results"


def results_path(name: str, suffix: str = ".json") -> Path:
    """benchmarks/results/NAME.json: the default ``--out`` of benchmark NAME."""
    return RESULTS_DIR / f"{name}{suffix}"


def parser(doc: str | None, name: str) -> argparse.ArgumentParser:
    """An argument parser described by the script's docstring, with ``--out`` defaulting to ``results_path(name)``."""
    ap = argparse.ArgumentParser(description=(doc or name).strip().splitlines()[0])
    ap.add_argument("--out", type=Path, default=results_path(name), help="results JSON (default %(default)s)")
    return ap


def machine() -> dict[str, Any]:
    """What a timing or a result depends on beside the code: interpreter, libraries, processor, cores."""
    info: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                            "cpu": platform.processor() or platform.machine(), "cores": os.cpu_count()}
    for lib, module in (("numpy", "numpy"), ("opencv", "cv2")):
        try:
            info[lib] = __import__(module).__version__
        except ImportError:
            info[lib] = "not installed"
    return info


def write_results(path: Path, results: dict[str, Any]) -> None:
    """The results with the machine beside them, as indented JSON."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**results, "machine": machine()}, indent=2) + "\n")
    print(f"wrote {path}")


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()


@contextmanager
def reference_checkout(rev: str) -> Iterator[Path]:
    """The repository as it was at ``rev``, checked out in a temporary folder (``git worktree add``) and
    removed afterwards; run its code with ``slz(..., code=PATH)``."""
    commit = git("rev-parse", "--verify", f"{rev}^{{commit}}")
    with tempfile.TemporaryDirectory(prefix="slz-ref-") as tmp:
        where = Path(tmp) / "repo"
        git("worktree", "add", "--detach", str(where), commit)
        try:
            yield where
        finally:
            git("worktree", "remove", "--force", str(where))


def slz(*args: str, code: Path = REPO, check: bool = True) -> subprocess.CompletedProcess[str]:
    """``slz ARGS`` in a fresh interpreter with the package at ``code`` first on the path (the current code
    by default, a ``reference_checkout`` for the old one)."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    res = subprocess.run([sys.executable, "-m", "slzcli.cli", *args], cwd=code, env=env, capture_output=True,
                         text=True, check=False)
    if check and res.returncode != 0:
        raise SystemExit(f"slz {' '.join(args)} failed ({code}):\n{res.stderr}")
    return res
