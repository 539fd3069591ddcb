"""``--json``: one versioned schema (slzcli/schemas/summary.schema.json) for detect, a batch and compare;
errors as an object on stdout; floats rounded; paths as given; usage errors exit 2."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema  # type: ignore[import-untyped]  # no stubs in the lint extra (types-jsonschema)
import pytest
from conftest import GAUSSIAN, HALF_SIZE, REPO, synth_recording

from slzcli.cli import main
from slzcli.outputs.summary_json import SCHEMA_VERSION, round_float, rounded, schema_path

FRAMES = 4


@pytest.fixture(scope="module")
def validator() -> jsonschema.protocols.Validator:
    schema = json.loads(schema_path().read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$defs"]["schema_version"]["const"] == SCHEMA_VERSION
    return jsonschema.Draft202012Validator(schema)


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """Two ground-truthed recordings (with their sidecars) in one folder (half size: the schema, not accuracy)."""
    folder = tmp_path_factory.mktemp("json")
    synth_recording(folder / "cf.mcap", "clear_field", FRAMES, *GAUSSIAN, *HALF_SIZE)
    for f in list(folder.iterdir()):
        shutil.copy(f, folder / f.name.replace("cf.mcap", "cf2.mcap"))
    return folder


def floats(obj: Any) -> list[float]:
    if isinstance(obj, float):
        return [obj]
    if isinstance(obj, dict):
        return [x for v in obj.values() for x in floats(v)]
    if isinstance(obj, list):
        return [x for v in obj for x in floats(v)]
    return []


def check(validator, out: dict[str, Any], kind: str) -> None:
    errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(out)]
    assert errors == [], errors[:5]
    assert out["schema_version"] == SCHEMA_VERSION and out.get("command") == kind
    assert all(round_float(x) == x for x in floats(out)), "a float was not rounded"


def test_detect_batch_and_compare_validate_against_one_schema(runner, flights: Path, validator, monkeypatch) -> None:
    monkeypatch.chdir(flights)  # relative paths: --json must print them as given
    odometry = ["--set", "slam.backend=odometry"]  # deterministic: the three commands' sites are compared exactly
    res = runner.invoke(main, ["detect", "cf.mcap", "-o", "out/cf", "--outputs", "summary", "--json", *odometry])
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    check(validator, d, "detect")
    assert (d["source"], d["run"]) == ("cf.mcap", "out/cf")
    assert d["timings_ms"]["score"] == d["timings_ms"][d["method"]]
    assert d["ground_truth"]["mask"]["precision"] is not None
    run = json.loads(Path("out/cf/run.json").read_text())
    assert Path(run["summary"]["source"]).is_absolute()   # the run folder keeps the absolute path
    assert d["site_world"] == [round_float(x) for x in run["summary"]["site_world"]]

    res = runner.invoke(main, ["detect", "cf.mcap", "./cf2.mcap", "-o", "out/b", "--outputs", "summary",
                               "--workers", "1", "--json", *odometry])
    assert res.exit_code == 0, res.output
    b = json.loads(res.stdout)
    check(validator, b, "batch")
    assert [(r["source"], r["run"]) for r in b["runs"]] == [("cf.mcap", "out/b/cf"), ("cf2.mcap", "out/b/cf2")]
    assert all(r["ground_truth"]["mask"] is not None and r["reason"] is None for r in b["runs"])
    assert b["runs"][0]["site_world"] == d["site_world"]

    res = runner.invoke(main, ["compare", "cf.mcap", "-o", "out/cmp", "--json", *odometry])
    assert res.exit_code == 0, res.output
    c = json.loads(res.stdout)
    check(validator, c, "compare")
    rec = c["recordings"][0]
    assert rec["source"] == "cf.mcap"
    assert rec["methods"]["fuzzy"]["site_world"] == d["site_world"]   # the same frames, maps and points


def test_errors_under_json_are_one_object_on_stdout(runner, flights: Path, validator, monkeypatch) -> None:
    monkeypatch.chdir(flights)
    cases = [
        (["detect", "nothere.mcap"], 1, "DatasetError", {"file": "nothere.mcap"}),
        (["info", "nothere.mcap"], 1, "DatasetError", {"file": "nothere.mcap"}),
        (["detect", "cf.mcap", "-o", "out/e", "--set", "mask.nope=1"], 1, "ConfigError", {"key": "mask.nope"}),
        (["detect", "cf.mcap", "-o", "out/e", "--start", "100"], 1, "DatasetError", {"file": "cf.mcap"}),
        (["detect", "cf.mcap", "--set", "foo"], 2, "usage", {}),
        (["detect", "cf.mcap", "--start", "1,2"], 2, "usage", {}),
        (["compare", "cf.mcap", "--end", "x"], 2, "usage", {}),
        (["detect", "cf.mcap", "--no-such-option"], 2, "usage", {}),
    ]
    for args, code, kind, fields in cases:
        res = runner.invoke(main, [*args, "--json"])
        assert res.exit_code == code, (args, res.output)
        out = json.loads(res.stdout)  # stdout is exactly one JSON object
        check_error = [e.message for e in validator.iter_errors(out)]
        assert check_error == [], (args, check_error)
        err = out["error"]
        assert (err["exit_code"], err["kind"]) == (code, kind), (args, err)
        assert {k: err.get(k) for k in fields} == fields, (args, err)
        assert "Traceback" not in res.output and res.stderr.strip(), args  # still a line on stderr
    assert not Path("out/e").exists()


def test_usage_errors_exit_2_without_json_too(runner, flights: Path) -> None:
    rec = str(flights / "cf.mcap")
    for args in (["detect", rec, "--set", "foo"], ["info", rec, "--set", "=1"], ["detect", rec, "--max-frames", "-1"]):
        res = runner.invoke(main, args)
        assert res.exit_code == 2, (args, res.output)
        assert "slz: error: Invalid value" in res.stderr and not res.stdout


def test_json_usage_error_through_the_real_entry_point(flights: Path) -> None:
    """The group's ``main`` (not only CliRunner): a usage error under --json in a real process."""
    proc = subprocess.run([sys.executable, "-m", "slzcli.cli", "info", str(flights / "cf.mcap"), "--stride", "0",
                           "--json"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert json.loads(proc.stdout)["error"]["kind"] == "usage"
    proc = subprocess.run([sys.executable, "-m", "slzcli.cli", "--version"], capture_output=True, text=True,
                          cwd=REPO, timeout=120)
    assert proc.returncode == 0 and "slz" in proc.stdout


@pytest.mark.parametrize(("x", "expected"), [
    (19.999999999999996, 20.0), (0.1 + 0.2, 0.3), (1e-7 / 3, 3.333333333e-08), (123456.123456789, 123456.123457),
    (-2.5000000000000004, -2.5), (0.0, 0.0), (1700000000.166666665, 1700000000.166667)])
def test_round_float(x: float, expected: float) -> None:
    assert round_float(x) == expected


def test_rounded_keeps_ints_bools_and_non_finite() -> None:
    out = rounded({"a": [1, True, None, "s", 0.30000000000000004], "b": (float("nan"), 2**70)})
    b = out["b"]
    assert isinstance(b, list) and math.isnan(b[0]) and b[1] == 2**70
    assert out["a"] == [1, True, None, "s", 0.3]


def test_config_dump_json_is_not_rounded(runner) -> None:
    """Config values round-trip: --json of config dump is exact, not rounded like the summaries."""
    res = runner.invoke(main, ["config", "dump", "--set", "camera.fx=462.13708496093753", "--json"])
    assert res.exit_code == 0 and json.loads(res.stdout)["camera"]["fx"] == 462.13708496093753


def test_the_schema_file_is_packaged() -> None:
    text = (REPO / "pyproject.toml").read_text()
    assert '"schemas/*.json"' in text and schema_path().is_file()
