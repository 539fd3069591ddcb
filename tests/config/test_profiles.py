"""Profiles (issue 22): the layer order, the paper profile's sources, its pieces, and its runs end to end."""

from __future__ import annotations

import importlib.util
import json
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import REPO, synth_recording

from slzcli.cli import main
from slzcli.config import PROFILE_DIR, _leaf_comments, _leaves, load_config, profile_names, read_yaml_mapping
from slzcli.errors import ConfigError
from slzcli.slam.orbslam3 import available as orbslam3_available
from slzcli.slam.orbslam3 import monocular_scale

needs_orbslam3 = pytest.mark.skipif(not orbslam3_available(),
                                    reason="optional pyorbslam3 (slz[orbslam3]) not installed")
PAPER = PROFILE_DIR / "paper.yaml"


def _ablation() -> Any:
    if str(REPO / "benchmarks") not in sys.path:   # a benchmark imports its harness from its own folder
        sys.path.insert(0, str(REPO / "benchmarks"))
    spec = importlib.util.spec_from_file_location("ablation", REPO / "benchmarks" / "ablation.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _diff(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k in a:
        if isinstance(a[k], dict):
            out += _diff(a[k], b[k], f"{prefix}{k}.")
        elif a[k] != b[k]:
            out.append(f"{prefix}{k}")
    return out


# ----------------------------------------------------------------------------- layering
def test_layers_apply_in_the_documented_order(tmp_path: Path) -> None:
    key = "terrain.depth_variance.normalise"
    assert load_config().terrain.depth_variance.normalise == "absolute"                  # default.yaml
    assert load_config(profile="paper").terrain.depth_variance.normalise == "frame"      # <- profile
    user = tmp_path / "mine.yaml"
    user.write_text("terrain:\n  depth_variance:\n    normalise: absolute\nmask:\n  threshold: 0.7\n")
    cfg = load_config(user, profile="paper")                                             # <- --config
    assert cfg.terrain.depth_variance.normalise == "absolute" and cfg.mask.threshold == 0.7
    assert cfg.terrain.flatness.normalise == "frame"          # the profile's other keys stay
    assert cfg.slam.orbslam3.sensor == "monocular"
    cfg = load_config(user, [f"{key}=frame", "mask.threshold=0.4"], profile="paper")     # <- --set
    assert cfg.terrain.depth_variance.normalise == "frame" and cfg.mask.threshold == 0.4
    assert load_config(profile="default") == load_config()    # "default" is no layer at all


def test_unknown_profile_is_refused_naming_the_known_ones(runner: Any) -> None:
    assert profile_names() == ["default", "bench", "paper"]
    with pytest.raises(ConfigError, match=r"did you mean 'paper'.*known: default, bench, paper"):
        load_config(profile="papr")
    res = runner.invoke(main, ["config", "dump", "--profile", "papr"])
    assert res.exit_code == 1 and res.output.count("\n") == 1 and "--profile" in res.output


def test_a_profile_key_unknown_to_the_defaults_names_the_profile_file(tmp_path: Path, monkeypatch: Any) -> None:
    (tmp_path / "bad.yaml").write_text("mask:\n  treshold: 0.5\n")
    monkeypatch.setattr("slzcli.config.loader.PROFILE_DIR", tmp_path)
    with pytest.raises(ConfigError, match=r"bad\.yaml.*mask\.treshold.*did you mean 'threshold'"):
        load_config(profile="bad")


def test_the_paper_profile_gives_a_source_beside_every_value() -> None:
    comments = _leaf_comments(PAPER.read_text())
    leaves = _leaves(read_yaml_mapping(PAPER))
    assert len(leaves) >= 25
    missing = [k for k in leaves if not comments.get(k)]
    assert not missing, missing
    unsourced = [k for k in leaves if not any(w in comments[k] for w in ("paper", "METHOD"))]
    assert not unsourced, unsourced


def test_paper_plus_every_ablation_decision_is_the_default_config() -> None:
    """The ablation's decisions are exactly where slz departs from the paper profile: all on = default."""
    abl = _ablation()
    items = [i for d in abl.DECISIONS.values() for i in d]
    assert _diff(load_config(None, items, "paper").to_dict(), load_config().to_dict()) == []
    for name, one in abl.DECISIONS.items():   # each decision changes something
        assert _diff(load_config(None, one, "paper").to_dict(), load_config(profile="paper").to_dict()), name


# ----------------------------------------------------------------------------- config dump
def test_config_dump_shows_each_layer_as_the_source(runner: Any, tmp_path: Path) -> None:
    user = tmp_path / "mine.yaml"
    user.write_text("mask:\n  smooth_m: 0.2          # m; my field tests\n")
    res = runner.invoke(main, ["config", "dump", "--profile", "paper", "--config", str(user),
                               "--set", "landing.kmeans_k=7"])
    assert res.exit_code == 0, res.output
    lines = {ln.split(":")[0].strip(): ln for ln in res.output.splitlines() if ":" in ln}
    assert "# profile paper: paper Eq. 5" in next(ln for ln in res.output.splitlines() if "normalise: frame" in ln)
    assert "sensor: monocular" in res.output and "# profile paper: paper sec. 2.2" in res.output
    assert f"# --config {user}: m; my field tests" in lines["smooth_m"]
    assert "kmeans_k: 7" in lines["kmeans_k"] and "# --set" in lines["kmeans_k"]
    assert "# m; paper T3" in lines["radius_m"] or "profile paper" in lines["radius_m"]
    # a key no layer sets keeps default.yaml's comment
    assert "# px; paper T1" in lines["fx"]
    as_json = json.loads(runner.invoke(main, ["config", "dump", "--profile", "paper", "--json"]).output)
    assert as_json["slam"]["orbslam3"]["sensor"] == "monocular"


# ----------------------------------------------------------------------------- the paper's pieces
def test_monocular_scale_is_measured_depth_over_map_depth() -> None:
    rng = np.random.default_rng(0)
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    true = rng.uniform([-2, -1.5, 4], [2, 1.5, 6], (200, 3))      # points in a camera at the origin
    depth = np.full((240, 320), np.nan, np.float32)
    u = np.rint(400 * true[:, 0] / true[:, 2] + 160).astype(int)
    v = np.rint(400 * true[:, 1] / true[:, 2] + 120).astype(int)
    ok = (u >= 0) & (u < 320) & (v >= 0) & (v < 240)
    depth[v[ok], u[ok]] = true[ok, 2]
    T = np.eye(4)
    T[:3, 3] = [0.3, -0.2, 0.1]                                    # a map in units of 1/2.5 m, camera moved
    scale = monocular_scale(T, true / 2.5 + T[:3, 3], depth, K, 20)
    assert scale == pytest.approx(2.5, rel=1e-3)
    assert monocular_scale(T, true[:10] / 2.5, depth, K, 20) is None              # too few points
    assert monocular_scale(T, true / 2.5, np.full_like(depth, np.nan), K, 20) is None  # no depth


def test_the_paper_depth_variance_keeps_a_ramp_the_plane_fit_removes() -> None:
    from slzcli.config import DepthVarianceCfg
    from slzcli.terrain.maps import depth_variance_map

    cfg = load_config().terrain.depth_variance
    yy = np.arange(120, dtype=np.float32)[:, None] * np.ones((1, 160), np.float32)
    ramp = 5.0 + 0.05 * yy                                           # 5 cm per pixel: a steep ramp
    plane = depth_variance_map(ramp, cfg)
    std = depth_variance_map(ramp, DepthVarianceCfg(**{**cfg.__dict__, "statistic": "std", "s0_m": 0.05}))
    inner = (slice(2, -2), slice(2, -2))
    assert plane[inner].min() > 0.99                   # a plane has no residual
    # Alg. 1's plain std of a 3x3 window on the ramp: 0.05 m x sqrt(2/3) = 0.041 m -> exp(-0.041/0.05) = 0.44
    assert std[inner] == pytest.approx(np.exp(-0.05 * np.sqrt(2 / 3) / 0.05), abs=1e-3)
    flat = depth_variance_map(np.full((40, 40), 5.0, np.float32),
                              DepthVarianceCfg(**{**cfg.__dict__, "statistic": "std"}))
    assert flat[2:-2, 2:-2].min() == pytest.approx(1.0)


def test_commit_latest_takes_the_last_detection_not_the_best_supported() -> None:
    from types import SimpleNamespace

    from slzcli.pipeline.commit import commit_site
    from slzcli.types import FoundSite

    def entry(i: int, x: float, accepted: bool) -> FoundSite:
        site = SimpleNamespace(center_world=(x, 0.0, 0.0), accepted=accepted, normal_variance=0.01, score=0.8,
                               edge_clearance_m=1.0)
        return FoundSite(SimpleNamespace(index=i), site, i, None, 0)  # type: ignore[arg-type]  # what commit reads

    sites = [entry(0, 0.0, True), entry(1, 0.1, True), entry(2, 5.0, False)]
    agreed = commit_site(sites, 1.0)
    assert agreed is not None and agreed.frame.index in (0, 1)      # two agree (and are accepted)
    latest = commit_site(sites, 1.0, "latest")
    assert latest is not None and latest.frame.index == 2 and latest.support == 1


# ----------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def hover(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default synth hover: 0.3 m drift over 12 s, so almost no parallax in 12 frames."""
    return synth_recording(tmp_path_factory.mktemp("hover") / "hover.mcap", "clear_field", 12,
                           "--set", "synth.sensor.model=ideal", "--start", "0,0,5")


@needs_orbslam3
def test_the_paper_profile_on_a_hover_says_monocular_slam_did_not_initialise(runner: Any, hover: Path,
                                                                              tmp_path: Path, caplog: Any) -> None:
    with caplog.at_level(logging.WARNING):
        res = runner.invoke(main, ["detect", str(hover), "-o", str(tmp_path / "run"), "--profile", "paper",
                                   "--set", "slam.orbslam3.init_warn_frames=10", "--outputs", "summary"])
    assert res.exit_code == 0, res.output
    said = res.output + caplog.text
    assert "monocular ORB-SLAM3 has not initialised after 10 frames" in said
    assert "slam.orbslam3.sensor=rgbd" in said
    landing = json.loads((tmp_path / "run" / "landing.json").read_text())
    assert landing["status"] == "no_safe_site"
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["config"]["slam"]["orbslam3"]["sensor"] == "monocular"


@needs_orbslam3
def test_compare_profiles_runs_the_paper_and_the_default_on_the_same_frames(runner: Any, hover: Path,
                                                                             tmp_path: Path) -> None:
    res = runner.invoke(main, ["compare", str(hover), "--profiles", "paper,default", "-o", str(tmp_path / "cmp"),
                               "--json"])
    assert res.exit_code == 0, res.output
    rows = {r["profile"]: r for r in json.loads(res.stdout)["rows"]}   # stderr: the monocular warning
    paper, default = rows["paper"], rows["default"]
    assert "monocular ORB-SLAM3 never initialised (12 frames" in res.stderr
    assert paper["frames"] == default["frames"] == 12
    assert paper["slam_backend"] == "orbslam3" and default["slam_backend"] == "orbslam3"
    # monocular: no map on a hover, so no keyframe and no detection; said as a reason, not a crash
    assert paper["tracking"] == {"initialising": 12} and paper["detections"] == 0
    assert paper["status"] == "no_safe_site" and "no keyframe" in paper["reason"]
    # RGB-D: a map from the first frame, detections, and an ATE against the true poses
    assert default["detections"] >= 1 and default["ate_rmse_m"] is not None
    assert default["precision"] is not None and paper["ate_rmse_m"] is None
    saved = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert saved["profiles"] == ["paper", "default"]
    assert saved["configs"]["paper"]["slam"]["orbslam3"]["sensor"] == "monocular"
    assert (tmp_path / "cmp" / "compare.csv").read_text().count("\n") == 3


def test_compare_profiles_refuses_one_profile_and_two_methods(runner: Any, hover: Path, tmp_path: Path) -> None:
    res = runner.invoke(main, ["compare", str(hover), "--profiles", "paper", "-o", str(tmp_path / "c")])
    assert res.exit_code == 1 and "at least two different profiles" in res.output
    res = runner.invoke(main, ["compare", str(hover), "--profiles", "paper,default", "--methods", "fuzzy,bayes",
                               "-o", str(tmp_path / "c")])
    assert res.exit_code == 1 and "one method" in res.output
    res = runner.invoke(main, ["compare", str(hover), "--profiles", "paper,nope", "-o", str(tmp_path / "c")])
    assert res.exit_code == 1 and "unknown profile 'nope'" in res.output
    assert not (tmp_path / "c").exists()
