"""``results.mcap``: one run's results as ROS 2 messages that Foxglove opens, on the recording's stamps.

Written while the run goes (one detection at a time, streamed to the MCAP writer: memory stays
bounded by one chunk), through the project's one recording writer (``outputs/recording.py``:
rosbags CDR, schemas from the ROS 2 Humble type store, atomic rename on close).

Topics. Frame ids: ``world`` is the world frame of the first SLAM map segment, ``camera`` the
optical frame of the colour camera (x right, y down, z forward). After a SLAM map reset the
poses are in a new, unrelated world frame (``slzcli.slam.segments``): map segment K >= 1 has
its own pair ``world_K`` -> ``camera_K`` (``frame_ids``), so /tf is a forest of one tree per
segment and nothing is drawn in a frame it is not in; pick the segment's ``world_K`` as the
3D panel's fixed frame. The committed site is in its segment's frames (run.json
``summary.slam`` names the run's segment).

    /slz/color                      sensor_msgs/Image rgb8       every detection frame
    /slz/camera_info                sensor_msgs/CameraInfo       of the depth image the maps are on
    /slz/maps/<name>                sensor_msgs/Image mono8      round(255 * map); depth_variance,
                                                                 flatness, inclination, steepness
    /slz/score                      sensor_msgs/Image mono8      round(255 * score)
    /slz/overlay                    sensor_msgs/Image rgb8       mask tint, SLAM points, Eq. 10 square
    /slz/mask                       sensor_msgs/PointCloud2      safe pixels back-projected (camera)
    /slz/map_points                 sensor_msgs/PointCloud2      the keyframe's SLAM map points (world)
    /slz/candidates                 sensor_msgs/PointCloud2      map points under the mask (world),
                                                                 field ``cluster`` = k-means label
    /slz/site                       visualization_msgs/MarkerArray   this detection's site and square
    /slz/landing_site               visualization_msgs/MarkerArray   the committed site (landing.json)
    /slz/camera_pose                geometry_msgs/PoseStamped    every tracked frame (world)
    /tf                             tf2_msgs/TFMessage           world -> camera (world_K -> camera_K in
                                                                 map segment K), every tracked frame

Images are mono8 so that a script gets the values back (value = byte / 255); the overlay is
the picture to look at. Frames without a pose have no /tf, so their clouds stay in ``camera``.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np

from slzcli.config import Config
from slzcli.geometry import back_project_every
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.recording import CAMERA_INFO, IMAGE, RecordingWriter, TopicLayout

WORLD_FRAME = "world"
CAMERA_FRAME = "camera"
TOPIC = "/slz"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
FLOAT32 = 7  # sensor_msgs/PointField FLOAT32
BYTE_MAX = 255.0  # mono8 full scale: a map value v in [0, 1] is written as round(v * 255)

# Display styling of the site markers (Foxglove draws them; no result depends on these).
SQUARE_LINE_M = 0.05       # line width of the Eq. 10 square
CENTRE_DIAMETER_M = 0.25   # sphere at the site centre
TEXT_HEIGHT_M = 0.4        # label height
TEXT_LIFT_M = 0.5          # label above the centre
ACCEPTED_RGBA = (0.15, 0.85, 0.2, 1.0)
REJECTED_RGBA = (1.0, 0.6, 0.1, 1.0)
COMMITTED_RGBA = (0.1, 0.5, 1.0, 1.0)
MARKER = {"SPHERE": 2, "LINE_STRIP": 4, "TEXT_VIEW_FACING": 9}  # visualization_msgs/Marker types
MARKER_ADD = 0


def frame_ids(segment: int) -> tuple[str, str]:
    """(world, camera) frame ids of a SLAM map segment: ``world``/``camera`` for the first, ``_K`` suffixed after."""
    if segment == 0:
        return WORLD_FRAME, CAMERA_FRAME
    return f"{WORLD_FRAME}_{segment}", f"{CAMERA_FRAME}_{segment}"


class ResultsMcap:
    """An open ``results.mcap``: poses and per-detection messages as they come, the committed site at the end."""

    def __init__(self, path: Path, config: Config) -> None:
        self.path = Path(path)
        self.stride_px = config.output.mask_cloud_stride_px
        self.writer = RecordingWriter(self.path, "mcap", layout=TopicLayout(frame_id=CAMERA_FRAME))

    def __enter__(self) -> ResultsMcap:
        self.writer.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.writer.__exit__(exc_type, exc, tb)

    # ------------------------------------------------------------------ per detection
    def write_detection(self, det: Any, overlay: np.ndarray | None = None) -> None:
        """The images, clouds and site markers of one detection (a ``pipeline.Detection``); ``overlay``: its
        overlay when the caller drew it already (overlay.png is the same picture)."""
        frame, stamp = det.frame, det.frame.stamp_ns
        world, camera = frame_ids(det.segment)
        self._image("color", frame.rgb, "rgb8", stamp, camera)
        h, w = det.score.mask.shape
        self._raw("camera_info", CAMERA_INFO, self._camera_info(frame.intrinsics.scaled(w, h), stamp, camera), stamp)
        for name, values in det.maps.as_dict().items():
            self._image(f"maps/{name}", mono8(values), "mono8", stamp, camera)
        self._image("score", mono8(det.score.score), "mono8", stamp, camera)
        bgr = detection_overlay_bgr(det) if overlay is None else overlay
        self._image("overlay", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), "rgb8", stamp, camera)
        xyz_cam = back_project_every(det.frame.depth_m, frame.intrinsics, self.stride_px)
        safe = det.score.mask[::self.stride_px, ::self.stride_px] & np.all(np.isfinite(xyz_cam), axis=2)
        self._cloud("mask", xyz_cam[safe], camera, stamp)
        sel = det.selection
        if det.points is not None:
            self._cloud("map_points", det.points.xyz_world, world, stamp)
        if sel is not None and det.points is not None:
            kept = np.asarray(sel.kept, dtype=bool)
            self._cloud("candidates", det.points.xyz_world[kept], world, stamp,
                        cluster=np.asarray(sel.labels)[kept])
        if sel is not None and sel.site is not None:
            site = sel.site
            colour = ACCEPTED_RGBA if site.accepted else REJECTED_RGBA
            label = f"score {site.score:.2f}" + ("" if site.accepted else f" ({site.acceptance_reason})")
            self._markers("site", site, colour, label, stamp, world)

    # ------------------------------------------------------------------ end of run
    def write_pose(self, stamp: int, T: np.ndarray | None, segment: int = 0) -> None:
        """The camera pose of one tracked frame (PoseStamped and /tf, in its map segment's frames), as it is
        tracked: the file stays in time order and a long run holds no list of poses to write at its end."""
        if T is None:
            return
        world, camera = frame_ids(segment)
        self.writer.write_pose(f"{TOPIC}/camera_pose", stamp, T, "PoseStamped", world, camera)
        self.writer.write_pose("/tf", stamp, T, "tf", world, camera)

    def write_run(self, committed: dict[str, Any] | None) -> None:
        """The committed site (known at the end of the run)."""
        if committed is not None:
            site = committed["site"]
            label = (f"landing site: score {site.score:.2f}, seen in {committed['support']} of "
                     f"{committed['detections']} detections")
            self._markers("landing_site", site, COMMITTED_RGBA, label, committed["frame"].stamp_ns,
                          frame_ids(committed["segment"])[0])

    # ------------------------------------------------------------------ messages
    def _raw(self, name: str, msgtype: str, msg: Any, stamp: int) -> None:
        self.writer.write_raw(f"{TOPIC}/{name}", msgtype, msg, stamp)

    def _image(self, name: str, pixels: np.ndarray, encoding: str, stamp: int, camera: str) -> None:
        data = np.ascontiguousarray(pixels, dtype=np.uint8)
        h, w = data.shape[:2]
        msg = self.writer.message(IMAGE, header=self.writer.header(stamp, camera), height=h, width=w,
                                  encoding=encoding, is_bigendian=0, step=data.size // h, data=data.reshape(-1))
        self._raw(name, IMAGE, msg, stamp)

    def _camera_info(self, k: Any, stamp: int, camera: str) -> Any:
        t = self.writer.typestore.types
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        p = np.array([[k.fx, 0, k.cx, 0], [0, k.fy, k.cy, 0], [0, 0, 1, 0]], dtype=np.float64).reshape(-1)
        return t[CAMERA_INFO](header=self.writer.header(stamp, camera), height=k.height, width=k.width,
                              distortion_model="plumb_bob", d=np.zeros(5), k=k.K.reshape(-1).astype(np.float64),
                              r=np.eye(3).reshape(-1), p=p, binning_x=0, binning_y=0, roi=roi)

    def _cloud(self, name: str, xyz: np.ndarray, frame_id: str, stamp: int, **extra: np.ndarray) -> None:
        msg = point_cloud(self.writer, np.asarray(xyz), frame_id, stamp, **extra)
        self._raw(name, POINT_CLOUD, msg, stamp)

    def _markers(self, name: str, site: Any, rgba: tuple[float, ...], label: str, stamp: int, world: str) -> None:
        self._raw(name, MARKER_ARRAY, site_markers(self.writer, site, rgba, label, stamp, name, world), stamp)


class NoResults:
    """Stands in for ``ResultsMcap`` when ``output.results_mcap`` is off: writes nothing."""

    def __enter__(self) -> NoResults:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def write_detection(self, det: Any, overlay: np.ndarray | None = None) -> None:
        return None

    def write_pose(self, stamp: int, T: np.ndarray | None, segment: int = 0) -> None:
        return None

    def write_run(self, committed: dict[str, Any] | None) -> None:
        return None


def open_results(run_dir: Path, config: Config) -> ResultsMcap | NoResults:
    """The results writer of a run folder (use it as a context manager: aborted on an exception)."""
    return ResultsMcap(Path(run_dir) / "results.mcap", config) if config.output.results_mcap else NoResults()


# ----------------------------------------------------------------------------- message builders
def mono8(values: np.ndarray) -> np.ndarray:
    """A map in [0, 1] as bytes: round(255 * v); NaN (no data) -> 0."""
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float32), nan=0.0), 0.0, 1.0)
    return np.rint(v * BYTE_MAX).astype(np.uint8)


def point_cloud(writer: RecordingWriter, xyz: np.ndarray, frame_id: str, stamp: int, **extra: np.ndarray) -> Any:
    """An unorganised little-endian float32 PointCloud2 with x, y, z and one float32 field per ``extra``."""
    names = ("x", "y", "z", *extra)
    columns = [xyz.reshape(-1, 3).astype("<f4"), *(np.asarray(v, dtype="<f4").reshape(-1, 1) for v in extra.values())]
    data = np.ascontiguousarray(np.hstack(columns), dtype="<f4")
    n, step = data.shape[0], 4 * len(names)
    t = writer.typestore.types
    fields = [t["sensor_msgs/msg/PointField"](name=nm, offset=4 * i, datatype=FLOAT32, count=1)
              for i, nm in enumerate(names)]
    return t[POINT_CLOUD](header=writer.header(stamp, frame_id), height=1, width=n, fields=fields,
                          is_bigendian=False, point_step=step, row_step=step * n,
                          data=data.reshape(-1).view(np.uint8), is_dense=True)


def site_markers(writer: RecordingWriter, site: Any, rgba: tuple[float, ...], label: str, stamp: int,
                 ns: str, world: str = WORLD_FRAME) -> Any:
    """The site as three markers in ``world`` (its segment's): the closed Eq. 10 square, a centre sphere, a label."""
    t = writer.typestore.types
    gm = "geometry_msgs/msg/"
    colour = t["std_msgs/msg/ColorRGBA"](*map(float, rgba))
    centre = np.asarray(site.center_world, dtype=np.float64)
    corners = np.asarray(site.corners_world, dtype=np.float64)[[0, 1, 3, 2, 0]]  # ++, +-, --, -+ and close
    header = writer.header(stamp, world)

    def marker(mid: int, kind: str, position: np.ndarray, scale: tuple[float, float, float],
               points: np.ndarray | None = None, text: str = "") -> Any:
        pose = t[gm + "Pose"](position=t[gm + "Point"](*map(float, position)),
                              orientation=t[gm + "Quaternion"](0.0, 0.0, 0.0, 1.0))
        return t["visualization_msgs/msg/Marker"](
            header=header, ns=ns, id=mid, type=MARKER[kind], action=MARKER_ADD, pose=pose,
            scale=t[gm + "Vector3"](*scale), color=colour,
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
            points=[t[gm + "Point"](*map(float, p)) for p in ([] if points is None else points)], colors=[],
            texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=header, format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text=text, mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False)

    up = np.array([0.0, 0.0, TEXT_LIFT_M])
    return t[MARKER_ARRAY](markers=[
        marker(0, "LINE_STRIP", np.zeros(3), (SQUARE_LINE_M, 0.0, 0.0), corners),
        marker(1, "SPHERE", centre, (CENTRE_DIAMETER_M,) * 3),
        marker(2, "TEXT_VIEW_FACING", centre + up, (0.0, 0.0, TEXT_HEIGHT_M), text=label),
    ])
