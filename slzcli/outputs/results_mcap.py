"""``results.mcap``: one run's results as ROS 2 messages that Foxglove opens, on the recording's stamps.

Written while the run goes (one detection at a time, streamed to the MCAP writer: memory stays
bounded by one chunk), through the project's one recording writer (``outputs/recording.py``:
rosbags CDR, schemas from the ROS 2 Humble type store, atomic rename on close).

Topics. Frame ids (REP 105; docs/DESIGN.md "results.mcap frames"): ``map`` (``output.map_frame``)
is slz's SLAM map, the world frame of the first map segment; camera messages keep the recording's
optical frame id (the colour image's ``header.frame_id``; ``camera`` when the recording has none).
When the recording has camera poses (a pose topic slz reads), ``/tf_static`` links ``map`` to the
frame those poses are in (e.g. ``world``, ``odom``), aligned on the first frame that has both
poses; a recording whose ``/tf`` places the camera keeps doing so (slz publishes no second parent
for it), otherwise slz's ``/tf`` places it (through the camera's ``/tf_static`` chain, copied).
After a SLAM map reset the poses are in a new, unrelated world frame (``slzcli.slam.segments``):
map segment K >= 1 has its own ``map_K`` (and, where slz places the camera, ``<camera>_K``), with
its own link when there are recorded poses; without them /tf is a forest of one tree per segment
and nothing is drawn in a frame it is not in. The committed site is in its segment's frames
(run.json ``summary.slam`` names the run's segment).

    /slz/color/compressed           sensor_msgs/CompressedImage  every detection frame, JPEG
    /slz/camera_info                sensor_msgs/CameraInfo       of the depth image the maps are on
    /slz/maps/<name>                sensor_msgs/Image mono8      round(255 * map); depth_variance,
                                                                 flatness, inclination, steepness
    /slz/score                      sensor_msgs/Image mono8      round(255 * score)
    /slz/overlay/compressed         sensor_msgs/CompressedImage  mask tint, SLAM points, Eq. 10 square, JPEG
    /slz/mask                       sensor_msgs/PointCloud2      safe pixels back-projected (camera)
    /slz/map_points                 sensor_msgs/PointCloud2      the keyframe's SLAM map points (map)
    /slz/candidates                 sensor_msgs/PointCloud2      map points under the mask (map),
                                                                 field ``cluster`` = k-means label
    /slz/site                       visualization_msgs/MarkerArray   this detection's site and square
    /slz/funnel                     std_msgs/String              what each filter left (run.json funnel's
                                                                 row of the frame, JSON)
    /slz/landing_site               visualization_msgs/MarkerArray   the committed site (landing.json)
    /slz/landing_map                foxglove_msgs/Grid           methods with a landing map (fused): per detection
                                                                 the cells it judged (map), at the end the flight's
                                                                 (= landing_map.npz); fields below
    /slz/camera_pose                geometry_msgs/PoseStamped    every tracked frame (map)
    /tf                             tf2_msgs/TFMessage           map -> camera (map_K -> camera_K in map
                                                                 segment K), every tracked frame, unless
                                                                 the recording's /tf places the camera
    /tf_static                      tf2_msgs/TFMessage           <pose frame> -> map_K once per segment;
                                                                 the camera's static chain (copied)

The maps and the score are raw mono8 images so that a script gets the values back exactly
(value = byte / 255). The colour image and the overlay are pictures to look at, written as JPEG
(``JPEG_QUALITY``) on ``<topic>/compressed`` as image_transport names them: the exact colour is in
the recording, the exact overlay in ``frames/NNNNNN/overlay.png`` (``output.level`` maps or all).
Chunks are LZ4-compressed (``CHUNK_COMPRESSION``). Why (benchmarks/writes.py, a 640x480 detection
frame): raw rgb8 colour and overlay were 1.8 MB of the 3.4 MB a frame wrote, and mcap's default
zstd took ~44 ms a frame over chunks of camera images that it shrank by a third; JPEG takes ~2 ms
an image for ~1/5 of the bytes, LZ4 ~1/10 of zstd's time. PNG maps (lossless too) would cost
~18 ms a frame to encode against ~2 ms of LZ4 over the raw bytes, so they stay raw. Frames without
a pose have no /tf, so their clouds stay in the camera frame.

The landing map is a ``foxglove_msgs/msg/Grid`` (ROS 2 CDR like every message here; the definitions of
foxglove/schemas ``ros_foxglove_msgs/ros2``, registered by name, ``FOXGLOVE_MSGS``): Foxglove's 3D panel
draws a Grid in its colours without configuration when it has ``red``, ``green``, ``blue`` and ``alpha``
fields (its "RGBA (separate fields)" mode, chosen automatically), so the verdict shows in the palette of
every slz picture, unseen cells transparent; the values ride beside them, ``GRID_FIELDS``: ``score`` (first:
older Foxglove colours the first field with its colour map), ``height_m``, ``height_std_m``, ``looks`` (float32,
NaN unseen) and ``verdict`` (uint8: 0 unseen, 1 unsafe, 2 undecided, 3 safe; landing_map.npz's
``verdict_names``). A nav_msgs/OccupancyGrid holds one int8 per cell
(0-100, drawn as a grey ramp): none of these values, none of these colours. Rows are world y from the
grid's pose (the south-west corner of cell (0, 0): landing_map.npz's ``origin_xy``; z the median fused
height, display only), columns x, cell size the map's resolution. Per detection the grid is the square
the fused method judged around the camera (cropped to its seen cells); the run's last message is the
whole map of the last map segment, stamped with the last frame fused, and equals landing_map.npz.
Cost (benchmarks/landing_grid.py): the cells cropped ~0.4 ms a detection (in the background writer, when
results.mcap is written: the detection carries how to build them), the message built and written there ~5 ms
CPU (most of it LZ4 over its bytes, 24 a cell).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from types import TracebackType

import cv2
import numpy as np
from rosbags.interfaces.typing import Typesdict
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from slzcli.config import Config
from slzcli.errors import ConfigError, OutputError
from slzcli.funnel import frame_funnel
from slzcli.geometry import Pose, back_project_every, invert_pose
from slzcli.outputs import palette
from slzcli.outputs.landing_map import verdict_lut
from slzcli.outputs.overlay import detection_overlay_bgr
from slzcli.outputs.recording import (
    CAMERA_INFO,
    COMPRESSED,
    IMAGE,
    POSE_TYPES,
    RecordingWriter,
    RosMessage,
    TopicLayout,
)
from slzcli.types import CommittedSite, Detection, Intrinsics, LandingGrid, RecordedFrames, Site

log = logging.getLogger(__name__)
MAP_FRAME = "map"  # REP 105; output.map_frame
CAMERA_FRAME = "camera"  # the camera's frame id when the recording names none (TUM folders)
TOPIC = "/slz"
POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
STRING = "std_msgs/msg/String"
FLOAT32 = 7  # sensor_msgs/PointField FLOAT32
BYTE_MAX = 255.0  # mono8 full scale: a map value v in [0, 1] is written as round(v * 255)
# The colour image and the overlay (pictures, module docstring): OpenCV's default JPEG quality, the one `slz synth
# --color-encoding jpeg` writes too; ~2 ms and ~0.2 MB for a 640x480 image (benchmarks/writes.py).
JPEG_QUALITY = 95
CHUNK_COMPRESSION = "lz4"  # module docstring; RecordingWriter's ``compression``

# Display styling of the site markers (Foxglove draws them; no result depends on these).
SQUARE_LINE_M = 0.05       # line width of the Eq. 10 square
CENTRE_DIAMETER_M = 0.25   # sphere at the site centre
TEXT_HEIGHT_M = 0.4        # label height
TEXT_LIFT_M = 0.5          # label above the centre
ACCEPTED_RGBA = palette.rgba01(palette.SAFE)      # a site that passed the acceptance test: the verdict colours
REJECTED_RGBA = palette.rgba01(palette.UNSAFE)    # of every picture (outputs/palette.py)
COMMITTED_RGBA = palette.rgba01(palette.SITE)     # the committed site: the overlay's square
MARKER = {"SPHERE": 2, "LINE_STRIP": 4, "TEXT_VIEW_FACING": 9}  # visualization_msgs/Marker types
MARKER_ADD = 0

GRID = "foxglove_msgs/msg/Grid"
# foxglove/schemas ros_foxglove_msgs/ros2 (comments dropped): Foxglove knows these by their names.
FOXGLOVE_MSGS = {
    "foxglove_msgs/msg/Vector2": "float64 x\nfloat64 y\n",
    "foxglove_msgs/msg/PackedElementField": (
        "string name\nuint32 offset\nuint8 UNKNOWN=0\nuint8 UINT8=1\nuint8 INT8=2\nuint8 UINT16=3\n"
        "uint8 INT16=4\nuint8 UINT32=5\nuint8 INT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nuint8 type\n"),
    GRID: ("builtin_interfaces/Time timestamp\nstring frame_id\ngeometry_msgs/Pose pose\nuint32 column_count\n"
           "foxglove_msgs/Vector2 cell_size\nuint32 row_stride\nuint32 cell_stride\n"
           "foxglove_msgs/PackedElementField[] fields\nuint8[] data\n"),
}
PACKED_TYPE = {"u1": 1, "<f4": 7}  # PackedElementField.UINT8, FLOAT32
# One cell of /slz/landing_map: (name, byte offset, type), little-endian, 24 bytes (the float32 fields aligned,
# 3 bytes of padding at the end).
GRID_LAYOUT = (("score", 0, "<f4"), ("height_m", 4, "<f4"), ("height_std_m", 8, "<f4"), ("looks", 12, "<f4"),
               ("verdict", 16, "u1"), ("red", 17, "u1"), ("green", 18, "u1"), ("blue", 19, "u1"), ("alpha", 20, "u1"))
GRID_FIELDS = np.dtype({"names": [n for n, _, _ in GRID_LAYOUT], "formats": [f for _, _, f in GRID_LAYOUT],
                        "offsets": [o for _, o, _ in GRID_LAYOUT], "itemsize": 24})
OPAQUE, CLEAR = 255, 0   # alpha of a seen cell, of an unseen one
DISPLAY_STRIDE = 4       # the grid's display height is the median of every 4th row and column's heights


def map_frame_of(segment: int, map_frame: str = MAP_FRAME) -> str:
    """The frame id of a SLAM map segment's world: ``map`` for the first, ``map_K`` after a reset."""
    return map_frame if segment == 0 else f"{map_frame}_{segment}"


def frame_ids(segment: int, map_frame: str = MAP_FRAME, camera: str = CAMERA_FRAME) -> tuple[str, str]:
    """(map, camera) frame ids of a SLAM map segment where slz places the camera: ``_K`` suffixed after the first."""
    return map_frame_of(segment, map_frame), camera if segment == 0 else f"{camera}_{segment}"


def check_map_frame(name: str) -> str:
    """``output.map_frame``: a tf frame id (no spaces, no leading '/'), ConfigError otherwise."""
    if not name or name != name.strip() or " " in name or name.startswith("/"):
        raise ConfigError("output.map_frame", f"{name!r} is not a tf frame id (non-empty, no spaces, no leading /)")
    return name


class ResultsMcap:
    """An open ``results.mcap``: poses and per-detection messages as they come, the committed site at the end.

    ``frames``: the recording's own frame ids (``Recording.recorded_frames``), which the camera
    keeps and the map is linked to (module docstring).
    """

    def __init__(self, path: Path, config: Config, frames: RecordedFrames | None = None) -> None:
        self.path = Path(path)
        self.stride_px = config.output.mask_cloud_stride_px
        self.rec = frames or RecordedFrames()
        self.map_frame = check_map_frame(config.output.map_frame)
        self.camera = self.rec.camera or CAMERA_FRAME
        self.links: dict[int, np.ndarray] = {}  # map segment -> T_<pose frame>_<map_K>, as written to /tf_static
        self.link_parent = self.rec.pose_frame
        taken = {self.rec.camera, self.rec.camera_root, self.rec.pose_frame, *(e[0] for e in self.rec.static_chain)}
        if self.map_frame in taken:
            log.warning("%s: the recording has its own frame %r: slz's map is not linked to it (set output.map_frame "
                        "to another name, e.g. slz_map)", self.path.parent.name, self.map_frame)
            self.link_parent = ""
        self.writer = RecordingWriter(self.path, "mcap", layout=TopicLayout(frame_id=self.camera),
                                      compression=CHUNK_COMPRESSION)
        register_foxglove(self.writer.typestore)

    def __enter__(self) -> ResultsMcap:
        self.writer.open()
        self._static_chain()
        return self

    def frame_ids(self, segment: int) -> tuple[str, str]:
        """(map, camera) frame ids of the messages of one map segment (the camera's: see the module docstring)."""
        if self.rec.tf_places_camera:
            return map_frame_of(segment, self.map_frame), self.camera
        return frame_ids(segment, self.map_frame, self.camera)

    def _static_chain(self) -> None:
        """The camera's /tf_static chain from the recording, the same edges (so no frame gets a second parent)."""
        if self.rec.tf_places_camera or not self.rec.static_chain:
            return
        self._tf("/tf_static", 0, [(parent, child, T) for parent, child, T in self.rec.static_chain])

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.writer.__exit__(exc_type, exc, tb)

    # ------------------------------------------------------------------ per detection
    def write_detection(self, det: Detection, overlay: np.ndarray | None = None) -> None:
        """The images, clouds and site markers of one detection (a ``pipeline.Detection``); ``overlay``: its
        overlay when the caller drew it already (overlay.png is the same picture)."""
        frame, stamp = det.frame, det.frame.stamp_ns
        world, camera = self.frame_ids(det.segment)
        self._jpeg("color", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR), stamp, camera)
        h, w = det.score.mask.shape
        self._raw("camera_info", CAMERA_INFO, self._camera_info(frame.intrinsics.scaled(w, h), stamp, camera), stamp)
        for name, values in det.maps.as_dict().items():
            self._image(f"maps/{name}", mono8(values), "mono8", stamp, camera)
        self._image("score", mono8(det.score.score), "mono8", stamp, camera)
        bgr = detection_overlay_bgr(det) if overlay is None else overlay
        self._jpeg("overlay", bgr, stamp, camera)
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
        row = json.dumps(frame_funnel(det).as_dict(), separators=(",", ":"))
        self._raw("funnel", STRING, self.writer.message(STRING, data=row), stamp)
        if det.landing_grid is not None:
            self.write_landing_grid(det.landing_grid())

    def write_landing_grid(self, grid: LandingGrid) -> None:
        """A landing map on ``/slz/landing_map`` at its own stamp, in its map segment's frame."""
        msg = grid_message(self.writer, grid, self.frame_ids(grid.segment)[0])
        self._raw("landing_map", GRID, msg, grid.stamp_ns)

    # ------------------------------------------------------------------ end of run
    def write_pose(self, stamp: int, T: np.ndarray | None, segment: int = 0,
                   recorded: np.ndarray | None = None) -> None:
        """The camera pose of one tracked frame (PoseStamped and /tf, in its map segment's frames), as it is
        tracked: the file stays in time order and a long run holds no list of poses to write at its end.

        ``recorded``: the frame's recorded camera pose in the recording's pose frame; the first one of a
        segment fixes that segment's link ``<pose frame> -> map_K`` on /tf_static.
        """
        if T is None:
            return
        world, camera = self.frame_ids(segment)
        self.writer.write_pose(f"{TOPIC}/camera_pose", stamp, T, "PoseStamped", world, camera)
        if recorded is not None and self.link_parent and segment not in self.links:
            self.links[segment] = np.asarray(recorded, np.float64) @ invert_pose(T)
            self._tf("/tf_static", stamp, [(self.link_parent, world, self.links[segment])])
        if self.rec.tf_places_camera:
            return
        if segment == 0 and self.rec.T_root_camera is not None:  # the root of the camera's static chain
            self.writer.write_pose("/tf", stamp, T @ invert_pose(self.rec.T_root_camera), "tf", world,
                                   self.rec.camera_root)
        else:
            self.writer.write_pose("/tf", stamp, T, "tf", world, camera)

    def _tf(self, topic: str, stamp: int, edges: list[tuple[str, str, np.ndarray]]) -> None:
        """One TFMessage of (parent, child, T_parent_child) transforms."""
        t = self.writer.typestore.types
        gm = "geometry_msgs/msg/"
        out = []
        for parent, child, T in edges:
            q = Pose.from_matrix(np.asarray(T, np.float64)).as_quat()
            tr = t[gm + "Transform"](translation=t[gm + "Vector3"](*map(float, T[:3, 3])),
                                     rotation=t[gm + "Quaternion"](*map(float, q)))
            out.append(t[gm + "TransformStamped"](header=self.writer.header(stamp, parent), child_frame_id=child,
                                                  transform=tr))
        self.writer.write_raw(topic, POSE_TYPES["tf"], t[POSE_TYPES["tf"]](transforms=out), stamp)

    def write_run(self, committed: CommittedSite | None, landing_grid: LandingGrid | None = None) -> None:
        """The committed site (known at the end of the run) and the flight's landing map, when the method has one."""
        if landing_grid is not None:
            self.write_landing_grid(landing_grid)
        if committed is not None:
            site = committed.site
            label = (f"landing site: score {site.score:.2f}, seen in {committed.support} of "
                     f"{committed.detections} detections")
            self._markers("landing_site", site, COMMITTED_RGBA, label, committed.frame.stamp_ns,
                          self.frame_ids(committed.segment)[0])

    # ------------------------------------------------------------------ messages
    def _raw(self, name: str, msgtype: str, msg: RosMessage, stamp: int) -> None:
        self.writer.write_raw(f"{TOPIC}/{name}", msgtype, msg, stamp)

    def _image(self, name: str, pixels: np.ndarray, encoding: str, stamp: int, camera: str) -> None:
        data = np.ascontiguousarray(pixels, dtype=np.uint8)
        h, w = data.shape[:2]
        msg = self.writer.message(IMAGE, header=self.writer.header(stamp, camera), height=h, width=w,
                                  encoding=encoding, is_bigendian=0, step=data.size // h, data=data.reshape(-1))
        self._raw(name, IMAGE, msg, stamp)

    def _jpeg(self, name: str, bgr: np.ndarray, stamp: int, camera: str) -> None:
        """A BGR picture as a JPEG CompressedImage on ``<name>/compressed`` (image_transport's format string)."""
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise OutputError(self.path, f"OpenCV could not encode the {name} image as JPEG")
        msg = self.writer.message(COMPRESSED, header=self.writer.header(stamp, camera),
                                  format="bgr8; jpeg compressed bgr8", data=buf.reshape(-1))
        self._raw(f"{name}/compressed", COMPRESSED, msg, stamp)

    def _camera_info(self, k: Intrinsics, stamp: int, camera: str) -> RosMessage:
        t = self.writer.typestore.types
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        p = np.array([[k.fx, 0, k.cx, 0], [0, k.fy, k.cy, 0], [0, 0, 1, 0]], dtype=np.float64).reshape(-1)
        return t[CAMERA_INFO](header=self.writer.header(stamp, camera), height=k.height, width=k.width,
                              distortion_model="plumb_bob", d=np.zeros(5), k=k.K.reshape(-1).astype(np.float64),
                              r=np.eye(3).reshape(-1), p=p, binning_x=0, binning_y=0, roi=roi)

    def _cloud(self, name: str, xyz: np.ndarray, frame_id: str, stamp: int, **extra: np.ndarray) -> None:
        msg = point_cloud(self.writer, np.asarray(xyz), frame_id, stamp, **extra)
        self._raw(name, POINT_CLOUD, msg, stamp)

    def _markers(self, name: str, site: Site, rgba: tuple[float, ...], label: str, stamp: int, world: str) -> None:
        self._raw(name, MARKER_ARRAY, site_markers(self.writer, site, rgba, label, stamp, name, world), stamp)


class NoResults:
    """Stands in for ``ResultsMcap`` when ``output.results_mcap`` is off: writes nothing."""

    def __enter__(self) -> NoResults:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def write_detection(self, det: Detection, overlay: np.ndarray | None = None) -> None:
        return None

    def write_pose(self, stamp: int, T: np.ndarray | None, segment: int = 0,
                   recorded: np.ndarray | None = None) -> None:
        return None

    def write_run(self, committed: CommittedSite | None, landing_grid: LandingGrid | None = None) -> None:
        return None


def open_results(run_dir: Path, config: Config, frames: RecordedFrames | None = None) -> ResultsMcap | NoResults:
    """The results writer of a run folder (use it as a context manager: aborted on an exception)."""
    if not config.output.results_mcap:
        return NoResults()
    return ResultsMcap(Path(run_dir) / "results.mcap", config, frames)



# ----------------------------------------------------------------------------- message builders
def register_foxglove(typestore: Typestore) -> None:
    """The foxglove_msgs this file writes, in a rosbags typestore (to write results.mcap or to read it)."""
    if GRID not in typestore.fielddefs:
        types: Typesdict = {}
        for name, text in FOXGLOVE_MSGS.items():
            types.update(get_types_from_msg(text, name))
        typestore.register(types)


def results_typestore() -> Typestore:
    """A typestore that reads every message of a results.mcap (ROS 2 Humble and the foxglove_msgs above)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    register_foxglove(store)
    return store


def grid_cells(grid: LandingGrid) -> np.ndarray:
    """The grid's cells as ``GRID_FIELDS`` records (row j = y, column i = x), colours from the verdict.

    Built as six float32 words a cell, the last two (bytes 16-23: verdict, red, green, blue, alpha, padding)
    gathered as one uint64 per cell from a table per verdict code: 1.6 ms CPU for 347 x 347 cells where
    assigning the nine record fields one by one took 3.7 ms (benchmarks/landing_grid.py, a loaded machine)."""
    tail = np.zeros((len(grid.verdict_names), 8), np.uint8)
    tail[:, 0] = np.arange(len(grid.verdict_names))
    tail[:, 1:4] = verdict_lut(grid.verdict_names)
    tail[:, 4] = OPAQUE
    if "unseen" in grid.verdict_names:
        tail[grid.verdict_names.index("unseen"), 4] = CLEAR
    words = np.empty((*grid.shape, GRID_FIELDS.itemsize // 4), np.float32)
    words[..., 0] = grid.score
    words[..., 1] = grid.height_m
    np.sqrt(grid.variance_m2, out=words[..., 2])
    words[..., 3] = grid.looks
    words.view(np.uint64)[..., 2] = tail.view("<u8")[:, 0][grid.verdict]
    return words.view(GRID_FIELDS)[..., 0]


def grid_message(writer: RecordingWriter, grid: LandingGrid, frame_id: str) -> RosMessage:
    """A foxglove_msgs/Grid of the landing map: pose at the south-west corner of cell (0, 0), z the median
    fused height (display only, so that the grid lies on the ground: the heights are in ``height_m``)."""
    t = writer.typestore.types
    gm = "geometry_msgs/msg/"
    cells = grid_cells(grid)
    sample = grid.height_m[::DISPLAY_STRIDE, ::DISPLAY_STRIDE]     # a median of 1/16 of the cells: ~0.1 ms
    heights = sample[np.isfinite(sample)]
    z = float(np.median(heights)) if heights.size else 0.0
    pose = t[gm + "Pose"](position=t[gm + "Point"](float(grid.origin_xy[0]), float(grid.origin_xy[1]), z),
                          orientation=t[gm + "Quaternion"](0.0, 0.0, 0.0, 1.0))
    field = t["foxglove_msgs/msg/PackedElementField"]
    fields = [field(name=name, offset=offset, type=PACKED_TYPE[kind]) for name, offset, kind in GRID_LAYOUT]
    stamp = t["builtin_interfaces/msg/Time"](sec=int(grid.stamp_ns // 1_000_000_000),
                                             nanosec=int(grid.stamp_ns % 1_000_000_000))
    nx = grid.shape[1]
    return t[GRID](timestamp=stamp, frame_id=frame_id, pose=pose, column_count=nx,
                   cell_size=t["foxglove_msgs/msg/Vector2"](float(grid.resolution_m), float(grid.resolution_m)),
                   row_stride=nx * GRID_FIELDS.itemsize, cell_stride=GRID_FIELDS.itemsize, fields=fields,
                   data=cells.reshape(-1).view(np.uint8))


def mono8(values: np.ndarray) -> np.ndarray:
    """A map in [0, 1] as bytes: round(255 * clip(v, 0, 1)); NaN (no data) -> 0.

    In place on one float32 buffer (~0.5 ms at 640x480 against ~0.9 ms with nan_to_num and clip, the same bytes):
    fmax/fmin return the other operand where one is NaN, so NaN becomes 0; clipping after the scaling gives the
    same float32 as before it, 255 * 1.0 being exact."""
    with np.errstate(over="ignore", invalid="ignore"):  # huge values become inf, then 255; NaN becomes 0
        v = np.multiply(np.asarray(values), np.float32(BYTE_MAX), dtype=np.float32)
        np.fmax(v, np.float32(0.0), out=v)
        np.fmin(v, np.float32(BYTE_MAX), out=v)
        np.rint(v, out=v)
    return v.astype(np.uint8)


def point_cloud(writer: RecordingWriter, xyz: np.ndarray, frame_id: str, stamp: int, **extra: np.ndarray) -> RosMessage:
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


def site_markers(writer: RecordingWriter, site: Site, rgba: tuple[float, ...], label: str, stamp: int,
                 ns: str, world: str = MAP_FRAME) -> RosMessage:
    """The site as three markers in ``world`` (a map segment's frame): the Eq. 10 square, a centre sphere, a label."""
    t = writer.typestore.types
    gm = "geometry_msgs/msg/"
    colour = t["std_msgs/msg/ColorRGBA"](*map(float, rgba))
    centre = np.asarray(site.center_world, dtype=np.float64)
    corners = np.asarray(site.corners_world, dtype=np.float64)[[0, 1, 3, 2, 0]]  # ++, +-, --, -+ and close
    header = writer.header(stamp, world)

    def marker(mid: int, kind: str, position: np.ndarray, scale: tuple[float, float, float],
               points: np.ndarray | None = None, text: str = "") -> RosMessage:
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
