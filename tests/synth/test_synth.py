"""slz synth: scene loading, exact geometry, ground truth, sensor model, flights, determinism, writers, CLI."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.errors import SlzError
from slzcli.outputs.recording import FORMATS
from slzcli.sources import open_recording
from slzcli.synth import record
from slzcli.synth.flight import R_WORLD_CAMERA_DOWN, make_flight
from slzcli.synth.groundtruth import load_ground_truth, pixel_safe_mask
from slzcli.synth.scenes import SceneError, load_scene, scene_names
from slzcli.synth.sensor import apply_depth_model, depth_edges

SMALL = ["camera.width=320", "camera.height=240", "camera.cx=160.0", "camera.cy=120.0",
         "camera.fx=231.0685", "camera.fy=231.0685"]
TINY = ["camera.width=160", "camera.height=120", "camera.cx=80.0", "camera.cy=60.0",
        "camera.fx=115.534", "camera.fy=115.534", "synth.sensor.model=gaussian"]   # gaussian: quick to render
NOISE_OFF = ["synth.sensor.model=ideal", "synth.sensor.depth_sigma_a=0", "synth.sensor.edge_hole_prob=0",
             "synth.sensor.color_noise=0"]


def down_pose(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_WORLD_CAMERA_DOWN
    T[:3, 3] = (x, y, z)
    return T


def write_scene(folder: Path, name: str, body: str) -> Path:
    """A scene file beside a copy of the shared materials, so tests own their geometry."""
    folder.mkdir(parents=True, exist_ok=True)
    common = Path(record.__file__).resolve().parent.parent.parent / "datasets" / "scenes" / "_common.yaml"
    (folder / "_common.yaml").write_text(common.read_text())
    path = folder / f"{name}.yaml"
    path.write_text(textwrap.dedent(body))
    return path


BOX_SCENE = """
description: "one box"
ground: {size_m: [20, 20], material: concrete}
objects:
  - {name: crate, kind: box, at_m: [0.0, 0.0], size_m: [2.0, 2.0, 1.5], material: crate}
"""


@pytest.fixture(scope="module")
def small_config():
    return load_config(overrides=SMALL + NOISE_OFF)


@pytest.fixture(scope="module")
def parking_world(small_config):
    return record.build_world(load_scene("parking_lot"), small_config)


# ----------------------------------------------------------------------------- scenes
def test_library_has_the_required_scenes():
    assert {"parking_lot", "playground", "office", "slopes", "clear_field", "no_site"} <= set(scene_names())


def test_every_scene_loads_with_every_variant():
    for name in scene_names():
        scene = load_scene(name)
        assert scene.primitives and scene.description
        for variant in ("sand", "low_light"):
            assert variant in scene.available_variants
    sandy = load_scene("parking_lot:sand+low_light")
    assert sandy.ground.material == "sand" and sandy.illumination.gain < 1.0
    assert load_scene("parking_lot", ["hard"]).ground.material == "hard"
    assert (load_scene("parking_lot").scenario, load_scene("playground").scenario, load_scene("office").scenario) \
        == (1, 3, 4)


def test_unknown_scene_key_names_file_and_path(tmp_path):
    path = write_scene(tmp_path, "bad", BOX_SCENE.replace("size_m: [2.0, 2.0, 1.5]", "sise_m: [2.0, 2.0, 1.5]"))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert "bad.yaml" in str(err.value) and "objects[0].sise_m" in str(err.value) and "size_m" in str(err.value)


def test_unknown_variant_and_material_rejected(tmp_path):
    with pytest.raises(SceneError, match="unknown variant 'muddy'"):
        load_scene("parking_lot:muddy")
    path = write_scene(tmp_path, "badmat", BOX_SCENE.replace("material: crate", "material: unobtainium"))
    with pytest.raises(SceneError, match=r"objects\[0\].material"):
        load_scene(path)



def test_materials_that_are_not_a_mapping_are_refused_by_name(tmp_path):
    path = write_scene(tmp_path, "listmat", BOX_SCENE + "materials: [crate]\n")
    with pytest.raises(SceneError, match="materials: expected a mapping of names, got list") as err:
        load_scene(path)
    assert "listmat.yaml" in str(err.value)


# ----------------------------------------------------------------------------- geometry
def test_depth_under_a_box_is_camera_height_minus_box_height(tmp_path, small_config):
    world = record.build_world(load_scene(write_scene(tmp_path, "box", BOX_SCENE)), small_config)
    r = world.renderer.render(down_pose(0.0, 0.0, 10.0), world.intrinsics)
    cy, cx = 120, 160                               # principal point: the ray straight down
    assert r.depth_m[cy, cx] == pytest.approx(10.0 - 1.5, abs=1e-3)
    assert r.depth_m[5, 5] == pytest.approx(10.0, abs=1e-3)   # ground, z-depth (not ray length)
    rng = np.random.default_rng(0)
    noisy_off = apply_depth_model(r.depth_m, small_config.synth.sensor, rng)
    assert noisy_off[cy, cx] == pytest.approx(8.5, abs=1e-3)
    assert r.object_id[cy, cx] == 2 and r.object_id[5, 5] == 1


def test_ramp_normals_give_the_slope(small_config):
    world = record.build_world(load_scene("slopes"), small_config)
    r = world.renderer.render(down_pose(0.0, 0.0, 10.0), world.intrinsics)
    names = {o.name: o.id for o in world.meshes.objects}
    n = r.normal_world.reshape(-1, 3)
    ids = r.object_id.ravel()
    for angle in (5, 10, 15, 20, 30):
        sel = (ids == names[f"ramp_{angle:02d}deg"]) & (n[:, 2] > 0.5)   # the sloped top, not the sides
        assert sel.sum() > 500
        slope = np.degrees(np.arccos(n[sel, 2]))
        assert np.all(np.abs(slope - angle) < 0.5), angle


# ----------------------------------------------------------------------------- ground truth
def test_pixels_on_cars_are_unsafe_and_open_lane_is_safe(parking_world):
    r = parking_world.renderer.render(down_pose(0.0, 0.0, 10.0), parking_world.intrinsics)
    safe = pixel_safe_mask(parking_world.raster, r.point_world, r.hit)
    cars = [o.id for o in parking_world.meshes.objects if o.name.startswith(("car_", "pickup"))]
    on_car = np.isin(r.object_id, cars)
    assert on_car.sum() > 1000
    assert not safe[on_car].any()
    assert safe.any() and 0.3 < safe.mean() < 0.9
    # the driving lane at (0, 1) is open asphalt: safe
    assert parking_world.raster.safe_at(np.array([0.0]), np.array([1.0]))[0]


def test_footprint_and_margin_are_cleared_around_a_box(tmp_path, small_config):
    world = record.build_world(load_scene(write_scene(tmp_path, "box", BOX_SCENE)), small_config)
    half = 0.656 / 2 + small_config.uav.margin_m     # metres beyond the box face
    ys = np.zeros(3)
    xs = np.array([1.0 + half - 0.1, 1.0 + half + 0.1, 5.0])         # the box face is at x = 1
    assert world.raster.safe_at(xs, ys).tolist() == [False, True, True]
    assert not world.raster.safe_at(np.array([0.0]), np.array([0.0]))[0]   # box top: not landable


def test_touchdown_dispersion_adds_to_the_margin_around_a_box(tmp_path):
    """uav.touchdown_dispersion_m (slz land simulate's p95) widens the truth's clearance like the margin does."""
    config = load_config(overrides=[*SMALL, *NOISE_OFF, "uav.touchdown_dispersion_m=0.3"])
    world = record.build_world(load_scene(write_scene(tmp_path, "box", BOX_SCENE)), config)
    half = 0.656 / 2 + config.uav.margin_m + 0.3
    xs = np.array([1.0 + half - 0.1, 1.0 + half + 0.1])   # 0.1 m either side of the widened clearance
    assert world.raster.safe_at(xs, np.zeros(2)).tolist() == [False, True]


def test_clear_field_centre_is_safe(small_config):
    world = record.build_world(load_scene("clear_field"), small_config)
    r = world.renderer.render(down_pose(0.0, 0.0, 10.0), world.intrinsics)
    safe = pixel_safe_mask(world.raster, r.point_world, r.hit)
    assert safe[100:140, 130:190].all()


def test_no_site_has_no_safe_pixel(small_config):
    world = record.build_world(load_scene("no_site"), small_config)
    assert not world.raster.safe.any()
    r = world.renderer.render(down_pose(0.0, 0.0, 10.0), world.intrinsics)
    assert not pixel_safe_mask(world.raster, r.point_world, r.hit).any()


def test_slopes_safe_up_to_the_limit_only(small_config):
    world = record.build_world(load_scene("slopes"), small_config)
    ids = {o.name: o.id for o in world.meshes.objects}
    ras = world.raster
    for angle, landable in ((5, True), (10, True), (15, True), (20, False), (30, False)):
        on_ramp = ras.object_id == ids[f"ramp_{angle:02d}deg"]
        assert ras.safe[on_ramp].any() == landable, angle


# ----------------------------------------------------------------------------- sensor and flight
def test_sensor_noise_grows_with_range_and_edges_drop(small_config):
    cfg = load_config(overrides=["synth.sensor.edge_hole_prob=1.0"]).synth.sensor
    z = np.full((200, 200), 10.0, np.float32)
    z[:, 100:] = 4.0
    out = apply_depth_model(z, cfg, np.random.default_rng(1))
    far = out[:, :90] - 10.0
    assert np.nanstd(far) == pytest.approx(cfg.depth_sigma_a * 100.0, rel=0.1)
    assert np.isnan(out[:, 99:101]).all() and not np.isnan(out[:, :98]).any()
    assert depth_edges(z, cfg.edge_jump_m)[:, 99:101].all()
    beyond = apply_depth_model(np.full((4, 4), cfg.max_range_m + 1, np.float32), cfg, np.random.default_rng(1))
    assert np.isnan(beyond).all()


def test_flight_starts_at_preset_and_looks_down(small_config):
    for path in ("hover", "descent"):
        f = make_flight((-3.0, 12.0, 9.0), 60, 20.0, path, small_config.synth.flight, 7, 0)
        assert np.allclose(f.T_world_camera[0, :3, 3], (-3.0, 12.0, 9.0))
        R = f.T_world_camera[:, :3, :3]
        assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
        assert np.allclose(np.linalg.det(R), 1.0)
        optical_z = R[:, :, 2]
        tilt = np.degrees(np.arccos(-optical_z[:, 2]))
        assert tilt.max() < 2 * small_config.synth.flight.tilt_deg + 1e-6
        assert np.all(np.diff(f.stamps_ns) == 50_000_000)
    assert f.T_world_camera[-1, 2, 3] < 9.0 - 1.0        # descent goes down


# ----------------------------------------------------------------------------- recordings
def _synth(out: Path, fmt: str = "mcap", seed: int = 3, frames: int = 3, **kw) -> dict:
    cfg = load_config(overrides=TINY)
    opts = record.SynthOptions(scene="clear_field", frames=frames, rate_hz=20.0, path="hover", seed=seed,
                               start_m=(0.0, 0.0, 10.0), fmt=fmt, **kw)
    return record.synthesize(out, opts, cfg)


def test_same_seed_same_bytes(tmp_path):
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    _synth(a)
    _synth(b)
    _synth(c, seed=4)
    assert a.read_bytes() == b.read_bytes()
    assert Path(str(a) + ".gt.npz").read_bytes() == Path(str(b) + ".gt.npz").read_bytes()
    assert a.read_bytes() != c.read_bytes()


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_reads_back(tmp_path, fmt):
    out = tmp_path / {"mcap": "r.mcap", "mcap-ros1": "r.mcap", "ros1": "r.bag"}.get(fmt, "r_bag")
    _synth(out, fmt=fmt, frames=3)
    cfg = load_config(overrides=TINY)
    with open_recording(out, cfg) as rec:
        frames = list(rec.frames())
    gt = load_ground_truth(out)
    assert len(frames) == len(gt) == 3
    assert [f.stamp_ns for f in frames] == gt.stamps_ns.tolist()
    assert frames[0].rgb.shape == (120, 160, 3) and gt.safe_masks.shape == (3, 120, 160)
    assert all(f.T_world_camera is None for f in frames)     # the ground-truth pose is not the pose input


def test_encodings_and_ground_truth_pose_topic(tmp_path):
    out = tmp_path / "j.mcap"
    _synth(out, color_encoding="jpeg", depth_encoding="32FC1")
    cfg = load_config(overrides=[*TINY, "sources.use_ground_truth_pose=true"])
    gt = load_ground_truth(out)
    with open_recording(out, cfg) as rec:
        frames = list(rec.frames())
    assert len(frames) == 3 and frames[1].T_world_camera is not None
    assert np.allclose(frames[1].T_world_camera, gt.T_world_camera[1], atol=1e-9)
    header = json.loads(Path(str(out) + ".gt.json").read_text())
    assert header["pose_topic"] == "/ground_truth/camera_pose" and header["image"]["width"] == 160
    assert gt.safe_mask(int(gt.stamps_ns[2])).shape == (120, 160)
    with pytest.raises(SlzError):
        gt.safe_mask(int(gt.stamps_ns[2]) + 1)


def test_default_start_is_the_scenes_scenario(tmp_path):
    cfg = load_config(overrides=TINY)
    opts = record.SynthOptions(scene="playground", frames=1, rate_hz=20.0, path="hover", seed=0, start_m=None)
    summary = record.synthesize(tmp_path / "p.mcap", opts, cfg)
    assert summary["start_m"] == [0.0, 0.0, 7.0]
    assert np.allclose(load_ground_truth(tmp_path / "p.mcap").T_world_camera[0, :3, 3], (0.0, 0.0, 7.0))


def test_load_ground_truth_without_sidecar(tmp_path):
    with pytest.raises(SlzError, match="no ground truth"):
        load_ground_truth(tmp_path / "missing.mcap")


def _varied_truth(tmp_path: Path) -> Path:
    """A short descent over the parking lot: masks and object ids differ from frame to frame."""
    out = tmp_path / "lazy.mcap"
    opts = record.SynthOptions(scene="parking_lot", frames=4, rate_hz=2.0, path="descent", seed=1,
                               start_m=(0.0, 0.0, 9.0))
    record.synthesize(out, opts, load_config(overrides=TINY))
    return out


def test_ground_truth_loads_per_frame_arrays_lazily(tmp_path):
    import zipfile

    from slzcli.synth.groundtruth import GT_VERSION, PackedMasks, ZipMemberFrames

    out = _varied_truth(tmp_path)
    npz = Path(str(out) + ".gt.npz")
    with zipfile.ZipFile(npz) as zf:
        kinds = {i.filename: i.compress_type for i in zf.infolist()}
    assert kinds["safe_masks.npy"] == zipfile.ZIP_STORED and kinds["object_ids.npy"] == zipfile.ZIP_DEFLATED
    assert not list(tmp_path.glob(".gt-spool-*"))            # the spool folder is gone
    gt = load_ground_truth(out)
    assert gt.header["version"] == GT_VERSION == 2
    # nothing per-frame is in memory: masks are a memory map of the packed bits, ids are read per frame
    assert isinstance(gt.safe_masks, PackedMasks) and isinstance(gt.safe_masks.packed, np.memmap)
    assert isinstance(gt.object_ids, ZipMemberFrames)
    assert gt.safe_masks.shape == gt.object_ids.shape == (4, 120, 160)
    # the same values as numpy's own reading of the npz (the file stays a plain npz)
    with np.load(npz) as z:
        masks = np.unpackbits(z["safe_masks"], axis=-1, count=160).astype(bool)
        ids = z["object_ids"]
    assert len({m.tobytes() for m in masks}) == 4 and len({i.tobytes() for i in ids}) == 4   # frames differ
    for i in (0, 3, 1, 2, -1):   # any order, backwards too
        assert np.array_equal(gt.safe_masks[i], masks[i]) and np.array_equal(gt.object_ids[i], ids[i])
    assert np.array_equal(gt.safe_mask(int(gt.stamps_ns[2])), masks[2])
    assert gt.safe_mask(int(gt.stamps_ns[2])).dtype == bool
    assert np.array_equal(np.asarray(gt.safe_masks), masks) and np.array_equal(np.asarray(gt.object_ids), ids)
    with pytest.raises(IndexError):
        gt.object_ids[4]


def test_version_1_sidecar_still_loads(tmp_path):
    import zipfile

    out = _varied_truth(tmp_path)
    npz, js = Path(str(out) + ".gt.npz"), Path(str(out) + ".gt.json")
    with zipfile.ZipFile(npz) as zf:
        members = {i.filename: zf.read(i) for i in zf.infolist()}
    with zipfile.ZipFile(npz, "w", zipfile.ZIP_DEFLATED) as zf:   # v1: every member deflated
        for name, data in members.items():
            zf.writestr(name, data)
    header = json.loads(js.read_text())
    js.write_text(json.dumps({**header, "version": 1}))
    gt = load_ground_truth(out)
    with np.load(npz) as z:
        masks = np.unpackbits(z["safe_masks"], axis=-1, count=160).astype(bool)
        ids = z["object_ids"]
    assert np.array_equal(gt.safe_mask(int(gt.stamps_ns[3])), masks[3]) and np.array_equal(gt.object_ids[1], ids[1])
    js.write_text(json.dumps({**header, "version": 99}))
    with pytest.raises(SlzError, match="header"):
        load_ground_truth(out)


# ----------------------------------------------------------------------------- CLI
def test_cli_list():
    res = CliRunner().invoke(main, ["synth", "--list"])
    assert res.exit_code == 0
    assert "parking_lot" in res.output and "low_light" in res.output


def test_cli_small_run(tmp_path):
    out = tmp_path / "run.mcap"
    res = CliRunner().invoke(main, ["synth", "clear_field:sand", "-o", str(out), "--frames", "2", "--scenario", "3",
                                    "--json", *[a for s in TINY for a in ("--set", s)]])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)  # the progress lines are on stderr
    assert summary["frames"] == 2 and summary["variants"] == ["sand"] and summary["start_m"] == [0.0, 0.0, 7.0]
    assert out.is_file() and Path(summary["preview"]).is_file() and Path(summary["ground_truth"]).is_file()
    again = CliRunner().invoke(main, ["synth", "clear_field", "-o", str(out), "--frames", "1"])
    assert again.exit_code == 1 and "--force" in again.output


@pytest.mark.parametrize("args, needle", [
    (["synth", "parkinglot", "-o", "x.mcap"], "unknown scene 'parkinglot' (did you mean 'parking_lot'?)"),
    (["synth", "parking_lot:muddy", "-o", "x.mcap"], "unknown variant 'muddy'"),
    (["synth", "parking_lot", "--set", "synth.sensor.edge_hole_prob=2", "-o", "x.mcap"],
     "synth.sensor.edge_hole_prob"),
    (["synth", "parking_lot", "--format", "ros1", "-o", "x.mcap"], "needs a name ending in .bag"),
])
def test_cli_bad_input_one_line(tmp_path, args, needle):
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.output
