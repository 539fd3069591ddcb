"""What every benchmark shares: its arguments, the machine it ran on, where its results go, and a run of
the code as it was at another commit (a reference to compare the current code against).

A benchmark is a script: ``sys.path`` holds its own folder, so ``import harness`` finds this module, and
importing it puts the checkout's own package first on the path (a benchmark measures the code beside it,
not an installed copy). Every script in benchmarks/ imports it; tests/benchmarks/test_benchmark_scripts.py holds that.
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
TESTS = REPO / "tests"
# the real RealSense frames: beside the checkout, or wherever SLZ_REALSENSE_DIR says (as for the tests)
REALSENSE = Path(os.environ.get("SLZ_REALSENSE_DIR") or REPO.parent / "shared" / "data" / "realsense_floor")
if str(REPO) not in sys.path:
    sys.path.insert(1, str(REPO))  # after the script's own folder, before site-packages


def use_test_helpers() -> None:
    """Make the shared test helpers in tests/ (slam_flight, bad_inputs, skfuzzy_oracle, ...) importable: the
    flights and scenes the tests check are the ones a benchmark should measure."""
    if str(TESTS) not in sys.path:
        sys.path.insert(1, str(TESTS))


def results_path(name: str, suffix: str = ".json") -> Path:
    """benchmarks/results/NAME.json: the default ``--out`` of benchmark NAME."""
    return RESULTS_DIR / f"{name}{suffix}"


def parser(doc: str | None, name: str, out: bool = True) -> argparse.ArgumentParser:
    """An argument parser described by the script's docstring (its first line; ``--help`` shows the rest),
    with ``--out`` defaulting to ``results_path(name)`` unless ``out`` is false (a results name that
    depends on another option)."""
    first, _, rest = (doc or name).strip().partition("\n")
    ap = argparse.ArgumentParser(description=first, epilog=rest.strip() or None,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    if out:
        ap.add_argument("--out", type=Path, default=results_path(name), help="results JSON (default %(default)s)")
    return ap


def machine() -> dict[str, Any]:
    """What a timing or a result depends on beside the code: interpreter, libraries, processor, cores, and
    the load average when the results are written (the cores may be shared with other jobs)."""
    info: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                            "cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                            "load_avg": [round(v, 2) for v in os.getloadavg()]}
    for lib, module in (("numpy", "numpy"), ("opencv", "cv2")):
        try:
            info[lib] = __import__(module).__version__
        except ImportError:
            info[lib] = "not installed"
    return info


def write_results(path: Path, results: dict[str, Any], indent: int = 2, say: bool = True) -> None:
    """The results with the machine beside them, as indented strict JSON (NaN and infinities as null, as in
    every JSON slz writes), written whole or not at all (a run stopped part way leaves the previous file).
    A benchmark that saves after every cell passes ``say=False`` and says where it wrote at the end."""
    from slzcli.outputs.files import finite_json

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(finite_json({**results, "machine": machine()}), indent=indent, default=str,
                              allow_nan=False) + "\n")
    tmp.replace(path)
    if say:
        print(f"wrote {path}")


def size_overrides(size: str) -> list[str]:
    """``--set camera.*`` for a ``WxH`` render with the paper's field of view (fx = 462.137 px at 640 wide,
    scaled with the width; the principal point in the middle): long renders at other sizes."""
    width, height = (int(v) for v in size.lower().split("x"))
    f = 462.137 * width / 640.0
    out: list[str] = []
    for key, value in (("width", width), ("height", height), ("fx", f), ("fy", f), ("cx", width / 2),
                       ("cy", height / 2)):
        out += ["--set", f"camera.{key}={value}"]
    return out


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()


def source_at(rev: str, path: str) -> str:
    """The text of the repository's file ``path`` (relative to the root) at git revision ``rev``: the old
    code a benchmark loads beside the current one."""
    return subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, capture_output=True, text=True,
                          check=True).stdout


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
