"""Recordings whose parts disagree with each other, generated into a folder (nothing binary is committed).

Each looks well formed on its own: poses, tf, stamps, CameraInfo and images all decode. What is
wrong is that one part contradicts another (poses in millimetres against depth in metres, a
camera pose upside down against the ground it measures, ...). ``CASES[name](folder) -> path``;
``tests/top/test_consistency.py`` says what slz must do with each.

The frames: a camera 6 m above flat textured ground looking straight down, moving 0.094 m per
frame along -x (the texture rolls 2 px per frame; 0.8 x width focal length). ``POSES`` are the
true poses of that motion in REP 103 (world z up, the camera's optical frame).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
from bad_inputs import ALTITUDE_M, T0_NS, W, textured_frame
from sources_util import write_cloud

from slzcli.outputs.recording import RecordingWriter

N = 12
STEP_M = 2 * ALTITUDE_M / (0.8 * W)  # 2 px at 6 m through fx = 0.8 W
DOWN = np.diag([1.0, -1.0, -1.0])    # optical axis straight down, camera x along world x


def true_pose(i: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = DOWN
    T[:3, 3] = (-STEP_M * i, 0.0, ALTITUDE_M)
    return T


def _posed(path: Path, pose: Callable[[int], np.ndarray] = true_pose, stamp_offset_ns: int = 0,
           kind: str = "PoseStamped", n: int = N, **kw: object) -> Path:
    with RecordingWriter(path, "mcap", **kw) as w:  # type: ignore[arg-type]
        for i in range(n):
            f = textured_frame(i)
            w.write_frame(f)
            w.write_pose("/camera/pose", f.stamp_ns + stamp_offset_ns, pose(i), kind=kind)  # type: ignore[arg-type]
    return path


def poses_right(folder: Path) -> Path:
    """The reference: poses that agree with the frames."""
    return _posed(folder / "poses_right.mcap")


def poses_mm(folder: Path) -> Path:
    """Recorded poses in millimetres (the depth in metres)."""
    def mm(i: int) -> np.ndarray:
        T = true_pose(i)
        T[:3, 3] *= 1000.0
        return T
    return _posed(folder / "poses_mm.mcap", mm)


def poses_cm(folder: Path) -> Path:
    def cm(i: int) -> np.ndarray:
        T = true_pose(i)
        T[:3, 3] *= 100.0
        return T
    return _posed(folder / "poses_cm.mcap", cm)


def pose_upside_down(folder: Path) -> Path:
    """The camera pose rotated 180 deg about x: the optical axis points up, the ground is measured below."""
    def up(i: int) -> np.ndarray:
        T = true_pose(i)
        T[:3, :3] = np.eye(3)
        return T
    return _posed(folder / "upside_down.mcap", up)


def poses_body_frame(folder: Path) -> Path:
    """Poses of a body frame (x forward, z up, camera looking down along -z) given as the camera's."""
    def body(i: int) -> np.ndarray:
        T = true_pose(i)
        T[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # yaw 90 deg, z up
        return T
    return _posed(folder / "body_frame.mcap", body)


def poses_yawed(folder: Path) -> Path:
    """Poses looking down but turned 90 deg about the vertical: they move the camera sideways to what it sees."""
    yaw = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

    def turned(i: int) -> np.ndarray:
        T = true_pose(i)
        T[:3, :3] = yaw @ DOWN
        return T
    return _posed(folder / "yawed.mcap", turned)


def poses_1s_late(folder: Path) -> Path:
    """Right poses, stamped 1 s after the frames they belong to."""
    return _posed(folder / "poses_1s_late.mcap", stamp_offset_ns=1_000_000_000)


def poses_start_late(folder: Path) -> Path:
    """Right poses, on time, but only from frame 4 on (a SLAM that publishes once initialised): not a contradiction."""
    p = folder / "poses_start_late.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(N):
            f = textured_frame(i)
            w.write_frame(f)
            if i >= 4:
                w.write_pose("/camera/pose", f.stamp_ns, true_pose(i))
    return p


def pose_stamps_in_seconds(folder: Path) -> Path:
    """Pose stamps written as seconds counted in nanoseconds (1.7e9 ns) beside frame stamps in ns."""
    return _posed(folder / "pose_stamps_s.mcap", stamp_offset_ns=T0_NS // 10**9 - T0_NS)


def poses_static_frames_moving(folder: Path) -> Path:
    """Poses that stay put while the images show the camera moving 1 m."""
    def still(i: int) -> np.ndarray:
        return true_pose(0)
    return _posed(folder / "poses_still.mcap", still)


def tf_two_parents(folder: Path) -> Path:
    """/tf gives the camera frame two parents: 'world' (the right pose) and 'map' (100 m off)."""
    p = folder / "tf_two_parents.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(N):
            f = textured_frame(i)
            w.write_frame(f)
            w.write_pose("/tf", f.stamp_ns, true_pose(i), kind="tf", parent="world")
            off = true_pose(i)
            off[:3, 3] += (100.0, 100.0, 100.0)
            w.write_pose("/tf", f.stamp_ns, off, kind="tf", parent="map")
    return p


def tf_cycle(folder: Path) -> Path:
    """/tf: world -> camera, and camera -> world: a cycle."""
    p = folder / "tf_cycle.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(N):
            f = textured_frame(i)
            w.write_frame(f)
            w.write_pose("/tf", f.stamp_ns, true_pose(i), kind="tf", parent="world")
            w.write_pose("/tf", f.stamp_ns, np.linalg.inv(true_pose(i)), kind="tf",
                         parent="camera_color_optical_frame", child="world")
    return p


def tf_right(folder: Path) -> Path:
    """/tf world -> camera: the reference for the tf cases."""
    p = folder / "tf_right.mcap"
    with RecordingWriter(p, "mcap") as w:
        for i in range(N):
            f = textured_frame(i)
            w.write_frame(f)
            w.write_pose("/tf", f.stamp_ns, true_pose(i), kind="tf", parent="world")
    return p


POINTS_TOPIC = "/orb_slam3/map_points"




def _clouded(path: Path, scale: float) -> Path:
    """A hover (the camera still: no motion to measure a scale by) with poses and a recorded map cloud of the
    ground under the camera, both in metres times ``scale``."""
    gx, gy = np.meshgrid(np.linspace(-2.5, 2.5, 12), np.linspace(-2.0, 2.0, 10))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    with RecordingWriter(path, "mcap") as w:
        for i in range(N):
            still = textured_frame(0)
            f = textured_frame(i, rgb=still.rgb)
            w.write_frame(f)
            T = true_pose(0)
            T[:3, 3] *= scale
            w.write_pose("/camera/pose", f.stamp_ns, T)
            if i % 3 == 0:
                write_cloud(w, POINTS_TOPIC, f.stamp_ns, ground * scale)
    return path


def clouds_right(folder: Path) -> Path:
    return _clouded(folder / "clouds_right.mcap", 1.0)


def clouds_mm(folder: Path) -> Path:
    """A hover whose poses and map points (one SLAM's) are in millimetres: only the map points' depth shows it."""
    return _clouded(folder / "clouds_mm.mcap", 1000.0)


def _aligned(path: Path, depth_of: Callable[[np.ndarray], np.ndarray], n: int = 4) -> Path:
    with RecordingWriter(path, "mcap") as w:
        for i in range(n):
            f = textured_frame(i)
            f.depth_m[:, : W // 2] = 3.0  # a box on the left half: where depth lands matters
            w.write_raw(w.color_topic, *w.color_message(f.rgb, f.stamp_ns), f.stamp_ns)
            w.write_raw(w.depth_topic, *w.depth_message(depth_of(f.depth_m), f.stamp_ns), f.stamp_ns)
            w.write_raw(w.layout.color_info, "sensor_msgs/msg/CameraInfo", w._camera_info(f.intrinsics, f.stamp_ns),
                        f.stamp_ns)
    return path


def aligned_depth_transposed(folder: Path) -> Path:
    """Aligned depth 120x160 beside 160x120 colour: the depth image transposed."""
    return _aligned(folder / "depth_transposed.mcap", lambda d: np.ascontiguousarray(d.T))


def aligned_depth_half_width(folder: Path) -> Path:
    """Aligned depth of half the colour width, full height (every other column)."""
    return _aligned(folder / "depth_half_width.mcap", lambda d: np.ascontiguousarray(d[:, ::2]))


def aligned_depth_half_size(folder: Path) -> Path:
    """Aligned depth at half the colour size both ways (a decimated aligned stream): same shape, scaled."""
    return _aligned(folder / "depth_half_size.mcap", lambda d: np.ascontiguousarray(d[::2, ::2]))


CASES: dict[str, Callable[[Path], Path]] = {f.__name__: f for f in (
    poses_right, poses_mm, poses_cm, pose_upside_down, poses_body_frame, poses_yawed, poses_1s_late,
    poses_start_late, pose_stamps_in_seconds, poses_static_frames_moving, tf_two_parents, tf_cycle, tf_right,
    aligned_depth_transposed, aligned_depth_half_width, aligned_depth_half_size, clouds_right, clouds_mm)}


# ----------------------------------------------------------------------------- CameraInfo of another camera
OTHER_CAMERA = 0.7  # the other camera's focal length relative to the colour one (same size: same aspect ratio)


def camera_layout(path: Path, streams: dict[str, tuple[str, str]], other: str = "", n: int = 4) -> Path:
    """Colour, depth and CameraInfo topics with the header frame_id each names: ``streams`` maps a role
    (color, depth, camera_info, depth_info) to (topic, frame_id). ``other``: the role whose CameraInfo holds
    another camera's intrinsics of the same size."""
    with RecordingWriter(path, "mcap") as w:
        for i in range(n):
            f = textured_frame(i)
            s = f.stamp_ns
            for role, (topic, frame) in streams.items():
                if role == "color":
                    msgtype, msg = w.color_message(f.rgb, s)
                elif role == "depth":
                    msgtype, msg = w.depth_message(f.depth_m, s)
                else:
                    k = f.intrinsics
                    if role == other:
                        k = replace(k, fx=k.fx * OTHER_CAMERA, fy=k.fy * OTHER_CAMERA)
                    msgtype, msg = "sensor_msgs/msg/CameraInfo", w._camera_info(k, s)
                w.write_raw(topic, msgtype, replace(msg, header=replace(msg.header, frame_id=frame)), s)
    return path


RS_COLOR = ("/camera/color/image_raw", "camera_color_optical_frame")
RS_ALIGNED = ("/camera/aligned_depth_to_color/image_raw", "camera_color_optical_frame")
RS_DEPTH = ("/camera/depth/image_rect_raw", "camera_depth_optical_frame")

# The camera layouts slz knows (topic and optical frame names as each driver publishes them).
LAYOUTS: dict[str, dict[str, tuple[str, str]]] = {
    # realsense-ros 4.x, align_depth.enable: the aligned depth and its CameraInfo carry the colour optical frame
    "realsense_aligned": {"color": RS_COLOR, "depth": RS_ALIGNED,
                          "camera_info": ("/camera/aligned_depth_to_color/camera_info", "camera_color_optical_frame")},
    "realsense_aligned_and_color_info": {
        "color": RS_COLOR, "depth": RS_ALIGNED, "camera_info": ("/camera/color/camera_info", RS_COLOR[1])},
    # realsense-ros 4.x without alignment: each stream with its own CameraInfo in its own optical frame
    "realsense_raw": {"color": RS_COLOR, "depth": RS_DEPTH,
                      "camera_info": ("/camera/color/camera_info", "camera_color_optical_frame"),
                      "depth_info": ("/camera/depth/camera_info", "camera_depth_optical_frame")},
    # ZED wrapper: depth_registered is in the left camera's optical frame
    "zed": {"color": ("/zed/zed_node/rgb/image_rect_color", "zed_left_camera_optical_frame"),
            "depth": ("/zed/zed_node/depth/depth_registered", "zed_left_camera_optical_frame"),
            "camera_info": ("/zed/zed_node/rgb/camera_info", "zed_left_camera_optical_frame")},
    # depthai-ros: stereo aligned to the RGB socket carries the RGB optical frame
    "oakd": {"color": ("/oak/rgb/image_raw", "oak_rgb_camera_optical_frame"),
             "depth": ("/oak/stereo/image_raw", "oak_rgb_camera_optical_frame"),
             "camera_info": ("/oak/rgb/camera_info", "oak_rgb_camera_optical_frame"),
             "depth_info": ("/oak/stereo/camera_info", "oak_rgb_camera_optical_frame")},
    # Azure Kinect ROS driver: depth_to_rgb is in rgb_camera_link
    "azure_kinect": {"color": ("/rgb/image_raw", "rgb_camera_link"),
                     "depth": ("/depth_to_rgb/image_raw", "rgb_camera_link"),
                     "camera_info": ("/rgb/camera_info", "rgb_camera_link")},
    # librealsense's recorder: images in frame "0", CameraInfo with no frame_id
    "realsense_viewer": {"color": ("/device_0/sensor_1/Color_0/image/data", "0"),
                         "depth": ("/device_0/sensor_0/Depth_0/image/data", "0"),
                         "camera_info": ("/device_0/sensor_1/Color_0/info/camera_info", ""),
                         "depth_info": ("/device_0/sensor_0/Depth_0/info/camera_info", "")},
    # ROS 1 openni: a leading '/' on one side only
    "openni_slash": {"color": ("/camera/rgb/image_color", "/camera_rgb_optical_frame"),
                     "depth": ("/camera/depth_registered/image_raw", "/camera_rgb_optical_frame"),
                     "camera_info": ("/camera/rgb/camera_info", "camera_rgb_optical_frame")},
    # a recorder that leaves every frame_id empty
    "no_frame_ids": {"color": (RS_COLOR[0], ""), "depth": (RS_ALIGNED[0], ""),
                     "camera_info": ("/camera/color/camera_info", "")},
}


def info_of_depth_beside_color(folder: Path) -> Path:
    """The depth imager's CameraInfo (its optical frame, its focal length, the colour's size) published as the
    colour stream's, beside colour; no aligned CameraInfo."""
    return camera_layout(folder / "info_of_depth_beside_color.mcap", {
        "color": RS_COLOR, "depth": RS_ALIGNED,
        "camera_info": ("/camera/color/camera_info", "camera_depth_optical_frame")}, other="camera_info")


def depth_info_of_another_camera(folder: Path) -> Path:
    """Unaligned depth whose CameraInfo is the infrared imager's (another frame, another focal length)."""
    return camera_layout(folder / "depth_info_of_ir.mcap", {
        "color": RS_COLOR, "depth": RS_DEPTH, "camera_info": ("/camera/color/camera_info", RS_COLOR[1]),
        "depth_info": ("/camera/depth/camera_info", "camera_infra1_optical_frame")}, other="depth_info")


def info_of_the_color_camera(folder: Path) -> Path:
    """The control: the colour CameraInfo in the colour optical frame."""
    return camera_layout(folder / "info_right.mcap", {
        "color": RS_COLOR, "depth": RS_ALIGNED, "camera_info": ("/camera/color/camera_info", RS_COLOR[1])})


CASES.update({f.__name__: f for f in (info_of_depth_beside_color, depth_info_of_another_camera,
                                      info_of_the_color_camera)})
