"""The wheel works on its own: built from the tracked files, installed into a clean venv, run from
a folder outside the checkout (issue 14: `pip install .` used to look for configs/ beside the source).

No network: the wheel is built without build isolation, and the new venv borrows the third-party
packages of the test's own environment through a ``.pth`` line. That path is appended after the
venv's own site-packages, and ``.pth`` files inside it are not run, so the checkout's editable
install stays invisible and ``slzcli`` is imported from the wheel (asserted below).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from conftest import REPO


def _tracked_files(repo: Path) -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=repo, check=True,
                             capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: cannot tell the tracked files")
    return [line for line in out.splitlines() if line]


def _copy_source(dest: Path) -> None:
    """The tracked files only (links kept as links), so build/ and *.egg-info never land in the checkout."""
    for rel in _tracked_files(REPO):
        src, dst = REPO / rel, dest / rel
        if not src.exists() and not src.is_symlink():
            continue  # deleted in the working tree
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
        else:
            shutil.copy2(src, dst)


def _run(cmd: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str], Path]:
    root = tmp_path_factory.mktemp("wheel")
    src, dist, venv, work = root / "src", root / "dist", root / "venv", root / "work"
    _copy_source(src)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist),
          str(src)], cwd=root, env=env)
    wheels = list(dist.glob("slz-*.whl"))
    assert len(wheels) == 1, wheels
    # A venv without pip (ensurepip costs ~6 s of CPU), filled by this environment's pip through --python.
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=root, env=env)
    vpy = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(vpy), "install", "-q", "--no-deps", "--no-index",
          str(wheels[0])], cwd=root, env=env)
    site = Path(_run([str(vpy), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=root, env=env).stdout.strip())
    (site / "_slz_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work.mkdir()
    return venv, env, work


def test_the_wheel_carries_configs_rules_and_scenes(installed: tuple[Path, dict[str, str], Path]) -> None:
    venv, env, work = installed
    where = _run([str(venv / "bin" / "python"), "-c",
                  "import slzcli, slzcli.config as c; print(slzcli.__file__); print(c.DEFAULT_CONFIG)"],
                 cwd=work, env=env).stdout.split()
    assert all(Path(p).is_relative_to(venv) for p in where), where  # imported from the wheel, not the checkout
    dump = _run([str(venv / "bin" / "slz"), "config", "dump"], cwd=work, env=env).stdout
    assert "fuzzy_rules.yaml" in dump and "# px; paper T1" in dump  # the comments of default.yaml came along
    paper = _run([str(venv / "bin" / "slz"), "config", "dump", "--profile", "paper"], cwd=work, env=env).stdout
    assert "sensor: monocular" in paper and "# profile paper: paper sec. 2.2" in paper  # configs/profiles/ came along
    scenes = _run([str(venv / "bin" / "slz"), "synth", "--list"], cwd=work, env=env).stdout
    assert all(name in scenes for name in ("clear_field", "parking_lot", "no_site"))
    schema = _run([str(venv / "bin" / "python"), "-c", "from slzcli.outputs.summary_json import schema_path as p; "
                   "import json; print(json.loads(p().read_text())['$defs']['schema_version']['const'])"],
                  cwd=work, env=env).stdout.strip()
    assert schema == "1.3"  # the --json schema is in the wheel
    presets = _run([str(venv / "bin" / "python"), "-c", "from slzcli.sources.presets import preset_names as p; "
                    "print(' '.join(p()))"], cwd=work, env=env).stdout.split()
    assert {"d435_aligned", "d435_raw", "zed", "oakd", "realsense_viewer", "tum_fr1"} <= set(presets)  # camera presets


def test_the_installed_slz_renders_and_detects_outside_the_checkout(
        installed: tuple[Path, dict[str, str], Path]) -> None:
    venv, env, work = installed
    slz = str(venv / "bin" / "slz")
    _run([slz, "synth", "clear_field", "-o", "f.mcap", "--frames", "2"], cwd=work, env=env)  # default sensor
    _run([slz, "detect", "f.mcap", "-o", "run", "--json"], cwd=work, env=env)
    landing = json.loads((work / "run" / "landing.json").read_text())
    assert landing["status"] in ("site", "no_safe_site")
    run = json.loads((work / "run" / "run.json").read_text())
    assert Path(run["config"]["scoring"]["fuzzy"]["rules"]).name == "fuzzy_rules.yaml"
