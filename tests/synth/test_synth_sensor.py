"""slz synth sensor models: ideal, gaussian and the stereo model of a D4xx (infrared pair + SGBM).

Stereo runs use the 424x240 infrared mode of a D4xx (the smallest 16:9 depth mode, f = 213 px)
and a 320x240 colour camera, so each frame costs well under a second. Every limit below was
measured over seeds 0, 1, 2 (three hover positions and three noise draws); the measured values
and the margin are written beside each assert.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_synth import SMALL, TINY, down_pose, write_scene

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.synth import record
from slzcli.synth.scenes import load_scene
from slzcli.synth.sensor import get_depth_sensor
from slzcli.synth.stereo import make_rig, register_to_color
from slzcli.types import Intrinsics

IR_424 = ["synth.sensor.stereo.ir_width_px=424", "synth.sensor.stereo.ir_height_px=240"]
COARSE_TRUTH = ["synth.ground_truth.raster_m=0.5"]        # the raster is not under test: keep the build cheap
STEREO = SMALL + IR_424 + COARSE_TRUTH + ["synth.sensor.model=stereo"]
PLANE = """
description: "a level plane"
ground: {{size_m: [30, 30], material: {material}}}
materials:
  plain_grey: {{color: [0.5, 0.5, 0.5], texture: plain}}
objects: []
"""
BORDER_PX = 40      # colour pixels left out at each side (the infrared view is wider; keeps the stats central)
SEEDS = (0, 1, 2)


def plane_world(folder: Path, material: str, variants: tuple[str, ...] = ()) -> record.World:
    path = write_scene(folder, material, PLANE.format(material=material))
    return record.build_world(load_scene(path, variants), load_config(overrides=STEREO))


def plane_stats(world: record.World, z: float, seed: int, extra: tuple[str, ...] = ()) -> tuple[float, float, float]:
    """(hole fraction, median error m, MAD sigma m) of the stereo depth of a level plane at height z."""
    cfg = load_config(overrides=STEREO + list(extra))
    sensor = get_depth_sensor(cfg.synth.sensor, world.renderer, world.intrinsics)
    T = down_pose(0.37 * seed, -0.23 * seed, z)
    exact = world.renderer.render(T, world.intrinsics).depth_m
    err = (sensor.measure(exact, T, np.random.default_rng(seed)) - exact)[BORDER_PX:-BORDER_PX, BORDER_PX:-BORDER_PX]
    ok = np.isfinite(err)
    e = err[ok]
    if len(e) == 0:
        return 1.0, float("nan"), float("nan")
    med = float(np.median(e))
    return 1.0 - float(ok.mean()), med, 1.4826 * float(np.median(np.abs(e - med)))


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("sensor_scenes")


@pytest.fixture(scope="module")
def asphalt(scenes_dir: Path) -> record.World:
    return plane_world(scenes_dir, "asphalt")


@pytest.fixture(scope="module")
def asphalt_stats(asphalt: record.World) -> dict[float, list[tuple[float, float, float]]]:
    return {z: [plane_stats(asphalt, z, s) for s in SEEDS] for z in (2.0, 4.0, 6.0)}


# ----------------------------------------------------------------------------- ideal and gaussian
def test_ideal_model_is_exact_within_the_range_limits() -> None:
    cfg = load_config(overrides=["synth.sensor.model=ideal"]).synth.sensor
    sensor = get_depth_sensor(cfg, None, None)  # type: ignore[arg-type]   # ideal needs no renderer
    z = np.linspace(0.0, 30.0, 300, dtype=np.float32).reshape(10, 30)
    out = sensor.measure(z, np.eye(4), np.random.default_rng(0))
    inside = (z >= cfg.min_range_m) & (z <= cfg.max_range_m)
    assert np.array_equal(out[inside], z[inside])
    assert np.isnan(out[~inside]).all() and (~inside).any()


@pytest.mark.parametrize("a", [0.0005, 0.0015, 0.003])
def test_gaussian_model_has_the_configured_sigma(a: float) -> None:
    cfg = load_config(overrides=["synth.sensor.model=gaussian", f"synth.sensor.depth_sigma_a={a}"]).synth.sensor
    sensor = get_depth_sensor(cfg, None, None)  # type: ignore[arg-type]
    z = np.full((300, 300), 5.0, np.float32)
    out = sensor.measure(z, np.eye(4), np.random.default_rng(1))
    # 90,000 samples: the std of the std is 0.24 %; 3 % leaves room for the float32 rounding at small a
    assert np.nanstd(out - z) == pytest.approx(a * 25.0, rel=0.03)


# ----------------------------------------------------------------------------- stereo: physics
def test_stereo_sigma_grows_with_z_squared(asphalt_stats: dict[float, list[tuple[float, float, float]]]) -> None:
    rig = make_rig(load_config(overrides=STEREO).synth.sensor)
    for s in range(len(SEEDS)):
        sigma = {z: asphalt_stats[z][s][2] for z in asphalt_stats}
        k = [sigma[z] / z ** 2 for z in sigma]
        # sigma / z^2 measured 6.4e-3, 6.5e-3, 7.2e-3 /m (all seeds within 2 %): spread 1.13; linear growth gives 3
        assert max(k) / min(k) < 1.5, sigma
        # sigma(6) / sigma(2) measured 10.0-10.2 (z^2 predicts 9, linear 3)
        assert 6.0 < sigma[6.0] / sigma[2.0] < 14.0, sigma
        # Intel's RMS = z^2 x 0.08 px / (f B) at this mode: 7.5e-3 /m; measured 0.86-0.96 of it; allowed 0.5-2
        intel = 0.08 / rig.focal_baseline_px_m
        assert all(0.5 < kk / intel < 2.0 for kk in k), (k, intel)


Stats = dict[float, list[tuple[float, float, float]]]


def test_stereo_bias_small_and_few_holes_on_texture(asphalt_stats: Stats) -> None:
    for z, rows in asphalt_stats.items():
        for holes, bias, _ in rows:
            assert abs(bias) < 0.02 * z, (z, bias)     # measured <= 0.6 % of z; the D435 datasheet allows 2 %
            assert holes < 0.05, (z, holes)            # measured 0.6-0.8 %


def test_plain_ground_has_more_holes_than_textured_emitter_off(scenes_dir: Path, asphalt: record.World) -> None:
    off = ("synth.sensor.stereo.emitter=false",)
    plain = plane_world(scenes_dir, "plain_grey")
    holes_plain = plane_stats(plain, 4.0, 0, off)[0]
    holes_textured = plane_stats(asphalt, 4.0, 0, off)[0]
    # measured plain 0.91-0.97 (the few matches left are noise), textured 0.006-0.008 over seeds 0-2
    assert holes_plain > 0.5 and holes_textured < 0.05, (holes_plain, holes_textured)


def test_emitter_dots_give_depth_on_plain_ground_in_dim_light(scenes_dir: Path) -> None:
    plain = plane_world(scenes_dir, "plain_grey")
    dim = ("synth.sensor.stereo.sun_irradiance_w_m2=2.0",)      # an indoor light level: the dots outshine it
    on = plane_stats(plain, 2.0, 0, dim)[0]
    off = plane_stats(plain, 2.0, 0, (*dim, "synth.sensor.stereo.emitter=false"))[0]
    # measured on 0.018-0.019, off 0.91-0.97 over seeds 0-2; in full sun (680 W/m^2) the dots are washed out
    assert on < 0.2 and off > 0.5, (on, off)


def test_low_light_gives_more_noise(scenes_dir: Path, asphalt_stats: dict[float, list[tuple[float, float, float]]]
                                    ) -> None:
    dark = plane_world(scenes_dir, "asphalt", ("low_light",))
    sigma_dark = plane_stats(dark, 2.0, 0)[2]
    sigma_lit = asphalt_stats[2.0][0][2]
    # measured ratio 1.26-1.28 at 2 m over seeds 0-2 (half the light: shot-noise SNR / sqrt 2)
    assert sigma_dark > 1.1 * sigma_lit, (sigma_dark, sigma_lit)


def test_d455_less_noisy_than_d435(asphalt: record.World,
                                   asphalt_stats: dict[float, list[tuple[float, float, float]]]) -> None:
    sigma_455 = plane_stats(asphalt, 4.0, 0, ("synth.sensor.preset=d455",))[2]
    sigma_435 = asphalt_stats[4.0][0][2]
    # measured 0.45 x at 4 m over seeds 0-2 (baselines 50 / 95 mm predict 0.53)
    assert sigma_455 < 0.75 * sigma_435, (sigma_455, sigma_435)


def test_stereo_is_deterministic(asphalt: record.World) -> None:
    cfg = load_config(overrides=STEREO)
    sensor = get_depth_sensor(cfg.synth.sensor, asphalt.renderer, asphalt.intrinsics)
    T = down_pose(0.1, 0.2, 3.0)
    exact = asphalt.renderer.render(T, asphalt.intrinsics).depth_m
    a, b, c = (sensor.measure(exact, T, np.random.default_rng(s)) for s in (5, 5, 6))
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(a, c, equal_nan=True)


# ----------------------------------------------------------------------------- stereo: registration
def test_registration_nearest_surface_wins_and_disocclusion_stays_a_hole() -> None:
    """A near square (1 m) before a far plane (4 m), seen from a colour camera 5 cm to the left."""
    cam = Intrinsics(100.0, 100.0, 99.5, 49.5, 200, 100)
    depth = np.full((100, 200), 4.0, np.float32)
    depth[30:70, 80:120] = 1.0
    T_color_ir = np.eye(4)
    T_color_ir[0, 3] = 0.05                        # the infrared camera sits 5 cm right of the colour camera
    out = register_to_color(depth, cam, cam, T_color_ir)
    near_shift, far_shift = 100 * 0.05 / 1.0, 100 * 0.05 / 4.0   # 5 px and 1.25 px to the right
    rows = slice(35, 65)
    assert np.all(out[rows, 86:124] == 1.0)          # the square, shifted 5 px: nothing behind it shows through
    gap = out[rows, int(np.ceil(80 + far_shift)):int(np.floor(80 + near_shift))]
    assert gap.size and np.isnan(gap).all()          # the far plane hidden from the infrared camera: a hole
    assert np.all(out[rows, 130:190] == 4.0) and np.all(out[rows, 10:70] == 4.0)


def test_registration_leaves_nan_where_no_infrared_pixel_lands() -> None:
    ir = Intrinsics(50.0, 50.0, 24.5, 24.5, 50, 50)
    color = Intrinsics(100.0, 100.0, 49.5, 49.5, 100, 100)    # twice as fine: every colour pixel still gets one
    out = register_to_color(np.full((50, 50), 2.0, np.float32), ir, color, np.eye(4))
    assert np.all(out == 2.0)
    holes = np.full((50, 50), 2.0, np.float32)
    holes[20:30, 20:30] = np.nan
    out = register_to_color(holes, ir, color, np.eye(4))
    assert np.isnan(out[45:55, 45:55]).all() and np.isfinite(out[:30]).all()


# ----------------------------------------------------------------------------- the recording and the CLI
def test_cli_synth_with_stereo_model(tmp_path: Path) -> None:
    out = tmp_path / "s.mcap"
    sets = [a for kv in TINY + IR_424 + COARSE_TRUTH + ["synth.sensor.model=stereo"] for a in ("--set", kv)]
    res = CliRunner().invoke(main, ["synth", "clear_field", "-o", str(out), "--frames", "1", *sets])
    assert res.exit_code == 0, res.output
    header = json.loads(Path(str(out) + ".gt.json").read_text())
    assert header["sensor"]["model"] == "stereo" and header["sensor"]["presets"]["d435"]["baseline_m"] == 0.05
    from slzcli.sources import open_recording
    with open_recording(out, load_config(overrides=TINY)) as rec:
        frame = next(iter(rec.frames()))
    valid = np.isfinite(frame.depth_m)
    assert 0.8 < valid.mean() < 1.0                 # measured 0.994-0.995 over seeds 0-2 (grass at 10 m)
    assert abs(float(np.median(frame.depth_m[valid])) - 10.0) < 0.3     # measured 9.86 m (hover wobble, bumps)


@pytest.mark.parametrize("key, value", [("synth.sensor.model", "lidar"), ("synth.sensor.preset", "d415"),
                                        ("synth.sensor.stereo.sgbm.block_px", "4")])
def test_cli_rejects_bad_sensor_settings(tmp_path: Path, key: str, value: str) -> None:
    res = CliRunner().invoke(main, ["synth", "clear_field", "-o", str(tmp_path / "x.mcap"), "--set", f"{key}={value}"])
    assert res.exit_code == 1 and key in res.output and "Traceback" not in res.output
    assert not list(tmp_path.iterdir())
