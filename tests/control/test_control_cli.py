"""`slz land simulate`: a landing.json in tmp_path -> RUN/ibvs outputs; bad inputs -> exit 1, one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from landing_file import write_landing

from slzcli.cli import main


def one_line_error(result, *words: str) -> None:
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("slz: error:"), result.output
    assert "Traceback" not in result.output
    for w in words:
        assert w in lines[0], lines[0]


def test_simulate_writes_outputs_and_succeeds(tmp_path: Path, runner: CliRunner) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    result = runner.invoke(main, ["land", "simulate", str(run), "--start", "0.4,-0.3,3", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["success"] is True and summary["reason"] == "touchdown"
    out = run / "ibvs"
    for name in ("trajectory.csv", "features.csv", "metrics.json", "image_plane.png", "feature_error.png",
                 "trajectory_3d.png"):
        assert (out / name).stat().st_size > 0, name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] is True and metrics["touchdown_error_m"] < 0.1
    assert metrics["final_feature_error_px"] < 1.0 and metrics["stabilisation_time_s"] > 0
    header = (out / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["t_s", "x_m", "y_m", "z_m"] and "thrust_n" in header and "tau_z_n_m" in header
    rows = (out / "features.csv").read_text().splitlines()
    assert "e_qz" in rows[0] and "u3_px" in rows[0] and len(rows) > 100
    assert not list(out.glob(".*tmp*"))  # atomic writes leave no temporaries


def test_landing_json_path_and_output_option(tmp_path: Path, runner: CliRunner) -> None:
    path = write_landing(tmp_path / "RUN")
    out = tmp_path / "elsewhere"
    result = runner.invoke(main, ["land", "simulate", str(path), "-o", str(out), "--start", "0,0,2.5",
                                  "--set", "control.sim.timeout_s=2"])
    assert result.exit_code == 0, result.output  # a failed landing is a result, not an error
    assert "FAILED (timeout)" in result.output and (out / "metrics.json").is_file()
    assert json.loads((out / "metrics.json").read_text())["reason"] == "timeout"
    assert not (path.parent / "ibvs").exists()


def test_montecarlo_writes_aggregate(tmp_path: Path, runner: CliRunner) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    result = runner.invoke(main, ["land", "simulate", str(run), "--start", "0,0,3", "--runs", "4", "--seed", "1",
                                  "--set", "control.sim.timeout_s=20", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["runs"] == 4 and summary["seed"] == 1
    mc = json.loads((run / "ibvs" / "montecarlo.json").read_text())
    assert mc["runs"] == 4 and set(mc) >= {"success_rate", "reasons", "touchdown_error_m", "landing_time_s"}
    assert (run / "ibvs" / "montecarlo_hist.png").stat().st_size > 0
    assert len((run / "ibvs" / "montecarlo_runs.csv").read_text().splitlines()) == 5


def test_no_safe_site_is_exit_1_one_line(tmp_path: Path, runner: CliRunner) -> None:
    write_landing(tmp_path / "RUN", status="no_safe_site")
    result = runner.invoke(main, ["land", "simulate", str(tmp_path / "RUN")])
    one_line_error(result, "no_safe_site", "landing.json")
    assert not (tmp_path / "RUN" / "ibvs").exists()


def test_recording_or_empty_folder_asks_for_slz_detect(tmp_path: Path, runner: CliRunner) -> None:
    bag = tmp_path / "flight.mcap"
    bag.write_bytes(b"\x89MCAP0\r\n")
    one_line_error(runner.invoke(main, ["land", "simulate", str(bag)]), "slz detect", "flight.mcap")
    empty = tmp_path / "empty"
    empty.mkdir()
    one_line_error(runner.invoke(main, ["land", "simulate", str(empty)]), "slz detect", "landing.json")
    one_line_error(runner.invoke(main, ["land", "simulate", str(tmp_path / "missing")]), "not found")


def test_broken_landing_json_and_bad_config_name_the_problem(tmp_path: Path, runner: CliRunner) -> None:
    run = tmp_path / "RUN"
    run.mkdir()
    (run / "landing.json").write_text("{not json")
    one_line_error(runner.invoke(main, ["land", "simulate", str(run)]), "landing.json", "JSON")
    (run / "landing.json").write_text(json.dumps({"status": "site", "site": {"center_world": [1, 2]}}))
    one_line_error(runner.invoke(main, ["land", "simulate", str(run)]), "site.center_world")
    write_landing(run)
    one_line_error(runner.invoke(main, ["land", "simulate", str(run), "--set", "control.sim.control_dt_s=0.003"]),
                   "control.sim.control_dt_s")
    one_line_error(runner.invoke(main, ["land", "simulate", str(run), "--set", "control.K_p=[1, 2]"]),
                   "control.K_p")


def test_usage_errors_exit_2(tmp_path: Path, runner: CliRunner) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    assert runner.invoke(main, ["land", "simulate", str(run), "--scenario", "5"]).exit_code == 2
    assert runner.invoke(main, ["land", "simulate", str(run), "--start", "a,b"]).exit_code == 2
    assert runner.invoke(main, ["land", "simulate", str(run), "--scenario", "1", "--start", "0,0,3"]).exit_code == 2
    result = runner.invoke(main, ["land", "simulate", str(run), "--start", "0,0,3", "--scenario", "1"])
    assert result.exit_code in (1, 2) and "not both" in result.output
    result = runner.invoke(main, ["land", "simulate", str(run), "--offset", "0,0,3", "--start", "1,-0.5,3.1"])
    assert result.exit_code in (1, 2) and "not both" in result.output


def test_start_is_absolute_offset_is_from_the_site_and_yaw_is_enu_everywhere(tmp_path: Path,
                                                                             runner: CliRunner) -> None:
    """--start means a world position as in `slz synth`; --offset is from the site (1.0, -0.5, 0.1).
    The start yaw of metrics.json and the first yaw of trajectory.csv are one convention (ENU)."""
    run = tmp_path / "RUN"
    write_landing(run)
    sets = ["--set", "control.sim.timeout_s=0.5", "--json"]
    a = runner.invoke(main, ["land", "simulate", str(run), "--start", "1.4,-0.8,3.1,35", "-o", str(tmp_path / "a"),
                             *sets])
    b = runner.invoke(main, ["land", "simulate", str(run), "--offset", "0.4,-0.3,3,35", "-o", str(tmp_path / "b"),
                             *sets])
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    start_a, start_b = json.loads(a.output)["start_world"], json.loads(b.output)["start_world"]
    assert start_a == pytest.approx([1.4, -0.8, 3.1, 35.0]) and start_b == pytest.approx(start_a)
    rows = (tmp_path / "a" / "trajectory.csv").read_text().splitlines()
    head, first = rows[0].split(","), [float(v) for v in rows[1].split(",")]
    assert first[head.index("yaw_deg")] == pytest.approx(35.0, abs=1e-6)
    assert first[head.index("x_m")] == pytest.approx(1.4) and first[head.index("z_m")] == pytest.approx(3.1)


def test_montecarlo_names_every_failure_including_outside_the_radius(tmp_path: Path, runner: CliRunner) -> None:
    run = tmp_path / "RUN"
    write_landing(run)
    # A 1 mm success radius: every landing is outside it (touch-down errors are cm under 2 cm pose noise).
    result = runner.invoke(main, ["land", "simulate", str(run), "--offset", "0,0,3", "--runs", "3", "--seed", "1",
                                  "--set", "control.sim.success_radius_m=0.001", "--json"])
    assert result.exit_code == 0, result.output
    s = json.loads(result.output)
    assert s["success_rate"] == 0.0 and s["failures"] == {"outside_radius": 3} == s["reasons"]
    rows = (run / "ibvs" / "montecarlo_runs.csv").read_text().splitlines()
    assert all(r.endswith(",outside_radius") for r in rows[1:]) and "approach_time_s" in rows[0]
