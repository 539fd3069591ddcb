"""Config: layering, validation with dotted key paths, and the commented dump."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from slzcli.cli import main
from slzcli.config import DEFAULT_CONFIG, dump, load_config
from slzcli.errors import ConfigError


def test_defaults_load_and_hold_paper_values() -> None:
    cfg = load_config()
    assert cfg.camera.fx == pytest.approx(462.137)  # paper Table 1
    assert (cfg.terrain.flatness.canny_low, cfg.terrain.flatness.canny_high) == (50, 220)  # Table 3
    assert cfg.terrain.depth_variance.kernel_px == 3
    assert cfg.terrain.inclination.radius_m == 0.5
    assert cfg.control.K_i == (0.1, 0.1, 0.001)
    assert cfg.uav.footprint_m == (0.656, 0.656)


def test_default_yaml_is_parsed_once_per_content_and_never_shared(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from slzcli.config import loader

    copy = tmp_path / "default.yaml"
    copy.write_text(DEFAULT_CONFIG.read_text())
    monkeypatch.setattr(loader, "DEFAULT_CONFIG", copy)
    first = loader._defaults()
    first["mask"]["threshold"] = 0.9  # type: ignore[index]  # a caller changing its copy changes no other
    hits = loader._parsed_defaults.cache_info().hits
    assert load_config().mask.threshold == 0.5 == load_config().mask.threshold
    assert loader._parsed_defaults.cache_info().hits == hits + 2   # parsed once
    copy.write_text(DEFAULT_CONFIG.read_text().replace("\n  threshold: 0.5 ", "\n  threshold: 0.6 ", 1))
    assert load_config().mask.threshold == 0.6   # an edited file is read again


def test_every_leaf_of_default_yaml_has_unit_and_source_comment() -> None:
    for line in DEFAULT_CONFIG.read_text().splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#") or stripped.endswith(":"):
            continue
        assert "#" in stripped, f"default.yaml leaf without a unit/source comment: {line!r}"


def test_file_then_set_layering(tmp_path: Path) -> None:
    f = tmp_path / "mine.yaml"
    f.write_text("mask:\n  threshold: 0.7\nterrain:\n  flatness:\n    canny_low: 40\n")
    cfg = load_config(f, ["mask.threshold=0.8"])
    assert cfg.mask.threshold == 0.8  # --set wins over the file
    assert cfg.terrain.flatness.canny_low == 40  # the file wins over the defaults
    assert cfg.terrain.flatness.canny_high == 220  # untouched keys keep the default


@pytest.mark.parametrize(
    ("override", "key", "words"),
    [
        ("terrain.flatnes.canny_low=3", "terrain.flatnes", "did you mean 'flatness'"),
        ("terrain.flatness.canny_lo=3", "terrain.flatness.canny_lo", "did you mean 'canny_low'"),
        ("mask.threshold=abc", "mask.threshold", "expected a number"),
        ("mask.threshold=1.5", "mask.threshold", "<= 1"),
        ("terrain.depth_variance.kernel_px=4", "terrain.depth_variance.kernel_px", "odd"),
        ("terrain.depth_variance.kernel_px=3.5", "terrain.depth_variance.kernel_px", "integer"),
        ("uav.footprint_m=[1, 2, 3]", "uav.footprint_m", "expected 2 values"),
        ("scoring.method=fuzz", "scoring.method", "did you mean 'fuzzy'"),
        ("sources.use_ground_truth_pose=1", "sources.use_ground_truth_pose", "true or false"),
        ("camera.fx=0", "camera.fx", "> 0"),
        ("mask=3", "mask", "expected a section"),
    ],
)
def test_bad_values_name_the_key(override: str, key: str, words: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(overrides=[override])
    assert info.value.key == key
    assert words in str(info.value)


def test_unknown_key_in_file_names_file_and_path(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text("landing:\n  kmeans_kk: 3\n")
    with pytest.raises(ConfigError) as info:
        load_config(f)
    assert info.value.key == "landing.kmeans_kk"
    assert str(f) in str(info.value) and "kmeans_k" in str(info.value)


def test_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("mask: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_config(bad)


def test_dump_round_trips_and_keeps_comments() -> None:
    cfg = load_config(overrides=["mask.threshold=0.65", "sources.topics.color=/cam/rgb"])
    text = dump(cfg)
    assert yaml.safe_load(text) == cfg.to_dict()
    assert "threshold: 0.65" in text and "# " in text.split("threshold: 0.65")[1].splitlines()[0]


def test_hash_changes_with_values() -> None:
    assert load_config().hash() == load_config().hash()
    assert load_config().hash() != load_config(overrides=["mask.threshold=0.6"]).hash()


def test_cli_config_dump(runner) -> None:
    res = runner.invoke(main, ["config", "dump", "--set", "mask.threshold=0.6"])
    assert res.exit_code == 0, res.output
    assert yaml.safe_load(res.output)["mask"]["threshold"] == 0.6
    res = runner.invoke(main, ["config", "dump", "--json"])
    assert json.loads(res.output)["camera"]["fx"] == pytest.approx(462.137)


def test_cli_bad_config_is_one_line_exit_1(runner, tmp_path: Path) -> None:
    res = runner.invoke(main, ["config", "dump", "--set", "terrain.flatness.canny_lo=1"])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "terrain.flatness.canny_lo" in lines[0] and "Traceback" not in res.output
    res = runner.invoke(main, ["config", "dump", "--config", str(tmp_path / "missing.yaml")])
    assert res.exit_code == 1 and "missing.yaml" in res.stderr
    res = runner.invoke(main, ["config", "dump", "--set", "novalue"])
    assert res.exit_code == 2 and "KEY=VALUE" in res.stderr  # not KEY=VALUE: a usage error


@pytest.mark.parametrize("old", ["terrain.steepness.slope_limit_deg", "landing.max_tilt_deg"])
def test_removed_slope_keys_name_their_replacement(runner, tmp_path: Path, old: str) -> None:
    res = runner.invoke(main, ["config", "dump", "--set", f"{old}=10"])
    assert res.exit_code == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and old in lines[0] and "uav.max_slope_deg" in lines[0], res.stderr
    section, _, leaf = old.rpartition(".")
    user = tmp_path / "old.yaml"
    user.write_text(yaml.safe_dump(_nest_plain(section.split("."), {leaf: 10.0})))
    res = runner.invoke(main, ["config", "dump", "--config", str(user)])
    assert res.exit_code == 1 and "old.yaml" in res.stderr and "uav.max_slope_deg" in res.stderr


def _nest_plain(parts: list[str], leaf: dict) -> dict:
    return {parts[0]: _nest_plain(parts[1:], leaf)} if parts else leaf


def test_one_slope_limit_reaches_the_steepness_map_and_the_tilt_test() -> None:
    """uav.max_slope_deg is psi_ref of Eq. 9 and the site acceptance test's tilt limit."""
    from slzcli.methods.maps import bayes, fuzzy
    from slzcli.terrain.maps import steepness_map

    cfg = load_config(overrides=["uav.max_slope_deg=10"])
    psi = np.radians(np.array([[10.0]], np.float32))
    assert float(steepness_map(psi, cfg.terrain.steepness, cfg.uav.max_slope_deg)[0, 0]) == pytest.approx(
        np.exp(-1.0), rel=1e-6)
    assert fuzzy(cfg).params.max_tilt_deg == bayes(cfg).params.max_tilt_deg == 10.0


@pytest.mark.parametrize(
    ("overrides", "key", "words"),
    [
        (["terrain.flatness.canny_low=230"], "terrain.flatness.canny_low", "<= terrain.flatness.canny_high"),
        (["terrain.steepness.normal_px=31", "terrain.steepness.normal_max_px=29"], "terrain.steepness.normal_px",
         "<= terrain.steepness.normal_max_px"),
        (["uav.thrust_min_n=7.0", "uav.thrust_max_n=6.0"], "uav.thrust_min_n", "< uav.thrust_max_n"),
        (["uav.thrust_max_n=3.0"], "uav.thrust_max_n", "must exceed the weight"),
        (["uav.thrust_min_n=5.0"], "uav.thrust_min_n", "must be below the weight"),
        (["synth.sensor.min_range_m=30.0"], "synth.sensor.min_range_m", "< synth.sensor.max_range_m"),
        (["slam.odometry.min_depth_m=25.0"], "slam.odometry.min_depth_m", "< slam.odometry.max_depth_m"),
        (["slam.orb.fast_min_threshold=30"], "slam.orb.fast_min_threshold", "<= slam.orb.fast_threshold"),
        (["camera.cx=700.0"], "camera.cx", "<= camera.width"),
        (["camera.fx=1000000000.0"], "camera", "field of view"),
        (["sources.intrinsics.min_fov_deg=100.0", "sources.intrinsics.max_fov_deg=90.0"],
         "sources.intrinsics.min_fov_deg", "< sources.intrinsics.max_fov_deg"),
        (["landing.seed=4294967296"], "landing.seed", "<= 4294967295"),  # scipy's kmeans2 refused it, deep inside
    ],
)
def test_contradictory_values_name_both_keys(overrides: list[str], key: str, words: str) -> None:
    """Each value is in its range; together they cannot work (canny_low > canny_high used to be accepted)."""
    with pytest.raises(ConfigError) as info:
        load_config(overrides=overrides)
    assert info.value.key == key
    assert words in str(info.value)


def test_a_utf16_config_with_a_byte_order_mark_is_read(tmp_path: Path) -> None:
    f = tmp_path / "utf16.yaml"
    f.write_bytes("mask:\n  threshold: 0.6\n".encode("utf-16"))  # with BOM, as Windows editors save it
    assert load_config(f).mask.threshold == 0.6


def test_a_deep_set_value_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="nested too deeply"):
        load_config(overrides=["mask.threshold=" + "[" * 20000 + "]" * 20000])


def test_errors_survive_a_process_pool() -> None:
    """A worker's error is pickled to the parent: a custom __init__ without __reduce__ failed there."""
    import pickle

    from slzcli.errors import DatasetError, OutputError, StageTimeout

    for err in (ConfigError("a.b", "bad", "f.yaml"), DatasetError("x.mcap", "cut"), OutputError("run", "full"),
                StageTimeout("x.mcap", "SLAM on frame 3", 2.0)):
        back = pickle.loads(pickle.dumps(err))
        assert type(back) is type(err) and str(back) == str(err)


@pytest.mark.parametrize(("item", "cause"), [
    # found by tests/top/test_properties.py: --set uav.mass_kg=1 was refused naming uav.thrust_max_n
    ("uav.mass_kg=1", "uav.mass_kg: makes the weight uav.mass_kg x control.gravity_m_s2 = 9.81 N, which "
                      "uav.thrust_max_n = 7.8 must exceed (it could not hover)"),
    ("control.gravity_m_s2=30", "control.gravity_m_s2: makes the weight"),
    ("uav.thrust_max_n=0.1", "uav.thrust_max_n: must be > uav.thrust_min_n (the thrust range); got 0.1 and 0.4"),
    ("uav.thrust_min_n=10", "uav.thrust_min_n: must be < uav.thrust_max_n (the thrust range); got 10 and 7.8"),
    ("terrain.steepness.normal_max_px=3", "terrain.steepness.normal_max_px: must be >= terrain.steepness.normal_px"),
])
def test_a_contradiction_is_named_by_the_key_the_user_set(item: str, cause: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, [item])
    assert info.value.key == item.partition("=")[0]
    assert cause in str(info.value)
