"""Bounds before reading, and no "internal error": each case one line naming the file or key, through the CLI.

Sparse files cost no disk here but their full size to read whole; a JSON nested 200,000 deep was a
RecursionError; values such as 1e300 overflowed in arithmetic; a ``**`` pattern through a link
loop never returned. See slzcli/bounds.py (the file bounds) and docs/FAILURE_MODES.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import bad_inputs as B
import pytest
from click.testing import CliRunner
from landing_file import write_landing
from test_user_files import FAST, invoke, refused, snapshot

from slzcli import bounds

DEEP = "[" * 200_000 + "]" * 200_000


def sparse(path: Path, size: int = 3 << 30) -> Path:
    with open(path, "ab") as fh:
        fh.truncate(size)
    return path


# ----------------------------------------------------------------------------- JSON inputs
@pytest.mark.parametrize("content", ["deep", "sparse"])
def test_landing_json_deep_or_huge_is_one_line(runner: CliRunner, tmp_path: Path, content: str) -> None:
    run = tmp_path / "RUN"
    landing = write_landing(run)
    if content == "deep":
        landing.write_text(DEEP)
    else:
        sparse(landing)
    cause = "nested more than 64 levels deep" if content == "deep" else "is 3072 MiB, larger than 64 MiB"
    refused(invoke(runner, "land", "simulate", str(run)), "landing.json", cause)
    assert sorted(p.name for p in run.iterdir()) == ["landing.json"]


@pytest.mark.parametrize("marker", ["run.json", "compare.json", "summary.json"])
def test_a_deep_marker_is_not_slzs_and_its_folder_is_kept(runner, tmp_path, marker) -> None:
    """A run.json / compare.json / batch summary.json nested 200,000 deep is a user's file: refused, kept."""
    rec = B.good(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / marker).write_text(DEEP)
    before = snapshot(out)
    if marker == "summary.json":
        args = ["detect", str(rec), str(B.depth_constant(tmp_path)), "-o", str(out), *FAST]
    else:
        args = ["detect" if marker == "run.json" else "compare", str(rec), "-o", str(out), *FAST]
    res = invoke(runner, *args)
    refused(res, "out", "not")
    assert snapshot(out) == before


def test_a_deep_ground_truth_header_is_one_line(runner, tmp_path) -> None:
    rec = B.good(tmp_path)
    (tmp_path / "good.mcap.gt.json").write_text(DEEP)
    (tmp_path / "good.mcap.gt.npz").write_bytes(b"PK\x03\x04")
    refused(invoke(runner, "detect", str(rec), "-o", str(tmp_path / "run"), *FAST), "good.mcap.gt.json",
            "nested more than 64 levels deep")
    assert not (tmp_path / "run").exists()


def test_json_depth_is_measured_without_recursion() -> None:
    doc: list = []
    for _ in range(100_000):
        doc = [doc]
    assert bounds.json_depth(doc) == bounds.MAX_JSON_DEPTH + 1  # stops counting past the bound
    assert bounds.json_depth({"a": [1, {"b": 2}]}) == 4


# ----------------------------------------------------------------------------- recordings
def test_an_mcap_chunk_declaring_2_62_bytes_is_damage_not_a_memory_error(runner, tmp_path) -> None:
    path = B.mcap_huge_chunk(tmp_path)
    res = invoke(runner, "info", str(path), "--json")
    assert res.exit_code == 0
    assert any("declares 4611686018427387904 bytes uncompressed" in w for w in json.loads(res.stdout)["warnings"])
    refused(invoke(runner, "detect", str(path), "-o", str(tmp_path / "run")), path.name, "no RGB-D frame")


def test_a_glob_through_link_loops_returns(tmp_path) -> None:
    """Two links back up per level multiplied glob's walk past any wait; ** no longer follows links."""
    root = tmp_path / "flights"
    (root / "a" / "b").mkdir(parents=True)
    B.good(root / "a" / "b")
    for d in (root / "a", root / "a" / "b"):
        os.symlink("..", d / "up")
        os.symlink(".", d / "here")
    proc = subprocess.run([sys.executable, "-c", "from slzcli.batch import expand; import sys; "
                           "print([str(p) for p in expand([sys.argv[1]])])", str(root / "**" / "*.mcap")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert eval(proc.stdout) == [str(root / "a" / "b" / "good.mcap")]


def test_a_fifo_named_as_a_recording_does_not_hang(tmp_path) -> None:
    fifo = B.fifo_recording(tmp_path)
    for args in (["info", str(fifo)], ["detect", str(fifo), "-o", str(tmp_path / "run")]):
        proc = subprocess.run([sys.executable, "-m", "slzcli.cli", *args], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "a FIFO" in proc.stderr, proc.stderr
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- absurd values
@pytest.mark.parametrize("key", ["sources.sync_tolerance_ms", "terrain.noise", "control.sim.timeout_s",
                                 "uav.max_step_m"])
def test_an_absurd_config_value_is_refused_naming_the_key(runner, tmp_path, key) -> None:
    rec = B.good(tmp_path)
    res = invoke(runner, "detect", str(rec), "-o", str(tmp_path / "run"), "--set", f"{key}=1e300")
    assert res.exit_code in (1, 2) and key in res.stderr and "beyond" in res.stderr, res.stderr
    assert not (tmp_path / "run").exists()


def test_synth_frames_beyond_the_bound_is_one_line(runner, tmp_path) -> None:
    """--frames 2^40 was a MemoryError (8 TiB of stamps) before the first frame."""
    res = invoke(runner, "synth", "clear_field", "-o", str(tmp_path / "f.mcap"), "--frames", str(2**40))
    refused(res, "--frames", "synth.max_frames")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [["info", "{rec}", "--start", "1e300"], ["detect", "{rec}", "--end", "1e300"],
                                  ["land", "simulate", "{run}", "--start", "0,0,1e300"]])
def test_absurd_starts_are_usage_errors(runner, tmp_path, args) -> None:
    rec, run = B.good(tmp_path), tmp_path / "RUN"
    write_landing(run)
    res = invoke(runner, *(a.format(rec=rec, run=run) for a in args))
    assert res.exit_code == 2 and "1e300" in res.output and "Traceback" not in res.output


def test_depth_near_the_float32_limit_is_an_answer_not_an_index_error(runner, tmp_path) -> None:
    """3e38 m overflowed the plan raster's indices (IndexError); now no site, and why."""
    path = B.depth_3e38(tmp_path)
    res = invoke(runner, "detect", str(path), "-o", str(tmp_path / "run"), "--json")
    assert res.exit_code == 0, res.stderr
    assert json.loads((tmp_path / "run" / "landing.json").read_text())["status"] == "no_safe_site"
