"""One run assembly: the Python API and ``slz detect`` are one run, whatever the profile; ``--json`` of every
registered method validates against the packaged schema."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import jsonschema  # type: ignore[import-untyped]  # no stubs in the lint extra (types-jsonschema)
import pytest
from conftest import GAUSSIAN, HALF_SIZE, synth_recording

import slzcli
from slzcli.cli import main
from slzcli.config import Config, load_config, profile_names
from slzcli.landing.select import SelectParams, select_site
from slzcli.methods import registry
from slzcli.methods.maps import fuzzy
from slzcli.methods.registry import names as method_names
from slzcli.outputs.summary_json import schema_path
from slzcli.sources import open_recording
from slzcli.types import Detection, ScoreMap, TerrainMaps, TrackedFrame

FRAMES = 4
ODOMETRY = ["slam.backend=odometry"]
# Every frame a detection, bayes: on this recording the commit rules `agree` and `latest` choose different
# sites (checked below), so a run that commits by the wrong rule shows.
EVERY_FRAME = [*ODOMETRY, "landing.detect_on=every_nth", "landing.every_nth_frame=1"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("assembly") / "office.mcap", "office", FRAMES, *GAUSSIAN,
                           *HALF_SIZE)


def _without_timings(landing: dict) -> dict:
    return {k: v for k, v in landing.items() if k != "timings_ms"}


def _cli_landing(runner, recording: Path, out: Path, sets: list[str], profile: str | None) -> dict:
    args = ["detect", str(recording), "-o", str(out), "--method", "bayes"]
    for s in sets:
        args += ["--set", s]
    if profile is not None:
        args += ["--profile", profile]
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output + res.stderr
    return _without_timings(json.loads((out / "landing.json").read_text()))


def test_the_recording_tells_the_commit_rules_apart(runner, recording, tmp_path) -> None:
    agree = _cli_landing(runner, recording, tmp_path / "agree", [*EVERY_FRAME, "landing.commit=agree"], None)
    latest = _cli_landing(runner, recording, tmp_path / "latest", [*EVERY_FRAME, "landing.commit=latest"], None)
    assert agree["status"] == latest["status"] == "site"
    assert agree["site"]["center_world"] != latest["site"]["center_world"]


@pytest.mark.parametrize("profile", profile_names())
def test_the_api_and_slz_detect_write_the_same_landing_json(runner, recording, tmp_path, profile) -> None:
    """The API on a recording gives landing.json as `slz detect` writes it, under every profile (the paper's
    commits by `latest`); frames in memory give the same site."""
    name = None if profile == "default" else profile
    cli = _cli_landing(runner, recording, tmp_path / "run", EVERY_FRAME, name)
    config = load_config(None, EVERY_FRAME, profile=name)
    assert _without_timings(slzcli.detect(recording, config, method="bayes").landing) == cli
    with open_recording(recording, config) as rec:
        frames = list(rec.frames())
    in_memory = slzcli.detect(iter(frames), config, method="bayes").landing
    if profile == "bench":  # a 0.2 m vehicle from 10 m: the depth noise hides its 0.027 m steps, and both say so
        assert in_memory["status"] == cli["status"] == "no_safe_site"
        assert in_memory["reason"] == cli["reason"] and "hides steps below" in cli["reason"]
        return
    assert in_memory["status"] == cli["status"] == "site"
    assert in_memory["site"]["center_world"] == cli["site"]["center_world"]
    assert in_memory["frame"] == cli["frame"] and in_memory["site"]["support"] == cli["site"]["support"]


@pytest.mark.parametrize("method", method_names())
def test_detect_json_of_every_method_validates(runner, recording, tmp_path, method) -> None:
    schema = json.loads(schema_path().read_text())
    res = runner.invoke(main, ["detect", str(recording), "-o", str(tmp_path / method), "--method", method, "--json",
                               "--set", *ODOMETRY])
    assert res.exit_code == 0, res.output + res.stderr
    out = json.loads(res.stdout)
    errors = [f"{list(e.absolute_path)}: {e.message}" for e in jsonschema.Draft202012Validator(schema).iter_errors(out)]
    assert errors == [] and out["method"] == method


# ----------------------------------------------------------------------------- a method is one file + one line
@dataclass(eq=False)
class Steepness:
    """A tiny method, as a new method's file would hold it: the steepness map alone is the score; it sees every
    tracked frame (a method may keep state across frames: here, which frames it saw)."""

    params: SelectParams
    seen: list[int] = field(default_factory=list)
    name: str = "steepness"
    reads_maps: bool = True
    selects: str = "the least normal variance, as fuzzy"

    def observe(self, tracked: TrackedFrame) -> None:
        self.seen.append(tracked.frame.index)

    def detect(self, tracked: TrackedFrame, maps: TerrainMaps, maps_ms: float) -> Detection:
        frame, T, points = tracked.frame, tracked.T_world_camera, tracked.points
        score = maps.steepness
        mask = score > 0.5
        selection = None if T is None or points is None else select_site(points.xyz_world, T, frame.K, mask, score,
                                                                          self.params)
        return Detection(frame, T, maps, ScoreMap(self.name, score, mask), points, selection, maps.edge_distance_m,
                         {"maps": maps_ms, "score": 0.0, "mask": 0.0, "select": 0.0}, tracked.segment)


def test_a_method_is_one_file_and_one_registry_line(runner, recording, tmp_path, monkeypatch) -> None:
    built: list[Steepness] = []

    def steepness(config: Config) -> Steepness:  # the new file's builder
        built.append(Steepness(fuzzy(config).params))
        return built[-1]

    monkeypatch.setitem(registry.METHODS, "steepness", registry.Entry(steepness, "the steepness map alone"))  # the line
    res = runner.invoke(main, ["detect", str(recording), "-o", str(tmp_path / "run"), "--json",
                               "--set", "scoring.method=steepness", "--set", *ODOMETRY])
    assert res.exit_code == 0, res.output + res.stderr
    out = json.loads(res.stdout)
    assert out["method"] == "steepness" and out["detections"] > 0
    assert built[-1].seen == list(range(FRAMES))  # every tracked frame, due or not
    landing = json.loads((tmp_path / "run" / "landing.json").read_text())
    api = slzcli.detect(recording, load_config(None, ODOMETRY), method="steepness").landing
    assert _without_timings(api) == _without_timings(landing) and landing["method"] == "steepness"
    res = runner.invoke(main, ["compare", str(recording), "-o", str(tmp_path / "cmp"), "--methods",
                               "fuzzy,steepness", "--set", *ODOMETRY])
    assert res.exit_code == 0, res.output + res.stderr
    # without the line, the config check names the known methods
    monkeypatch.delitem(registry.METHODS, "steepness")
    res = runner.invoke(main, ["detect", str(recording), "-o", str(tmp_path / "r2"),
                               "--set", "scoring.method=steepness"])
    assert res.exit_code == 1 and "scoring.method" in res.stderr and "fuzzy" in res.stderr


def test_every_registered_method_is_in_the_schema_enum() -> None:
    schema = json.loads(schema_path().read_text())
    assert schema["$defs"]["detect"]["properties"]["method"]["enum"] == list(method_names())
