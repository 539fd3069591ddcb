"""Every command that writes follows one rule (slzcli/outputs/safe_output.py), through the CLI.

No output may be an input or hold one; nothing slz did not write is replaced without --force, and
with it only what slz recognises as its own; names that merely look like slz's temporaries or locks
are a user's and stay; a failed command leaves nothing. Each refusal: exit 1, one line naming the
path, every byte of the user's where it was.
"""

from __future__ import annotations

import csv
import errno
import hashlib
import json
import os
from pathlib import Path

import bad_inputs as B
import pytest
from click.testing import CliRunner
from landing_file import write_landing
from test_user_files import FAST, SYNTH, invoke, refused, snapshot

from slzcli.outputs import safe_output

VOCAB = ("--set", "slam.vocab.levels=2", "--set", "slam.vocab.k=4")


def folder(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ----------------------------------------------------------------------------- slz vocab build
def test_vocab_build_into_its_input_recording_is_refused(runner: CliRunner, tmp_path: Path) -> None:
    rec = B.good(tmp_path)
    before = digest(rec)
    for extra in ((), ("--force",)):
        refused(invoke(runner, "vocab", "build", str(rec), "-o", str(rec), *extra, *VOCAB), rec.name,
                "is the input recording")
    assert digest(rec) == before


def test_vocab_build_never_overwrites_a_file_that_is_not_a_vocabulary(runner: CliRunner, tmp_path: Path) -> None:
    rec = B.good(tmp_path)
    mine = tmp_path / "thesis.txt"
    mine.write_text("chapter one\n")
    refused(invoke(runner, "vocab", "build", str(rec), "-o", str(mine), *VOCAB), "thesis.txt", "already exists")
    refused(invoke(runner, "vocab", "build", str(rec), "-o", str(mine), "--force", *VOCAB), "thesis.txt",
            "is not a vocabulary of slz")
    assert mine.read_text() == "chapter one\n"
    voc = tmp_path / "voc.txt"
    assert invoke(runner, "vocab", "build", str(rec), "-o", str(voc), *VOCAB).exit_code == 0
    assert safe_output.is_vocabulary(voc)
    refused(invoke(runner, "vocab", "build", str(rec), "-o", str(voc), *VOCAB), "voc.txt", "--force")
    assert invoke(runner, "vocab", "build", str(rec), "-o", str(voc), "--force", *VOCAB).exit_code == 0


# ----------------------------------------------------------------------------- slz synth
@pytest.mark.parametrize("companion", [".preview.png", ".gt.json", ".gt.npz"])
def test_synth_never_overwrites_a_users_file_beside_a_new_recording(runner, tmp_path, companion) -> None:
    out = tmp_path / "f.mcap"
    users = tmp_path / f"f.mcap{companion}"
    users.write_bytes(b"a user's file")
    for extra in ((), ("--force",)):
        refused(invoke(runner, "synth", "clear_field", "-o", str(out), *extra, *SYNTH), users.name,
                "use --force" if not extra else "of slz")
    assert users.read_bytes() == b"a user's file" and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [users.name]  # no temporary, no lock


def test_synth_contact_sheet_never_overwrites_a_users_file(runner, tmp_path) -> None:
    sheet = tmp_path / "report.pdf"
    sheet.write_bytes(b"%PDF a user's report")
    out = tmp_path / "f.mcap"
    refused(invoke(runner, "synth", "clear_field", "-o", str(out), "--contact-sheet", str(sheet), *SYNTH),
            "report.pdf", "already exists")
    refused(invoke(runner, "synth", "clear_field", "-o", str(out), "--contact-sheet", str(sheet), "--force",
                   *SYNTH), "report.pdf", "not a preview PNG of slz")
    refused(invoke(runner, "synth", "clear_field", "-o", str(out), "--contact-sheet", str(out), *SYNTH),
            "f.mcap", "are the same file")
    assert sheet.read_bytes() == b"%PDF a user's report" and not out.exists()


def test_synth_force_replaces_a_recording_and_its_own_preview_only(runner, tmp_path) -> None:
    other = tmp_path / "notes.mcap"
    other.write_text("not a recording, though it is named like one\n")
    refused(invoke(runner, "synth", "clear_field", "-o", str(other), "--force", *SYNTH), "notes.mcap",
            "is not a recording")
    assert other.read_text().startswith("not a recording")
    out = tmp_path / "f.mcap"
    assert invoke(runner, "synth", "clear_field", "-o", str(out), *SYNTH).exit_code == 0
    assert safe_output.is_slz_png(tmp_path / "f.mcap.preview.png")  # tagged: a later --force knows it
    assert invoke(runner, "synth", "clear_field", "-o", str(out), "--force", *SYNTH).exit_code == 0


def test_names_that_look_like_slz_temporaries_are_a_users_and_stay(runner, tmp_path) -> None:
    """detect's .RUN.old/ and .RUN.x.partial/, synth's .OUT.x.tmp/: without slz's marker, never removed."""
    rec = B.good(folder(tmp_path / "in"))
    for name in (".run.old", ".run.x1.partial", ".run.abc.old", ".f.mcap.x1.tmp", ".f.mcap.1.old"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "keep.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    assert invoke(runner, "detect", str(rec), "-o", str(tmp_path / "run"), *FAST).exit_code == 0
    assert invoke(runner, "synth", "clear_field", "-o", str(tmp_path / "f.mcap"), *SYNTH).exit_code == 0
    after = snapshot(tmp_path)
    assert {k: v for k, v in after.items() if k in before} == before


@pytest.mark.parametrize("command", ["detect", "synth"])
def test_a_users_file_named_like_the_lock_is_refused_not_removed(runner, tmp_path, command) -> None:
    rec = B.good(folder(tmp_path / "in"))
    name = "run" if command == "detect" else "f.mcap"
    lock = tmp_path / f".{name}.lock"
    lock.write_text("a user's file\n")
    args = (["detect", str(rec), "-o", str(tmp_path / name), *FAST] if command == "detect"
            else ["synth", "clear_field", "-o", str(tmp_path / name), *SYNTH])
    res = invoke(runner, *args)
    if command == "detect":  # a single detect reports its run's error line
        assert res.exit_code == 1 and lock.name in res.stderr and "not a lock file of slz" in res.stderr
    else:
        refused(res, lock.name, "not a lock file of slz")
    assert lock.read_text() == "a user's file\n" and not (tmp_path / name).exists()


# ----------------------------------------------------------------------------- slz detect batch
def test_a_second_batch_into_one_folder_keeps_the_first_batchs_rows(runner, tmp_path) -> None:
    a, b = B.good(folder(tmp_path / "a")), B.depth_constant(folder(tmp_path / "b"))
    c = tmp_path / "c" / "third.mcap"
    c.parent.mkdir()
    c.write_bytes(a.read_bytes())
    out = tmp_path / "batch"
    assert invoke(runner, "detect", str(a), str(b), "-o", str(out), "--workers", "1", *FAST).exit_code == 0
    assert invoke(runner, "detect", str(c), str(b), "-o", str(out), "--workers", "1", *FAST).exit_code == 0
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert sorted(Path(r["run"]).name for r in rows) == ["depth_constant", "good", "third"]
    doc = json.loads((out / "summary.json").read_text())
    assert doc["batch"]["earlier_rows"] == 1 and len(doc["recordings"]) == 3
    assert Path(doc["recordings"][0]["run"]).name == "good"  # the earlier row first


# ----------------------------------------------------------------------------- slz land simulate
def test_land_simulate_never_writes_into_a_users_folder(runner, tmp_path) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "trajectory.csv").write_text("t,x\n0,1\n")
    (out / "metrics.json").write_text('{"mine": true}\n')
    before = snapshot(out)
    refused(invoke(runner, "land", "simulate", str(run), "-o", str(out), "--start", "0.4,-0.3,3"), "mine",
            "not an slz land simulate folder")
    refused(invoke(runner, "land", "simulate", str(run), "-o", str(run), "--start", "0.4,-0.3,3"), "RUN",
            "holds the input")
    assert snapshot(out) == before


def test_land_simulate_reruns_and_monte_carlo_share_its_own_folder(runner, tmp_path) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    for args in (("--start", "0.4,-0.3,3"), ("--start", "0.4,-0.3,3"), ("--runs", "2")):
        assert invoke(runner, "land", "simulate", str(run), *args).exit_code == 0
    names = sorted(p.name for p in (run / "ibvs").iterdir())
    assert "metrics.json" in names and "montecarlo.json" in names and not [n for n in names if n.startswith(".")]
    assert sorted(p.name for p in run.iterdir()) == ["ibvs", "landing.json"]


def test_land_simulate_on_a_full_disk_leaves_nothing(runner, tmp_path, monkeypatch) -> None:
    from slzcli.outputs import ibvs_plots

    run = tmp_path / "RUN"
    write_landing(run)

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(ibvs_plots, "trajectory_3d", disk_full)  # the last of the six files
    res = invoke(runner, "land", "simulate", str(run), "--start", "0.4,-0.3,3")
    refused(res, "ibvs", "No space left on device")
    assert sorted(p.name for p in run.iterdir()) == ["landing.json"]  # no ibvs/, no .ibvs.*.partial, no lock


@pytest.mark.parametrize("start", [("--offset", "0,0,0"), ("--offset", "0.5,0,-2"), ("--start", "1,-0.5,0.1")])
def test_land_simulate_from_at_or_below_the_site_is_one_line(runner, tmp_path, start) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    refused(invoke(runner, "land", "simulate", str(run), *start), start[0], "above the site")
    assert sorted(p.name for p in run.iterdir()) == ["landing.json"]
