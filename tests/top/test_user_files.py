"""slz deletes only what it wrote; reruns skip on content (issue 15), through the CLI.

Real folders holding a user's files (a recording, its ground truth, a thesis, notes, landing
simulations) are handed to `slz detect`, `slz compare`, a batch and `slz synth` as `-o`; every
refusal must be exit 1 with one line naming the path and the cause, and leave every byte where it
was. Recordings are the small textured flights of the bad-input corpus (fast to write, and the
odometry backend tracks them); `slz synth` is only run where synth itself is under test.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import threading
from pathlib import Path

import bad_inputs as B
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN

from slzcli import fingerprint
from slzcli.cli import main
from slzcli.outputs import run_lock
from slzcli.outputs.recording import RecordingWriter

FAST = ("--set", "slam.backend=odometry")  # tracks the corpus' textured frames; no native worker to start


def snapshot(folder: Path) -> dict[str, str]:
    """Every file and folder under ``folder`` (hidden ones too) -> sha256 of its bytes ('dir' for folders)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p.relative_to(folder))] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def invoke(runner: CliRunner, *args: str):
    res = runner.invoke(main, list(args))
    assert "Traceback" not in res.output and "internal error" not in res.stderr, res.stderr
    return res


def refused(res, path_part: str, cause: str) -> str:
    """Exit 1, exactly one error line, naming the path and the cause; returns the line."""
    assert res.exit_code == 1, res.output
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("slz: error:")]
    assert len(errors) == 1, res.stderr
    assert path_part in errors[0] and cause in errors[0], errors[0]
    return errors[0]


SYNTH = ("--frames", "2", *GAUSSIAN, "--set", "camera.width=160", "--set", "camera.height=120",
         "--set", "camera.fx=115.5", "--set", "camera.fy=115.5", "--set", "camera.cx=80",
         "--set", "camera.cy=60")  # small and quick to render


@pytest.fixture(scope="module")
def synth_flight(tmp_path_factory) -> Path:
    """A `slz synth` recording with its ground-truth sidecars (rendered once, copied per test)."""
    folder = tmp_path_factory.mktemp("synth")
    res = CliRunner().invoke(main, ["synth", "clear_field", "-o", str(folder / "flight.mcap"), *SYNTH])
    assert res.exit_code == 0, res.output
    return folder / "flight.mcap"


def user_folder(root: Path, flight: Path) -> Path:
    """A user's folder: a recording with its ground-truth sidecars, a thesis in a subfolder, notes."""
    folder = root / "data"
    (folder / "sub").mkdir(parents=True)
    for src in (flight, *(flight.parent / f"{flight.name}{s}" for s in (".gt.json", ".gt.npz"))):
        shutil.copy(src, folder / src.name)
    (folder / "sub" / "thesis.tex").write_text("\\chapter{Landing}\n")
    (folder / "notes.txt").write_text("do not delete\n")
    return folder


def ros2_bag(path: Path, n: int = 4) -> Path:
    with RecordingWriter(path, "ros2-mcap") as w:
        for i in range(n):
            w.write_frame(B.textured_frame(i))
    return path


def detect(runner: CliRunner, rec: Path, out: Path, *extra: str) -> dict:
    res = invoke(runner, "detect", str(rec), "-o", str(out), "--json", *FAST, *extra)
    assert res.exit_code == 0, res.stderr
    return json.loads(res.stdout)


# ----------------------------------------------------------------------------- slz detect -o
def test_detect_into_the_recordings_folder_is_refused(runner, tmp_path, monkeypatch, synth_flight) -> None:
    folder = user_folder(tmp_path, synth_flight)
    before = snapshot(folder)
    monkeypatch.chdir(folder)
    refused(invoke(runner, "detect", "flight.mcap", "-o", ".", *FAST), str(folder), "holds the input")
    assert snapshot(folder) == before


def test_detect_into_a_users_folder_is_refused_and_nothing_changes(runner, tmp_path, synth_flight) -> None:
    folder = user_folder(tmp_path, synth_flight)
    before = snapshot(folder)
    res = invoke(runner, "detect", str(folder / "flight.mcap"), "-o", str(folder / "sub"), *FAST)
    refused(res, str(folder / "sub"), "not an slz detect run folder")
    res = invoke(runner, "detect", str(folder / "flight.mcap"), "-o", str(folder / "notes.txt"), *FAST)
    assert res.exit_code == 2 and "notes.txt" in res.stderr and "is a file" in res.stderr  # click: a usage error
    assert snapshot(folder) == before


def test_detect_into_the_input_rosbag2_folder_is_refused(runner, tmp_path) -> None:
    bag = ros2_bag(tmp_path / "bag")
    before = snapshot(tmp_path)
    refused(invoke(runner, "detect", str(bag), "-o", str(bag), *FAST), str(bag), "is the input recording")
    refused(invoke(runner, "detect", str(bag / "bag.mcap"), "-o", str(bag), *FAST), str(bag), "holds the input")
    assert snapshot(tmp_path) == before


def test_another_config_is_refused_and_force_keeps_what_slz_did_not_write(runner, tmp_path) -> None:
    rec, run = B.good(tmp_path, n=4), tmp_path / "run"
    first = detect(runner, rec, run)
    assert first["status"] == "site"
    # -> RUN/ibvs and RUN/ibvs2: every file a landing writes; a 0.5 s flight (a timeout, still exit 0) writes them
    # all, and whether the UAV lands is not what is held here (tests/control/test_control_cli.py)
    short = ("--set", "control.sim.timeout_s=0.5")
    assert invoke(runner, "land", "simulate", str(run), "--offset", "1,-1,6", *short).exit_code == 0
    assert invoke(runner, "land", "simulate", str(run), "--offset", "0,1,5", "-o", str(run / "ibvs2"),
                  *short).exit_code == 0
    (run / "notes.txt").write_text("mine\n")
    mine = {k: v for k, v in snapshot(run).items() if k.startswith(("ibvs", "notes"))}
    before = snapshot(run)

    res = invoke(runner, "detect", str(rec), "-o", str(run), *FAST, "--set", "mask.threshold=0.6")
    line = refused(res, str(run), "--force")
    assert "mask.threshold 0.5 -> 0.6" in line and "another -o" in line
    assert snapshot(run) == before

    again = detect(runner, rec, run, "--set", "mask.threshold=0.6", "--force")
    assert not again.get("skipped")
    after = snapshot(run)
    assert {k: v for k, v in after.items() if k.startswith(("ibvs", "notes"))} == mine  # every byte of them
    doc = json.loads((run / "run.json").read_text())
    assert doc["config"]["mask"]["threshold"] == 0.6 and doc["slz_output"]["state"] == "finished"
    assert not {"ibvs", "ibvs2", "notes.txt"} & set(doc["slz_output"]["files"])
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary, no .run.old


def test_the_skip_keys_on_the_rules_files_bytes_not_its_name_or_mtime(runner, tmp_path) -> None:
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    rules = tmp_path / "rules.yaml"
    shutil.copy(Path(__file__).resolve().parents[2] / "slzcli" / "configs" / "fuzzy_rules.yaml", rules)
    opts = ("--set", f"scoring.fuzzy.rules={rules}")
    detect(runner, rec, run, *opts)
    assert detect(runner, rec, run, *opts).get("skipped") is True
    st = rules.stat()
    text = rules.read_text()
    edited = text.replace("low: {triangle: [0.0, 0.0, 0.5]}", "low: {triangle: [0.0, 0.0, 0.6]}", 1)
    assert edited != text and len(edited) == len(text)
    rules.write_text(edited)
    os.utime(rules, ns=(st.st_atime_ns, st.st_mtime_ns))  # same size, same mtime: only the bytes differ
    refused(invoke(runner, "detect", str(rec), "-o", str(run), *FAST, *opts), str(run), "rules rules.yaml changed")
    assert not detect(runner, rec, run, *opts, "--force").get("skipped")


def test_the_skip_keys_on_the_recording_its_ground_truth_and_slz_version(runner, tmp_path, monkeypatch) -> None:
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    detect(runner, rec, run)
    data = bytearray(rec.read_bytes())
    st = rec.stat()
    data[-40] ^= 0xFF  # a flipped byte in the MCAP footer's padding region: same size
    rec.write_bytes(bytes(data))
    os.utime(rec, ns=(st.st_atime_ns, st.st_mtime_ns))
    refused(invoke(runner, "detect", str(rec), "-o", str(run), *FAST), str(run), "recording good.mcap changed")
    data[-40] ^= 0xFF
    rec.write_bytes(bytes(data))
    assert detect(runner, rec, run).get("skipped") is True  # the same bytes again: the same run
    monkeypatch.setattr(fingerprint, "__version__", "99.0")
    refused(invoke(runner, "detect", str(rec), "-o", str(run), *FAST), str(run), "versions")


def test_the_skip_keys_on_the_method(runner, tmp_path) -> None:
    """--method is not in the config dict: a bayes rerun used to be 'skipped' with the fuzzy result."""
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    detect(runner, rec, run)
    refused(invoke(runner, "detect", str(rec), "-o", str(run), *FAST, "--method", "bayes"), str(run),
            "method fuzzy -> bayes")
    assert detect(runner, rec, run, "--method", "bayes", "--force")["method"] == "bayes"


def test_the_key_covers_the_orb_vocabulary_when_orbslam3_may_run(tmp_path) -> None:
    from slzcli.config import load_config
    from slzcli.slam.vocabulary import DEFAULT_VOCABULARY

    rec, vocab = B.good(tmp_path, n=2), tmp_path / "vocab.txt"
    shutil.copy(DEFAULT_VOCABULARY, vocab)
    cfg = load_config(overrides=["slam.backend=orbslam3", f"slam.vocabulary={vocab}"])

    def key() -> str:
        return fingerprint.run_key(cfg, "fuzzy", fingerprint.run_inputs(rec, cfg, {}), fingerprint.versions(cfg))

    before = key()
    assert [e["path"] for e in fingerprint.run_inputs(rec, cfg, {})["vocabulary"]] == [str(vocab.resolve())]
    vocab.write_bytes(vocab.read_bytes().replace(b"1", b"2", 1))
    assert key() != before
    odometry = load_config(overrides=["slam.backend=odometry", f"slam.vocabulary={vocab}"])
    assert fingerprint.run_inputs(rec, odometry, {})["vocabulary"] == []  # not read: not in the key


def test_inputs_hashed_in_the_background_are_the_same_and_fail_the_same(tmp_path, monkeypatch) -> None:
    """A first run hashes its inputs while it starts (fingerprint.PendingInputs): the same digests as in the
    run's own thread, and what hashing raised is raised where the run waits for them."""
    from slzcli.config import load_config

    rec, cfg = B.good(tmp_path, n=2), load_config()
    assert fingerprint.PendingInputs(rec, cfg, {}).result() == fingerprint.run_inputs(rec, cfg, {})

    def unreadable(p: Path) -> str:
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(fingerprint, "sha256_of", unreadable)
    pending = fingerprint.PendingInputs(rec, cfg, {})
    with pytest.raises(PermissionError):
        pending.result()


def test_a_first_runs_key_is_the_one_a_rerun_compares(runner, tmp_path) -> None:
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    detect(runner, rec, run)   # no finished run in the folder: hashed in the background
    key = json.loads((run / "run.json").read_text())["key"]
    from slzcli.config import load_config

    cfg = load_config(overrides=list(FAST[1::2]))
    inputs = fingerprint.run_inputs(rec, cfg, {})
    assert key["inputs"] == json.loads(json.dumps(inputs))
    assert key["sha256"] == fingerprint.run_key(cfg, "fuzzy", inputs, fingerprint.versions(cfg))


def test_a_rerun_does_not_rehash_unchanged_inputs(runner, tmp_path, monkeypatch) -> None:
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    hashed: list[str] = []
    real = fingerprint.sha256_of

    def counted(p: Path) -> str:
        hashed.append(Path(p).name)
        return real(p)

    monkeypatch.setattr(fingerprint, "sha256_of", counted)
    detect(runner, rec, run)
    assert "good.mcap" in hashed and "fuzzy_rules.yaml" in hashed
    hashed.clear()
    assert detect(runner, rec, run).get("skipped") is True and hashed == []  # the cache in run.json
    os.utime(rec)  # touched, same bytes: hashed again, still the same run
    assert detect(runner, rec, run).get("skipped") is True and hashed == ["good.mcap"]


def test_a_run_folder_inside_a_rosbag2_folder_is_skipped_on_rerun(runner, tmp_path) -> None:
    bag = ros2_bag(tmp_path / "bag")
    detect(runner, bag, bag / "run")
    (bag / "notes.txt").write_text("the bag's own notes\n")  # not a file the reader reads
    assert detect(runner, bag, bag / "run").get("skipped") is True


def test_a_killed_swap_is_recognised_and_redone_without_force(runner, tmp_path) -> None:
    """A run killed between moving the old files out and the new ones in left a 'replacing' marker."""
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    detect(runner, rec, run)
    doc = json.loads((run / "run.json").read_text())
    names = doc["slz_output"]["files"]
    (run / "landing.json").unlink()  # already moved out by the killed run
    (run / "run.json").write_text(json.dumps({"slz_output": {"kind": "detect", "state": "replacing",
                                                             "files": names}}))
    (run / "notes.txt").write_text("mine\n")
    again = detect(runner, rec, run)
    assert not again.get("skipped") and (run / "landing.json").is_file() and (run / "notes.txt").is_file()


def test_a_file_slz_did_not_write_under_a_name_it_writes_is_refused(runner, tmp_path) -> None:
    rec, run = B.good(tmp_path, n=3), tmp_path / "run"
    detect(runner, rec, run, "--set", "output.results_mcap=false")
    (run / "results.mcap").write_text("the user's own\n")
    before = snapshot(run)
    res = invoke(runner, "detect", str(rec), "-o", str(run), *FAST, "--force")
    refused(res, "results.mcap", "not written by slz")
    assert snapshot(run) == before


# ----------------------------------------------------------------------------- batches
def test_batch_slot_holding_a_file_is_a_failed_row_not_a_hidden_file(runner, tmp_path) -> None:
    a = B.good(tmp_path, n=3).rename(tmp_path / "a.mcap")
    b = B.depth_constant(tmp_path).rename(tmp_path / "b.mcap")
    out = tmp_path / "runs"
    out.mkdir()
    (out / "a").write_text("a file where run folder a would go\n")
    res = invoke(runner, "detect", str(a), str(b), "-o", str(out), "--workers", "1", *FAST)
    refused(res, "1 of 2 recordings failed", "is not a folder")
    rows = {Path(r["run"]).name: r for r in csv.DictReader((out / "summary.csv").open())}
    assert rows["a"]["status"] == "failed" and "is not a folder" in rows["a"]["error"]
    assert rows["b"]["status"] in ("site", "no_safe_site")
    assert (out / "a").read_text() == "a file where run folder a would go\n"
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []  # no .a.old


def test_batch_into_the_folder_of_its_rosbag2_inputs_is_refused_before_anything_runs(runner, tmp_path) -> None:
    bags = tmp_path / "bags"
    bags.mkdir()
    for name in ("b1", "b2"):
        ros2_bag(bags / name, n=3)
    before = snapshot(bags)
    res = invoke(runner, "detect", str(bags / "b1"), str(bags / "b2"), "-o", str(bags), *FAST)
    refused(res, str(bags / "b1"), "is the input recording")
    assert snapshot(bags) == before


def test_batch_folder_with_a_users_summary_is_refused(runner, tmp_path) -> None:
    shutil.copy(B.good(tmp_path, n=2), tmp_path / "b.mcap")
    (tmp_path / "good.mcap").rename(tmp_path / "a.mcap")
    out = tmp_path / "runs"
    out.mkdir()
    (out / "summary.csv").write_text("my,own,table\n")
    before = snapshot(out)
    res = invoke(runner, "detect", str(tmp_path / "a.mcap"), str(tmp_path / "b.mcap"), "-o", str(out), *FAST)
    refused(res, "summary.csv", "not written by slz")
    assert snapshot(out) == before


def test_a_name_with_glob_characters_that_exists_is_that_file(runner, tmp_path) -> None:
    B.good(tmp_path, n=2).rename(tmp_path / "flight[1].mcap")
    B.depth_constant(tmp_path).rename(tmp_path / "flight1.mcap")
    summary = detect(runner, tmp_path / "flight[1].mcap", tmp_path / "run")
    assert summary["source"].endswith("flight[1].mcap") and not (tmp_path / "summary.csv").exists()


def test_a_second_batch_waits_for_the_first_and_reports_its_run_as_done(runner, tmp_path, monkeypatch) -> None:
    """Two identical batches on one -o: the run one of them writes is not 'failed' in the other's summary."""
    from slzcli.config import load_config
    from slzcli.pipeline import detect_recording

    rec = B.good(tmp_path, n=3).rename(tmp_path / "a.mcap")
    shutil.copy(rec, tmp_path / "b.mcap")
    out = tmp_path / "runs"
    locked, waiting = threading.Event(), threading.Event()
    warn = run_lock.log.warning

    def warning(*args: object) -> None:
        waiting.set()
        warn(*args)

    monkeypatch.setattr(run_lock.log, "warning", warning)
    config = load_config(overrides=["slam.backend=odometry"])

    def first_batch() -> None:  # holds run a's lock until the CLI waits for it, then finishes run a
        with run_lock.claim(out / "a"):
            locked.set()
            waiting.wait(120)
            detect_recording(rec.absolute(), config, out / "a")

    t = threading.Thread(target=first_batch)
    t.start()
    try:
        assert locked.wait(60)
        res = invoke(runner, "detect", str(rec), str(tmp_path / "b.mcap"), "-o", str(out), "--workers", "1",
                     "--json", *FAST)
    finally:
        waiting.set()
        t.join(120)
    assert res.exit_code == 0, res.stderr
    rows = {Path(r["run"]).name: r for r in json.loads(res.stdout)["runs"]}
    assert rows["a"]["skipped"] is True and rows["a"]["status"] in ("site", "no_safe_site")
    assert "waiting for it to finish" in res.stderr


# ----------------------------------------------------------------------------- slz compare -o
def test_compare_into_the_recordings_folder_is_refused_with_force(runner, tmp_path, synth_flight) -> None:
    folder = user_folder(tmp_path, synth_flight)
    before = snapshot(folder)
    res = invoke(runner, "compare", str(folder / "flight.mcap"), "-o", str(folder), "--force", *FAST)
    refused(res, str(folder), "holds the input")
    res = invoke(runner, "compare", str(folder / "flight.mcap"), "-o", str(folder / "sub"), "--force", *FAST)
    refused(res, "sub", "not an slz compare folder")
    assert snapshot(folder) == before


def test_compare_force_replaces_only_what_compare_wrote(runner, tmp_path) -> None:
    rec, out = B.good(tmp_path, n=3), tmp_path / "cmp"
    assert invoke(runner, "compare", str(rec), "-o", str(out), *FAST).exit_code == 0
    (out / "notes.txt").write_text("mine\n")
    refused(invoke(runner, "compare", str(rec), "-o", str(out), *FAST), str(out), "--force")
    assert invoke(runner, "compare", str(rec), "-o", str(out), "--force", *FAST).exit_code == 0
    assert (out / "notes.txt").read_text() == "mine\n" and (out / "compare.json").is_file()
    assert json.loads((out / "compare.json").read_text())["slz_output"]["kind"] == "compare"


# ----------------------------------------------------------------------------- slz synth -o


def test_synth_force_never_replaces_a_folder_with_a_users_files(runner, tmp_path, synth_flight) -> None:
    folder = user_folder(tmp_path, synth_flight)
    before = snapshot(folder)
    res = invoke(runner, "synth", "clear_field", "-o", str(folder), "--format", "ros2-mcap", "--force", *SYNTH)
    refused(res, str(folder), "not a rosbag2 bag folder")
    res = invoke(runner, "synth", "clear_field", "-o", str(folder / "sub"), "--format", "ros2-mcap", "--force",
                 *SYNTH)
    refused(res, "sub", "holds thesis.tex")
    assert snapshot(folder) == before


def test_synth_force_never_pairs_a_recording_with_the_old_truth(runner, tmp_path, monkeypatch) -> None:
    """Killed between putting the new recording in place and its sidecar: no truth, not the old scene's."""
    from slzcli.config import load_config
    from slzcli.evaluate.truth import ground_truth_of
    from slzcli.synth import record

    out = tmp_path / "f.mcap"
    assert invoke(runner, "synth", "no_site", "-o", str(out), *SYNTH).exit_code == 0
    assert ground_truth_of(out, load_config().synth.ground_truth) is not None
    real = os.replace

    def killed_after_the_recording(src, dst):
        if Path(dst) == tmp_path / "f.mcap.gt.npz":
            raise KeyboardInterrupt  # as a kill would land there
        return real(src, dst)

    monkeypatch.setattr(record.os, "replace", killed_after_the_recording)
    res = runner.invoke(main, ["synth", "clear_field", "-o", str(out), "--force", *SYNTH])
    assert res.exit_code == 130
    monkeypatch.undo()
    # the old header went first: no recording is paired with the wrong truth
    assert ground_truth_of(out, load_config().synth.ground_truth) is None
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # an interrupt cleans up


def test_synth_removes_what_a_killed_synth_left_and_nothing_else(runner, tmp_path) -> None:
    """Only marked temporaries go: a user's folders and files that merely have such names stay."""
    from slzcli.outputs.safe_output import make_temp_dir

    out = tmp_path / "f.mcap"
    stage = make_temp_dir(out, ".tmp")  # a killed synth's staging folder
    (stage / "f.mcap").write_bytes(b"half")
    old = make_temp_dir(out, ".old")  # a killed synth's swapped-out rosbag2 folder
    users = [".f.mcap.notes", ".f.mcap.mine.tmp", ".f.mcap.preview.png.tmp-ab12.png"]
    for name in users:
        (tmp_path / name).write_text("a user's file\n")
    for name in (".f.mcap.x1y2.tmp", ".f.mcap.1234.old"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "thesis.tex").write_text("a user's folder\n")
    assert invoke(runner, "synth", "clear_field", "-o", str(out), *SYNTH).exit_code == 0
    assert not stage.exists() and not old.exists()
    left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("."))
    assert left == sorted([*users, ".f.mcap.x1y2.tmp", ".f.mcap.1234.old"])
    assert (tmp_path / ".f.mcap.x1y2.tmp" / "thesis.tex").is_file()


# ----------------------------------------------------------------------------- reproducibility
@pytest.mark.parametrize("backend", ["odometry", "recorded"])
def test_odometry_and_recorded_runs_are_bit_reproducible_alone_and_in_a_batch(runner, tmp_path, backend) -> None:
    """The same recording twice, and once after another recording in the same process: the same bytes."""
    rec = tmp_path / "flight.mcap"
    with RecordingWriter(rec, "mcap") as w:
        for i in range(5):
            f = B.textured_frame(i)
            w.write_frame(f)
            x = -2 * B.ALTITUDE_M / (0.8 * B.W) * i  # the motion the images show (2 px a frame)
            T = [[1, 0, 0, x], [0, -1, 0, 0], [0, 0, -1, B.ALTITUDE_M], [0, 0, 0, 1]]  # looking down
            w.write_pose("/camera/pose", f.stamp_ns, np.array(T, float))
    opts = ("--set", f"slam.backend={backend}")
    runs = [tmp_path / "r1", tmp_path / "r2"]
    for run in runs:
        assert detect(runner, rec, run, *opts)["slam_backend"] == backend
    other = B.depth_constant(tmp_path)
    res = invoke(runner, "detect", str(other), str(rec), "-o", str(tmp_path / "batch"), "--workers", "1", *FAST, *opts)
    assert res.exit_code == 0, res.stderr
    runs.append(tmp_path / "batch" / "flight")
    maps = [str(p.relative_to(runs[0])) for p in sorted(runs[0].glob("frames/*/maps.npz"))]
    assert maps  # every detection frame's maps are compared too
    for name in ("trajectory.tum", "sites.csv", "keyframes.npz", "points.ply", *maps):
        assert len({(r / name).read_bytes() for r in runs}) == 1, name
    landings = [json.loads((r / "landing.json").read_text()) for r in runs]
    for doc in landings:
        doc.pop("timings_ms")
    assert landings[0] == landings[1] == landings[2]
