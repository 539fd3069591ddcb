"""Real camera layouts: presets, depth registered to colour, undistortion, and a warning for every fallback.

The registration is checked on an analytic scene (a tilted floor and a box top) rendered directly
in a depth camera and in a colour camera beside it: the registered depth must equal the colour
camera's own rendering, and a hole in the depth must stay a hole.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage
from sources_util import T0_NS

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.geometry import Pose
from slzcli.outputs.recording import RecordingWriter, TopicLayout
from slzcli.sources import open_recording
from slzcli.sources.presets import all_presets, choose_preset, guess_from_folder, guess_from_topics, with_noise_prior
from slzcli.sources.registration import register_depth
from slzcli.sources.undistort import distortion_problem, undistort_color, undistort_maps
from slzcli.types import Intrinsics

K_DEPTH = Intrinsics(424.0, 424.0, 423.5, 239.5, 848, 480)      # a D435's depth stream (848x480, ~87 deg)
K_COLOR = Intrinsics(615.0, 615.5, 319.5, 239.5, 640, 480)      # its colour stream (640x480, ~55 deg)
FLOOR_N = np.array([0.0, np.sin(np.radians(20)), np.cos(np.radians(20))])   # a floor tilted 20 deg, 3 m away
FLOOR_D = 3.0


def render(k: Intrinsics, T_ref_cam: np.ndarray, box_z: float) -> np.ndarray:
    """Depth (z in the camera, metres) of the floor and a box top (z = box_z, |x| <= 0.3, -0.25 <= y <= 0.2),
    both given in the reference (depth camera) frame, seen by camera ``k`` at pose ``T_ref_cam``."""
    v, u = np.mgrid[0:k.height, 0:k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1) @ T_ref_cam[:3, :3].T
    o = T_ref_cam[:3, 3]
    s_floor = (FLOOR_D - FLOOR_N @ o) / (rays @ FLOOR_N)
    s_box = (box_z - o[2]) / rays[..., 2]
    hit = o + s_box[..., None] * rays
    on_box = (np.abs(hit[..., 0]) <= 0.3) & (hit[..., 1] >= -0.25) & (hit[..., 1] <= 0.2) & (s_box > 0)
    s = np.where(on_box, np.minimum(s_box, s_floor), s_floor)  # rays have z = 1 in the camera: s is the depth
    return np.where(s > 0, s, np.nan).astype(np.float32)


def camera_pair(seed: int) -> tuple[np.ndarray, float]:
    """T_depth_color (the colour camera's pose in the depth camera's frame): a RealSense-like baseline and a
    small rotation, and the box's height."""
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    a = np.radians(rng.uniform(-1.0, 1.0))
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = (rng.uniform(0.015, 0.06), rng.uniform(-0.005, 0.005), rng.uniform(-0.005, 0.005))
    return T, float(rng.uniform(1.5, 2.2))


@pytest.mark.parametrize("seed", range(4))
def test_registered_depth_equals_the_depth_rendered_in_the_colour_camera(seed: int) -> None:
    T_depth_color, box_z = camera_pair(seed)
    depth = render(K_DEPTH, np.eye(4), box_z)
    truth = render(K_COLOR, T_depth_color, box_z)
    depth[200:230, 600:640] = np.nan                      # a hole in the depth image
    got = register_depth(depth, K_DEPTH, np.linalg.inv(T_depth_color), K_COLOR)
    edge = ndimage.maximum_filter(truth, 5) - ndimage.minimum_filter(truth, 5) > 0.05   # 2 px around the box
    both = np.isfinite(got) & np.isfinite(truth) & ~edge
    rel = np.abs(got[both] - truth[both]) / truth[both]
    # Measured over seeds 0-3: max relative error 0.050-0.052 % (a patch's depth is its centre's, the floor
    # tilts across it); limit 0.2 %, ~4x. A resize instead of a registration is off by up to 30 % here.
    assert rel.max() < 0.002
    # Coverage of the colour pixels the depth camera sees: measured 0.988-0.990 (the rest: the hole and the
    # box's occlusion shadow); limit 0.97. No sampling gaps though the colour grid is 1.45x finer.
    assert np.isfinite(got[np.isfinite(truth) & ~edge]).mean() > 0.97
    # The hole stays a hole: colour pixels whose scene point the depth camera saw inside it (1.5 px in) are NaN.
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    P = np.stack([(u - K_COLOR.cx) / K_COLOR.fx, (v - K_COLOR.cy) / K_COLOR.fy, np.ones_like(u)], -1) \
        * truth[..., None].astype(np.float64)
    Pd = P @ T_depth_color[:3, :3].T + T_depth_color[:3, 3]
    ud, vd = K_DEPTH.fx * Pd[..., 0] / Pd[..., 2] + K_DEPTH.cx, K_DEPTH.fy * Pd[..., 1] / Pd[..., 2] + K_DEPTH.cy
    in_hole = (ud > 601.5) & (ud < 637.5) & (vd > 201.5) & (vd < 227.5)
    assert in_hole.sum() > 200 and np.isnan(got[in_hole]).all()


def test_registration_keeps_the_nearer_surface_and_empty_depth_gives_holes() -> None:
    depth = np.full((480, 848), 4.0, np.float32)
    depth[:, 400:450] = 1.0                                     # a near pole in front of a wall
    T = np.eye(4)
    T[0, 3] = -0.05                                             # colour 5 cm to the right
    got = register_depth(depth, K_DEPTH, T, K_COLOR)
    assert np.nanmin(got) == pytest.approx(1.0, abs=1e-5) and np.nanmax(got) == pytest.approx(4.0, abs=1e-5)
    row = got[240]
    pole = np.flatnonzero(np.abs(row - 1.0) < 1e-3)
    assert pole.size > 20 and np.all(np.abs(row[pole.min():pole.max() + 1] - 1.0) < 1e-3)  # no wall through it
    assert np.isnan(register_depth(np.full((480, 848), np.nan, np.float32), K_DEPTH, T, K_COLOR)).all()


@pytest.mark.parametrize("model, coeffs", [
    ("plumb_bob", (-0.28, 0.09, 0.001, -0.0015, -0.01)),
    ("rational_polynomial", (0.4, -0.05, 0.0008, 0.0005, 0.002, 0.75, 0.01, 0.005)),
    ("equidistant", (-0.02, 0.01, -0.004, 0.001)),
])
def test_undistortion_maps_a_distorted_grid_of_points_back(model: str, coeffs: tuple[float, ...]) -> None:
    k = Intrinsics(400.0, 402.0, 321.0, 238.0, 640, 480, model, coeffs)
    gu, gv = np.meshgrid(np.linspace(60, 580, 9), np.linspace(50, 430, 7))
    ideal = np.stack([gu.ravel(), gv.ravel()], -1)
    rays = np.stack([(ideal[:, 0] - k.cx) / k.fx, (ideal[:, 1] - k.cy) / k.fy, np.ones(len(ideal))], -1)
    D = np.asarray(coeffs)
    if model == "equidistant":
        seen = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k.K, D)[0].reshape(-1, 2)
    else:
        seen = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k.K, D)[0].reshape(-1, 2)
    img = np.zeros((480, 640, 3), np.uint8)
    for x, y in seen:  # test set-up only: 63 dots
        cv2.circle(img, (int(np.rint(x * 16)), int(np.rint(y * 16))), 3 * 16, (255, 255, 255), -1, cv2.LINE_AA, 4)
    maps = undistort_maps(k)
    assert maps is not None and maps.intrinsics.distortion == () and maps.intrinsics.fx == k.fx
    out = undistort_color(img, maps)[..., 0].astype(np.float64)
    labels, n = ndimage.label(out > 40)
    centres = np.array(ndimage.center_of_mass(out, labels, range(1, n + 1)))[:, ::-1]
    assert n == len(ideal)
    err = np.linalg.norm(centres[:, None, :] - ideal[None], axis=-1).min(axis=0)
    # Measured: max 0.10-0.14 px over the three models (dot centroids after resampling); limit 0.3 px (2x).
    # Without undistortion the dots sit up to 48-55 px away.
    assert err.max() < 0.3
    assert np.linalg.norm(seen - ideal, axis=-1).max() > 5


def test_distortion_slz_cannot_undo_is_named() -> None:
    assert distortion_problem(Intrinsics(500, 500, 320, 240, 640, 480, "radtan_fancy", (0.1,))) is not None
    assert distortion_problem(Intrinsics(500, 500, 320, 240, 640, 480, "plumb_bob", (0.0,) * 5)) is None
    assert undistort_maps(Intrinsics(500, 500, 320, 240, 640, 480, "plumb_bob", (0.0,) * 5)) is None


# ----------------------------------------------------------------------------- presets
@pytest.mark.parametrize("topics, name", [
    (["/oak/rgb/image_raw", "/oak/rgb/camera_info", "/oak/stereo/image_raw", "/oak/stereo/camera_info"], "oakd"),
    (["/zed/zed_node/rgb/image_rect_color", "/zed/zed_node/rgb/camera_info", "/zed/zed_node/depth/depth_registered",
      "/zed/zed_node/depth/camera_info"], "zed"),
    (["/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw", "/camera/depth/image_rect_raw"],
     "d435_aligned"),
    (["/camera/color/image_raw", "/camera/depth/image_rect_raw", "/camera/depth/camera_info"], "d435_raw"),
    (["/d455/color/image_raw", "/d455/aligned_depth_to_color/image_raw"], "d455_aligned"),
    (["/device_0/sensor_1/Color_0/image/data", "/device_0/sensor_0/Depth_0/image/data"], "realsense_viewer"),
    (["/cam/image", "/cam/depth"], None),
])
def test_presets_are_guessed_from_the_topics(topics: list[str], name: str | None) -> None:
    assert guess_from_topics(topics).name == name


def test_every_preset_has_its_noise_prior_and_tum_its_published_calibration() -> None:
    presets = {p.name: p for p in all_presets()}
    assert {"d435_aligned", "d435_raw", "d455_aligned", "d455_raw", "zed", "oakd", "realsense_viewer",
            "tum_fr1", "tum_fr2", "tum_fr3"} <= set(presets)
    assert all(0 < p.noise_prior_a_per_m < 0.01 for p in presets.values())
    fr1, fr2, fr3 = (presets[f"tum_fr{i}"].intrinsics for i in (1, 2, 3))
    assert fr1 is not None and (fr1.fx, fr1.fy, fr1.cx, fr1.cy) == (517.3, 516.5, 318.6, 255.3)
    assert fr2 is not None and (fr2.fx, fr2.fy, fr2.cx, fr2.cy) == (520.9, 521.0, 325.1, 249.7)
    assert fr3 is not None and (fr3.fx, fr3.fy, fr3.cx, fr3.cy) == (535.4, 539.2, 320.1, 247.6)
    assert guess_from_folder(Path("rgbd_dataset_freiburg2_desk")).name == "tum_fr2"
    assert choose_preset("none", ["/camera/color/image_raw"]).preset is None
    # the preset's prior replaces the default one only
    cfg = load_config()
    assert with_noise_prior(cfg, "d455_raw").terrain.noise_estimate.prior_a_per_m == 0.002
    mine = load_config(None, ["terrain.noise_estimate.prior_a_per_m=0.01"])
    assert with_noise_prior(mine, "d455_raw").terrain.noise_estimate.prior_a_per_m == 0.01


def test_tum_folder_named_freiburg1_uses_the_published_calibration_and_undistorts(tmp_path: Path, runner) -> None:
    root = tmp_path / "rgbd_dataset_freiburg1_xyz"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    cv2.imwrite(str(root / "rgb" / "0.png"), np.full((480, 640, 3), 128, np.uint8))
    cv2.imwrite(str(root / "depth" / "0.png"), np.full((480, 640), 10000, np.uint16))
    (root / "rgb.txt").write_text("1305031102.175304 rgb/0.png\n")
    (root / "depth.txt").write_text("1305031102.175304 depth/0.png\n")
    res = runner.invoke(main, ["info", str(root), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["camera_preset"]["name"] == "tum_fr1" and "freiburg1" in info["camera_preset"]["reason"]
    assert info["intrinsics"]["fx"] == 517.3 and info["warnings"] == []
    with open_recording(root, load_config()) as rec:
        frame = next(iter(rec.frames()))
    assert frame.intrinsics.distortion == () and frame.intrinsics.fx == 517.3
    assert np.isnan(frame.depth_m[0, 0]) and frame.depth_m[240, 320] == pytest.approx(2.0)  # corners left the image
    # --camera none: the fallback is a warning on stderr and in the JSON
    res = runner.invoke(main, ["info", str(root), "--json", "--camera", "none"])
    assert res.exit_code == 0 and "WARNING" in res.stderr and "config camera section" in res.stderr
    assert any("config camera section" in w for w in json.loads(res.stdout)["warnings"])


# ----------------------------------------------------------------------------- a D435 bag without alignment
RAW = TopicLayout(color="/camera/color/image_raw", color_info="/camera/color/camera_info",
                  depth="/camera/depth/image_rect_raw", depth_info="/camera/depth/camera_info",
                  frame_id="camera_color_optical_frame")


def write_raw_d435(path: Path, T_depth_color: np.ndarray, box_z: float, frames: int = 3, tf_static: bool = True,
                   poses: bool = True) -> None:
    """A realsense2_camera-like recording: 640x480 colour and 848x480 depth, each with its own CameraInfo and
    optical frame, /tf_static linking both to camera_link, and (optionally) a PoseStamped per frame."""
    depth = render(K_DEPTH, np.eye(4), box_z)
    rgb: np.ndarray = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8),
                                       (0, 0), 3)
    with RecordingWriter(path, "ros1" if path.suffix == ".bag" else "mcap", layout=RAW) as w:
        if tf_static:
            T_link_depth = np.eye(4)
            T_link_depth[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]     # REP 103 optical frame under camera_link
            w.write_pose("/tf_static", T0_NS, T_link_depth, kind="tf", parent="camera_link",
                         child="camera_depth_optical_frame")
            w.write_pose("/tf_static", T0_NS, T_link_depth @ T_depth_color, kind="tf", parent="camera_link",
                         child="camera_color_optical_frame")
        for i in range(frames):
            stamp = T0_NS + i * 33_333_333
            _, c = w.color_message(rgb, stamp)
            _, d = w.depth_message(depth, stamp)
            w.write_raw(RAW.color, "sensor_msgs/msg/Image", c, stamp)
            w.write_raw(RAW.depth, "sensor_msgs/msg/Image",
                        dataclasses.replace(d, header=w.header(stamp, "camera_depth_optical_frame")), stamp)
            for topic, k, frame in ((RAW.color_info, K_COLOR, "camera_color_optical_frame"),
                                    (RAW.depth_info, K_DEPTH, "camera_depth_optical_frame")):
                info = w._camera_info(k, stamp)
                w.write_raw(topic, "sensor_msgs/msg/CameraInfo",
                            dataclasses.replace(info, header=w.header(stamp, frame)), stamp)
            if poses:
                T = np.eye(4)
                T[:3, :3] = Pose.from_quat(np.array([1.0, 0, 0, 0]), np.zeros(3)).rotation.as_matrix()
                T[:3, 3] = (0.01 * i, 0.0, 3.0)
                w.write_pose("/camera/pose", stamp, T)


@pytest.mark.parametrize("suffix", [".bag", ".mcap"])
def test_raw_d435_depth_is_registered_with_tf_static_not_resized(tmp_path: Path, runner, suffix: str) -> None:
    T_depth_color, box_z = camera_pair(1)
    path = tmp_path / f"raw{suffix}"
    write_raw_d435(path, T_depth_color, box_z)
    res = runner.invoke(main, ["info", str(path), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["camera_preset"]["name"] == "d435_raw"
    assert info["streams"]["depth_info"]["topic"] == RAW.depth_info
    assert "registered to colour" in info["depth_to_color"] and "/tf_static" in info["depth_to_color"]
    assert info["warnings"] == [] and "WARNING" not in res.stderr
    with open_recording(path, load_config()) as rec:
        frame = next(iter(rec.frames()))
    truth = render(K_COLOR, T_depth_color, box_z)
    edge = ndimage.maximum_filter(truth, 5) - ndimage.minimum_filter(truth, 5) > 0.05
    both = np.isfinite(frame.depth_m) & np.isfinite(truth) & ~edge
    # Through 16UC1 millimetres: measured (seeds 0-2) max relative error 0.059-0.064 %, coverage 0.986-0.991;
    # limits 0.2 % (3x) and 0.9. A nearest-neighbour resize is off by 3.5 % at the median here, 64 % at most.
    rel = np.abs(frame.depth_m[both] - truth[both]) / truth[both]
    assert both.mean() > 0.9 and rel.max() < 0.002
    assert frame.depth_m.shape == (480, 640) and frame.intrinsics.fx == K_COLOR.fx


def test_fallbacks_are_warned_on_stderr_and_in_run_json(tmp_path: Path, runner) -> None:
    T_depth_color, box_z = camera_pair(2)
    path = tmp_path / "no_tf.mcap"
    write_raw_d435(path, T_depth_color, box_z, frames=3, tf_static=False)
    out = tmp_path / "run"
    res = runner.invoke(main, ["detect", str(path), "-o", str(out), "--json", "--outputs", "summary"])
    assert res.exit_code == 0, res.output
    assert "no depth->colour extrinsics" in res.stderr
    assert sum("no depth->colour extrinsics" in line for line in res.stderr.splitlines()) == 1   # once
    run = json.loads((out / "run.json").read_text())
    assert any("no depth->colour extrinsics" in w for w in run["recording"]["warnings"])
    assert run["recording"]["camera_preset"]["name"] == "d435_raw"
    assert run["config"]["terrain"]["noise_estimate"]["prior_a_per_m"] == 0.0038


def test_oakd_layout_is_read(tmp_path: Path, runner) -> None:
    """The OAK-D topics that used to give "no depth stream": depth on /oak/stereo/image_raw."""
    path = tmp_path / "oak.mcap"
    lay = TopicLayout(color="/oak/rgb/image_raw", color_info="/oak/rgb/camera_info", depth="/oak/stereo/image_raw",
                      depth_info="/oak/stereo/camera_info", frame_id="oak_rgb_camera_optical_frame")
    depth = np.full((24, 32), 2.0, np.float32)
    with RecordingWriter(path, "mcap", layout=lay) as w:
        from slzcli.types import Frame
        k = Intrinsics(30.0, 30.0, 15.5, 11.5, 32, 24)
        for i in range(2):
            w.write_frame(Frame(i, T0_NS + i * 33_333_333, np.zeros((24, 32, 3), np.uint8), depth, k))
    res = runner.invoke(main, ["info", str(path), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["camera_preset"]["name"] == "oakd" and info["streams"]["depth"]["topic"] == "/oak/stereo/image_raw"
    assert info["frames"] == 2
    # the stereo CameraInfo and frame equal the rgb ones: already aligned, nothing reprojected
    assert "aligned" in info["depth_to_color"]
    text = runner.invoke(main, ["info", str(path)]).stdout
    assert "camera preset: oakd" in text and "guessed from the topics" in text


def test_realsense_viewer_bag_layout_is_read_and_registered(tmp_path: Path, runner) -> None:
    """The RealSense Viewer's own .bag (librealsense ros-bag format 3): streams under /device_0/sensor_N/,
    CameraInfo per stream, per-stream extrinsics (geometry_msgs/Transform on .../tf/0), the depth unit as an
    option, and librealsense's own message types beside them."""
    from rosbags.typesys import get_types_from_msg

    T_depth_color, box_z = camera_pair(3)
    depth_mm = np.nan_to_num(render(K_DEPTH, np.eye(4), box_z) * 10000)   # Depth_Units 0.0001 m (a D405's)
    dev = "/device_0/sensor_0/Depth_0"
    col = "/device_0/sensor_1/Color_0"
    path = tmp_path / "viewer.bag"
    with RecordingWriter(path, "ros1") as w:
        w.typestore.register(get_types_from_msg("uint32 fps\nstring encoding\nbool is_recommended",
                                                "realsense_msgs/msg/StreamInfo"))
        gm = w.typestore.types
        # each stream's extrinsics from the reference (the depth) stream: T_stream_ref, as librealsense writes them
        for prefix, T in ((dev, np.eye(4)), (col, np.linalg.inv(T_depth_color))):
            q = Pose.from_matrix(T).as_quat()
            tr = gm["geometry_msgs/msg/Transform"](
                translation=gm["geometry_msgs/msg/Vector3"](*map(float, T[:3, 3])),
                rotation=gm["geometry_msgs/msg/Quaternion"](*map(float, q)))
            w.write_raw(prefix + "/tf/0", "geometry_msgs/msg/Transform", tr, T0_NS)
            w.write_raw(prefix + "/info", "realsense_msgs/msg/StreamInfo",
                        w.message("realsense_msgs/msg/StreamInfo", fps=30, encoding="mono16", is_recommended=True),
                        T0_NS)
        w.write_raw("/device_0/sensor_0/option/Depth_Units/value", "std_msgs/msg/Float32",
                    w.message("std_msgs/msg/Float32", data=0.0001), T0_NS)
        rgb = np.full((480, 640, 3), 90, np.uint8)
        for i in range(2):
            stamp = T0_NS + i * 33_333_333
            w.write_raw(col + "/image/data", *w.color_message(rgb, stamp), stamp)
            img = w._image(stamp, depth_mm.astype(np.uint16), "mono16")
            w.write_raw(dev + "/image/data", "sensor_msgs/msg/Image", img, stamp)
            w.write_raw(col + "/info/camera_info", "sensor_msgs/msg/CameraInfo", w._camera_info(K_COLOR, stamp), stamp)
            w.write_raw(dev + "/info/camera_info", "sensor_msgs/msg/CameraInfo", w._camera_info(K_DEPTH, stamp), stamp)
    # the floor is tilted and nothing measures gravity: the scene would be used, with its warnings
    # (tests/top/test_gravity.py); the registration is what is tested here
    res = runner.invoke(main, ["info", str(path), "--json", "--set", "camera.gravity.source=mount"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["camera_preset"]["name"] == "realsense_viewer" and info["frames"] == 2
    assert info["streams"]["depth_info"]["topic"] == dev + "/info/camera_info"
    assert "recorded stream extrinsics" in info["depth_to_color"] and info["warnings"] == []
    with open_recording(path, load_config()) as rec:
        frame = next(iter(rec.frames()))
    truth = render(K_COLOR, T_depth_color, box_z)
    edge = ndimage.maximum_filter(truth, 5) - ndimage.minimum_filter(truth, 5) > 0.05
    both = np.isfinite(frame.depth_m) & np.isfinite(truth) & ~edge
    # the recorded depth unit is used (0.1 mm counts), and the extrinsics: as the D435 bag, limit 0.2 %
    assert both.mean() > 0.9 and (np.abs(frame.depth_m[both] - truth[both]) / truth[both]).max() < 0.002


def test_zed_layout_takes_the_rgb_camera_info_not_the_first_of_two() -> None:
    from slzcli.sources.topics import choose_streams

    types = {"/zed/zed_node/rgb/image_rect_color": "sensor_msgs/msg/Image",
             "/zed/zed_node/rgb/camera_info": "sensor_msgs/msg/CameraInfo",
             "/zed/zed_node/depth/depth_registered": "sensor_msgs/msg/Image",
             "/zed/zed_node/depth/camera_info": "sensor_msgs/msg/CameraInfo"}
    cfg = load_config().sources
    for preset in (guess_from_topics(types).preset, None):   # with the zed preset, and by the generic rules
        ch = choose_streams(types, cfg, "zed.bag", preset=preset)
        assert ch.aligned and ch.depth.topic == "/zed/zed_node/depth/depth_registered"
        assert ch.camera_info.topic == "/zed/zed_node/rgb/camera_info", ch.camera_info.reason
        assert "not aligned" not in ch.depth.reason


def test_real_realsense_depth_survives_a_round_trip_through_another_camera(realsense_dir: Path) -> None:
    """Real D435 depth (noise, holes at edges) registered into a virtual 848x480 depth camera 5 cm aside
    and back: what comes back is the original depth, and every hole wider than 2 px is still a hole."""
    params = json.loads((realsense_dir / "cam_params_realsense.json").read_text())["intrinsic_matrix"]
    k_real = Intrinsics(params[0], params[4], params[6], params[7], 640, 480)   # column-major K
    T = np.eye(4)
    T[0, 3] = 0.05
    for name in sorted((realsense_dir / "depth").glob("*.png"))[:10]:
        counts = cv2.imread(str(name), cv2.IMREAD_UNCHANGED)
        assert counts is not None
        raw = counts.astype(np.float32) / 1000
        raw[raw == 0] = np.nan
        back = register_depth(register_depth(raw, k_real, T, K_DEPTH), K_DEPTH, np.linalg.inv(T), k_real)
        both = np.isfinite(back) & np.isfinite(raw)
        rel = np.abs(back[both] - raw[both]) / raw[both]
        # Measured over the 10 frames: median 0, 90th percentile 0.28-0.86 % (two resamplings through a grid
        # 1.45x coarser, at depth edges), coverage of the valid pixels 0.897-0.991; limits 2 % and 0.85.
        assert np.median(rel) < 1e-6 and np.quantile(rel, 0.9) < 0.02
        assert both.sum() / np.isfinite(raw).sum() > 0.85
        core = ndimage.binary_erosion(np.isnan(raw), iterations=2)   # holes: 485-52,858 px per frame
        assert np.isnan(back[core]).all()
