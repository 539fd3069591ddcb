"""results.mcap frame ids (issue 19, REP 105): slz's map is ``map``, the camera keeps the recording's optical
frame id, and a recording with camera poses gets a /tf_static link from its pose frame to slz's map."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import GAUSSIAN, synth_recording

from slzcli.cli import main
from slzcli.config import load_config
from slzcli.geometry import invert_pose
from slzcli.outputs.recording import RecordingWriter
from slzcli.outputs.results_mcap import ResultsMcap
from slzcli.sources import open_recording
from slzcli.types import RecordedFrames

FRAMES = 4
OPTICAL = "camera_color_optical_frame"   # the synth recordings' (RealSense wrapper) colour frame id
# camera_link -> optical: the RealSense wrapper's rotation (z forward, x right, y down from x forward, z up)
T_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.01], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])


def read_mcap(path: Path) -> dict[str, list[Any]]:
    """Every message of a results.mcap, decoded (ROS 2 Humble CDR), per topic in file order."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, list[Any]] = {}
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            assert schema is not None
            out.setdefault(channel.topic, []).append(store.deserialize_cdr(message.data, schema.name))
    return out


def matrix(tr: Any) -> np.ndarray:
    from slzcli.geometry import Pose

    q, p = tr.rotation, tr.translation
    return Pose.from_quat(np.array([q.x, q.y, q.z, q.w]), np.array([p.x, p.y, p.z])).as_matrix()


def edges(msgs: list[Any]) -> list[tuple[str, str, np.ndarray]]:
    return [(t.header.frame_id, t.child_frame_id, matrix(t.transform)) for m in msgs for t in m.transforms]


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> Path:
    return synth_recording(tmp_path_factory.mktemp("f") / "clear.mcap", "clear_field", FRAMES, *GAUSSIAN)


@pytest.fixture(scope="module")
def with_tf(synth, tmp_path_factory) -> Path:
    """The synth flight re-recorded as a robot would: /tf odom -> camera_link, /tf_static camera_link -> optical."""
    path = tmp_path_factory.mktemp("tf") / "tf.mcap"
    config = load_config()
    with open_recording(synth, config) as rec:
        frames = list(rec.frames())
    truth = np.load(str(synth) + ".gt.npz")
    poses = truth["T_world_camera"]
    assert len(poses) == len(frames)
    with RecordingWriter(path, "mcap") as w:
        t = w.typestore.types
        gm = "geometry_msgs/msg/"
        static = w.message("tf2_msgs/msg/TFMessage", transforms=[t[gm + "TransformStamped"](
            header=w.header(frames[0].stamp_ns, "camera_link"), child_frame_id=OPTICAL,
            transform=t[gm + "Transform"](translation=t[gm + "Vector3"](0.01, 0.0, 0.0),
                                          rotation=t[gm + "Quaternion"](-0.5, 0.5, -0.5, 0.5)))])
        w.write_raw("/tf_static", "tf2_msgs/msg/TFMessage", static, frames[0].stamp_ns)
        for f, T in zip(frames, poses, strict=True):
            w.write_pose("/tf", f.stamp_ns, T @ invert_pose(T_LINK_OPTICAL), "tf", "odom", "camera_link")
            w.write_frame(f)
    return path


def detect(rec: Path, out: Path, *options: str) -> dict:
    res = CliRunner().invoke(main, ["detect", str(rec), "-o", str(out), "--json", *options])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def test_the_quaternion_of_the_static_chain_is_the_realsense_rotation() -> None:
    from slzcli.geometry import Pose

    np.testing.assert_allclose(Pose.from_matrix(T_LINK_OPTICAL).as_quat(), [-0.5, 0.5, -0.5, 0.5], atol=1e-12)


def test_recording_frames_are_read(synth, with_tf) -> None:
    config = load_config()
    with open_recording(synth, config) as rec:
        plain = rec.recorded_frames()
    assert (plain.camera, plain.camera_root, plain.pose_frame, plain.tf_places_camera) == (OPTICAL, "", "", False)
    with open_recording(with_tf, config) as rec:
        tf = rec.recorded_frames()
    assert (tf.camera, tf.camera_root, tf.pose_frame, tf.tf_places_camera) == (OPTICAL, "camera_link", "odom", True)
    assert tf.T_root_camera is not None
    np.testing.assert_allclose(tf.T_root_camera, T_LINK_OPTICAL, atol=1e-9)


def test_a_recording_without_tf_gets_map_and_its_own_camera_frame(synth, tmp_path) -> None:
    detect(synth, tmp_path / "run")
    msgs = read_mcap(tmp_path / "run" / "results.mcap")
    for topic in ("/slz/color/compressed", "/slz/camera_info", "/slz/score", "/slz/overlay/compressed", "/slz/mask"):
        assert {m.header.frame_id for m in msgs[topic]} == {OPTICAL}, topic
    for topic in ("/slz/map_points", "/slz/camera_pose"):
        assert {m.header.frame_id for m in msgs[topic]} == {"map"}, topic
    assert {(p, c) for p, c, _ in edges(msgs["/tf"])} == {("map", OPTICAL)}
    assert "/tf_static" not in msgs  # the ground-truth pose is not read: nothing to link to
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert [s["mcap_frame"] for s in run["summary"]["slam"]["segments"]] == ["map"]


def test_the_map_frame_is_configurable(synth, tmp_path) -> None:
    detect(synth, tmp_path / "run", "--set", "output.map_frame=slz_map")
    msgs = read_mcap(tmp_path / "run" / "results.mcap")
    assert {m.header.frame_id for m in msgs["/slz/map_points"]} == {"slz_map"}
    res = CliRunner().invoke(main, ["detect", str(synth), "-o", str(tmp_path / "bad"), "--set",
                                    "output.map_frame=/my map"])
    assert res.exit_code == 1 and "output.map_frame" in res.output and not (tmp_path / "bad").exists()


def test_recorded_tf_poses_link_the_map_to_the_recordings_frame(with_tf, tmp_path) -> None:
    """Recorded poses (the recorded backend): slz's map is the recording's odom, so the link is the identity; the
    recording's /tf places the camera, so slz publishes no second parent for it."""
    summary = detect(with_tf, tmp_path / "run")
    assert summary["slam_backend"] == "recorded"
    msgs = read_mcap(tmp_path / "run" / "results.mcap")
    assert "/tf" not in msgs
    (link,) = edges(msgs["/tf_static"])
    assert link[:2] == ("odom", "map")
    np.testing.assert_allclose(link[2], np.eye(4), atol=1e-9)
    assert {m.header.frame_id for m in msgs["/slz/color/compressed"]} == {OPTICAL}


def test_slam_poses_are_linked_on_the_first_frame(with_tf, synth, tmp_path) -> None:
    """SLAM (odometry) on a recording with /tf: map -> odom is fixed on the first tracked frame, and through it
    every later slz pose lands near the recorded one (the odometry's drift)."""
    detect(with_tf, tmp_path / "run", "--set", "slam.backend=odometry")
    msgs = read_mcap(tmp_path / "run" / "results.mcap")
    (link,) = edges(msgs["/tf_static"])
    assert link[:2] == ("odom", "map")
    truth = np.load(str(synth) + ".gt.npz")["T_world_camera"]
    slz = [matrix_of_pose(m.pose) for m in msgs["/slz/camera_pose"]]
    np.testing.assert_allclose(link[2] @ slz[0], truth[0], atol=1e-6)
    err = [float(np.linalg.norm((link[2] @ T)[:3, 3] - G[:3, 3])) for T, G in zip(slz, truth, strict=True)]
    # Measured (max over the 4 frames, synth seeds 0-3): 0.019, 0.021, 0.024, 0.037 m; bound 0.1 m (2.7x the
    # worst). A wrong or inverted link is metres off (slz's map starts at the first camera, ~10 m up in odom).
    assert max(err) < 0.1, err


def matrix_of_pose(p: Any) -> np.ndarray:
    from slzcli.geometry import Pose

    q, t = p.orientation, p.position
    return Pose.from_quat(np.array([q.x, q.y, q.z, q.w]), np.array([t.x, t.y, t.z])).as_matrix()


def test_the_link_is_the_first_poses_alignment_and_the_static_chain_is_copied(tmp_path) -> None:
    """ResultsMcap alone: link = recorded @ inv(slz) of each segment's first frame with both; slz places the camera
    through the root of its static chain when the recording's /tf does not."""
    rng = np.random.default_rng(3)
    from slzcli.geometry import Pose

    def random_pose() -> np.ndarray:
        return Pose.from_quat(rng.normal(size=4) / 2.0, rng.normal(size=3)).as_matrix()

    frames = RecordedFrames(camera=OPTICAL, camera_root="camera_link", T_root_camera=T_LINK_OPTICAL,
                            static_chain=(("camera_link", OPTICAL, T_LINK_OPTICAL),), pose_frame="world")
    slz, rec = [random_pose() for _ in range(4)], [random_pose() for _ in range(4)]
    path = tmp_path / "results.mcap"
    with ResultsMcap(path, load_config(), frames) as out:
        out.write_pose(1, slz[0], 0, None)         # no recorded pose yet: no link
        out.write_pose(2, slz[1], 0, rec[1])       # segment 0's link
        out.write_pose(3, slz[2], 0, rec[2])       # already linked
        out.write_pose(4, slz[3], 1, rec[3])       # segment 1's link
    msgs = read_mcap(path)
    static = edges(msgs["/tf_static"])
    assert [e[:2] for e in static] == [("camera_link", OPTICAL), ("world", "map"), ("world", "map_1")]
    np.testing.assert_allclose(static[0][2], T_LINK_OPTICAL, atol=1e-9)
    np.testing.assert_allclose(static[1][2] @ slz[1], rec[1], atol=1e-9)
    np.testing.assert_allclose(static[2][2] @ slz[3], rec[3], atol=1e-9)
    tf = edges(msgs["/tf"])
    assert [e[:2] for e in tf] == [("map", "camera_link")] * 3 + [("map_1", f"{OPTICAL}_1")]
    np.testing.assert_allclose(tf[0][2] @ T_LINK_OPTICAL, slz[0], atol=1e-9)  # map -> link -> optical = slz pose
