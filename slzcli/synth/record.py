"""Scene + flight -> RGB-D recording + ground-truth sidecar + preview: what ``slz synth`` runs.

Frames are rendered one at a time and streamed to the ``RecordingWriter``; their per-frame
truth (masks, object ids) is streamed to ``.npy`` spool files, so memory holds one frame, not
N. The spools then go into the sidecar (``<out>.gt.npz`` + ``<out>.gt.json``, see
datasets/GROUND_TRUTH.md). All of it is written into a staging folder beside the output and
moved into place at the end (``synthesize``), then a contact sheet.
Everything is seeded: the same scene, options and seed give the same bytes.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import cv2
import numpy as np

from slzcli import bounds, fingerprint
from slzcli.config import CameraCfg, Config, ScenariosCfg, SensorCfg
from slzcli.errors import ConfigError, OutputError
from slzcli.outputs import files, run_lock, safe_output
from slzcli.outputs.recording import FORMATS, RecordingWriter
from slzcli.synth.flight import Flight, PathKind, make_flight
from slzcli.synth.geometry import SceneMeshes, build_meshes
from slzcli.synth.groundtruth import (
    BINDING_KEY,
    GT_FORMAT,
    GT_VERSION,
    STORED_MEMBERS,
    SafetyRaster,
    compute_raster,
    pixel_safe_mask,
    raster_arrays,
    sidecar_paths,
)
from slzcli.synth.imu import imu_track
from slzcli.synth.preview import SheetRow, contact_sheet
from slzcli.synth.render import Renderer
from slzcli.synth.scenes import Scene, load_scene
from slzcli.synth.sensor import DepthSensor, apply_color_model, get_depth_sensor
from slzcli.types import Frame, Intrinsics

log = logging.getLogger(__name__)

GT_POSE_TOPIC = "/ground_truth/camera_pose"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera_color_optical_frame"
SUFFIX_OF_FORMAT = {"mcap": ".mcap", "mcap-ros1": ".mcap", "ros1": ".bag"}   # ros2-*: a bag folder
_RAY_TOP_CLEARANCE_M = 1.0           # raster rays start this far above the highest vertex


@dataclass(frozen=True)
class SynthOptions:
    """What to render: scene (``name[:variants]``), flight and sensor seed, output format."""

    scene: str
    frames: int
    rate_hz: float
    path: PathKind
    seed: int
    start_m: tuple[float, float, float] | None          # None: the scene's default scenario
    variants: tuple[str, ...] = ()
    fmt: str = "mcap"
    color_encoding: str = "rgb8"
    depth_encoding: str = "16UC1"


@dataclass(frozen=True, eq=False)
class World:
    """A loaded scene ready to render: meshes, raycaster, the safety raster and the depth sensor."""

    scene: Scene
    meshes: SceneMeshes
    renderer: Renderer
    raster: SafetyRaster
    intrinsics: Intrinsics
    depth_sensor: DepthSensor


@dataclass(frozen=True, eq=False)
class SynthFrame:
    frame: Frame               # what the recording holds (noisy depth, 8-bit colour, true pose)
    safe: np.ndarray           # bool HxW ground-truth safe mask
    object_id: np.ndarray      # uint16 HxW
    depth_true_m: np.ndarray   # float32 HxW exact depth (NaN = nothing hit)
    normal_world: np.ndarray   # float32 HxWx3


def scenario_start(scenarios: ScenariosCfg, scenario: int) -> tuple[float, float, float]:
    """The paper's start position of scenario 1..4 (``synth.scenarios``)."""
    if scenario not in (1, 2, 3, 4):
        raise ConfigError("--scenario", f"must be 1, 2, 3 or 4, got {scenario}")
    start = getattr(scenarios, f"s{scenario}_m")
    return float(start[0]), float(start[1]), float(start[2])


def intrinsics_of(c: CameraCfg) -> Intrinsics:
    return Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height)


def build_world(scene: Scene, config: Config) -> World:
    """Meshes, raycaster and the ground-truth safety raster of a scene."""
    meshes = build_meshes(scene, config.synth.embed_m)
    bounds.check(bounds.synth_sizes(config, meshes.extent_xy))   # raster cells, before the rays are cast
    renderer = Renderer(scene, meshes, config.synth.light)
    top = max(float(p.vertices[:, 2].max()) for p in meshes.parts) + _RAY_TOP_CLEARANCE_M
    landable = np.array([p.landable for p in meshes.parts], dtype=bool)
    objects = np.array([p.object_id for p in meshes.parts], dtype=np.uint16)
    raster = compute_raster(renderer.cast, meshes.extent_xy, top, landable, objects, config.uav,
                            config.synth.ground_truth)
    intr = intrinsics_of(config.camera)
    return World(scene, meshes, renderer, raster, intr, get_depth_sensor(config.synth.sensor, renderer, intr))


def seeds(seed: int) -> tuple[int, np.random.Generator]:
    """Independent streams for the flight wobble and the sensor noise from one user seed."""
    flight_ss, sensor_ss = np.random.SeedSequence(seed).spawn(2)
    return int(flight_ss.generate_state(1)[0]), np.random.default_rng(sensor_ss)


def render_frames(world: World, flight: Flight, sensor: SensorCfg, sensor_rng: np.random.Generator,
                  source: str = "") -> Iterator[SynthFrame]:
    """Render, apply the sensor model (``synth.sensor``) and attach the truth, one frame at a time."""
    for i, (stamp, T) in enumerate(zip(flight.stamps_ns, flight.T_world_camera, strict=True)):
        r = world.renderer.render(T, world.intrinsics)
        depth = world.depth_sensor.measure(r.depth_m, T, sensor_rng)
        rgb = apply_color_model(r.rgb, sensor, sensor_rng)
        frame = Frame(index=i, stamp_ns=int(stamp), rgb=rgb, depth_m=depth, intrinsics=world.intrinsics,
                      T_world_camera=T.copy(), source=source)
        yield SynthFrame(frame, pixel_safe_mask(world.raster, r.point_world, r.hit), r.object_id,
                         r.depth_m, r.normal_world)


def synthesize(out: Path, options: SynthOptions, config: Config, preview: Path | None = None,
               progress: Callable[[int, int], None] | None = None, force: bool = False) -> dict[str, Any]:
    """Render ``options.frames`` frames to a recording at ``out``; write the truth sidecar and preview.

    Everything is written into a staging folder beside ``out`` (``.OUT.<random>.tmp``) and moved into
    place at the end, the ground truth's header last: the old header goes first, so at no moment is
    a recording paired with another recording's truth. ``force`` replaces an existing recording (a
    file, or a rosbag2 folder holding nothing but the bag), never a folder with other files in it.
    One writer per output (``run_lock``); the temporaries of a killed synth are removed by the next.
    """
    if options.fmt not in FORMATS:
        raise ConfigError("--format", f"must be one of {', '.join(FORMATS)}; got {options.fmt!r}")
    out = Path(out)
    want = SUFFIX_OF_FORMAT.get(options.fmt, "")
    if out.suffix.lower() != want and (want or out.suffix.lower() in (".mcap", ".bag")):
        raise OutputError(out, f"--format {options.fmt} needs "
                               f"{'a name ending in ' + want if want else 'a folder name without .mcap/.bag'} "
                               "(readers guess the format from the path)")
    check_replaceable(out, options.fmt, force)
    bounds.check(bounds.synth_frames(config, options.frames))
    scene = load_scene(options.scene, options.variants)
    if options.start_m is None:
        options = dataclasses.replace(options, start_m=scenario_start(config.synth.scenarios, scene.scenario))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(out.parent, f"cannot create folder ({err.strerror})") from err
    preview_path = preview if preview is not None else Path(str(out).rstrip("/\\") + ".preview.png")
    check_companions(out, preview_path, force)
    with run_lock.claim(out, leftovers=run_lock.SYNTH_LEFTOVERS):
        check_replaceable(out, options.fmt, force)  # again, now that no other synth writes it
        check_companions(out, preview_path, force)
        stage = safe_output.make_temp_dir(out, ".tmp")
        try:
            summary, sheet = _render_into(stage, out, options, scene, config, progress)
            # the preview is made before the install (a failed preview leaves no new recording) and
            # renamed into place after it (a failed install leaves the old preview)
            with files.atomic_path(preview_path) as preview_tmp:
                _write_png(preview_tmp, sheet)
                _install(stage, out)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    log.info("synth: %s (%d frames of %s), ground truth %s, preview %s", out, options.frames, scene.name,
             summary["ground_truth"], preview_path)
    return {**summary, "preview": str(preview_path)}


def check_replaceable(out: Path, fmt: str, force: bool) -> None:
    """OutputError unless ``out`` is free, or ``force`` and it is a recording slz may replace."""
    if not os.path.lexists(out):
        return
    if not force:
        raise OutputError(out, "already exists (use --force to replace it)")
    if fmt.startswith("ros2"):
        if not out.is_dir():
            raise OutputError(out, f"exists and is not a folder; --format {fmt} writes a rosbag2 folder here")
        other = sorted(p.name for p in out.iterdir() if p.name != "metadata.yaml" and not p.name.endswith(BAG_SUFFIXES))
        if other or not (out / "metadata.yaml").is_file():
            why = f"holds {other[0]}" if other else "has no metadata.yaml"
            raise OutputError(out, f"is not a rosbag2 bag folder ({why}); --force replaces only a recording: "
                                   "move it away or choose another -o")
    elif out.is_dir():
        raise OutputError(out, f"is a folder; --format {fmt} writes a file: choose another -o")
    else:
        safe_output.check_file(out, force=True, ours=safe_output.is_recording_file, label="a recording (MCAP or "
                               "ROS 1 bag)")


def check_companions(out: Path, preview: Path, force: bool) -> None:
    """The files written beside the recording (truth sidecar, preview) follow the same rule as it: none
    of them is another output or an existing file slz cannot tell is its own of that kind."""
    npz, header = sidecar_paths(out)
    safe_output.distinct({"-o": out, "the ground truth": npz, "the ground-truth header": header,
                          "--contact-sheet": preview})
    safe_output.check_file(npz, force=force, ours=safe_output.is_ground_truth_arrays,
                           label="a ground-truth sidecar (.gt.npz)")
    safe_output.check_file(header, force=force, ours=lambda p: safe_output.is_json_of_format(p, GT_FORMAT),
                           label="a ground-truth header (.gt.json)")
    safe_output.check_file(preview, force=force, ours=safe_output.is_slz_png, label="a preview PNG",
                           option="--contact-sheet")


BAG_SUFFIXES = (".db3", ".db3-shm", ".db3-wal", ".mcap")  # what a rosbag2 folder holds besides metadata.yaml


def _render_into(stage: Path, out: Path, options: SynthOptions, scene: Scene, config: Config,
                 progress: Callable[[int, int], None] | None) -> tuple[dict[str, Any], np.ndarray]:
    """Render the recording and its sidecar into ``stage`` under their final names; the summary and preview."""
    world = build_world(scene, config)
    flight_seed, sensor_rng = seeds(options.seed)
    assert options.start_m is not None  # synthesize() resolves the scene's default first
    flight = make_flight(options.start_m, options.frames, options.rate_hz, options.path,
                         config.synth.flight, flight_seed, config.synth.start_stamp_ns)
    sheet_rows: list[SheetRow] = []
    keep = {0, options.frames // 2}
    safe_first = float("nan")
    intr = world.intrinsics
    staged = stage / out.name
    imu = None
    if config.synth.imu.enabled:  # its own noise stream: turning it on leaves the frames' bytes as they were
        imu_rng = np.random.default_rng(np.random.SeedSequence(options.seed).spawn(3)[2])
        imu = imu_track(options.start_m, options.path, config.synth.flight, flight_seed,
                        (options.frames - 1) / options.rate_hz, config.synth.start_stamp_ns, config.synth.imu, imu_rng)
    imu_next = 0
    with TruthSpool(stage, options.frames, intr.height, intr.width) as spool:
        with RecordingWriter(staged, options.fmt, color_encoding=options.color_encoding,
                             depth_encoding=options.depth_encoding) as writer:
            for sf in render_frames(world, flight, config.synth.sensor, sensor_rng, source=str(out)):
                upto = 0 if imu is None else int(np.searchsorted(imu.stamps_ns, sf.frame.stamp_ns, side="right"))
                for k in range(imu_next, upto):  # the IMU samples up to this frame, in time order
                    assert imu is not None
                    writer.write_imu(config.synth.imu.topic, int(imu.stamps_ns[k]), imu.accel[k], imu.gyro[k],
                                     CAMERA_FRAME)
                imu_next = max(imu_next, upto)
                writer.write_frame(sf.frame)
                assert sf.frame.T_world_camera is not None  # render_frames gives every frame its pose
                writer.write_pose(GT_POSE_TOPIC, sf.frame.stamp_ns, sf.frame.T_world_camera, kind="PoseStamped",
                                  parent=WORLD_FRAME, child=CAMERA_FRAME)
                spool.add(sf.safe, sf.object_id)
                if sf.frame.index == 0:
                    safe_first = float(sf.safe.mean())
                if sf.frame.index in keep:
                    sheet_rows.append(SheetRow(sf.frame.rgb, sf.frame.depth_m, sf.object_id, sf.safe,
                                               f"{scene.name} frame {sf.frame.index}"))
                if progress is not None:
                    progress(sf.frame.index + 1, options.frames)
        objects = tuple({"id": o.id, "name": o.name, "kind": o.kind, "landable": o.landable}
                        for o in world.meshes.objects)
        header = _header(out, options, scene, world, len(flight.stamps_ns), objects, config)
        header[BINDING_KEY] = fingerprint.recording_binding(staged)  # the truth names the bytes it belongs to
        members: dict[str, np.ndarray | Path] = {
            "stamps_ns": np.asarray(flight.stamps_ns, np.int64),
            "T_world_camera": np.asarray(flight.T_world_camera, np.float64),
            **spool.members(), **raster_arrays(world.raster)}
        write_sidecar(*sidecar_paths(staged), members, header)
    summary: dict[str, Any] = {  # JSON values, for `slz synth --json` and the text
        "recording": str(out), "format": options.fmt, "scene": scene.name, "variants": list(scene.variants),
        "frames": options.frames, "rate_hz": options.rate_hz, "path": options.path, "seed": options.seed,
        "start_m": list(options.start_m or ()), "ground_truth": str(sidecar_paths(out)[0]),
        "safe_fraction_first_frame": safe_first,
        "raster_safe_fraction": float(world.raster.safe.mean()), "objects": len(world.meshes.objects)}
    return summary, contact_sheet(sheet_rows, world.raster.safe, world.raster.usable)


def _install(stage: Path, out: Path) -> None:
    """Move the staged recording and sidecar to ``out``: old header out first, new header in last."""
    npz, header = sidecar_paths(out)
    staged_npz, staged_header = sidecar_paths(stage / out.name)
    try:
        header.unlink(missing_ok=True)  # the old truth is no longer paired with anything
        if out.is_dir() and not out.is_symlink():  # a rosbag2 folder (check_replaceable let it through)
            old = safe_output.make_temp_dir(out, ".old")
            os.replace(out, old / out.name)
            os.replace(stage / out.name, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(stage / out.name, out)
        os.replace(staged_npz, npz)
        os.replace(staged_header, header)
    except OSError as err:
        raise OutputError(out, f"cannot put the recording in place ({err})") from err


class TruthSpool:
    """Per-frame truth streamed to two ``.npy`` files (bit-packed masks, object ids) in a temporary folder.

    The array shapes are known up front (N frames of H x W), so each frame is appended as it is
    rendered and nothing accumulates in memory. The folder is removed on exit.
    """

    def __init__(self, parent: Path, frames: int, height: int, width: int) -> None:
        self._parent, self._n, self._h, self._w = Path(parent), frames, height, width
        self._dir: Path | None = None
        self._files: dict[str, BinaryIO] = {}
        self.written = 0

    def __enter__(self) -> TruthSpool:
        try:
            self._dir = Path(tempfile.mkdtemp(prefix=".gt-spool-", dir=self._parent))  # the caller's staging folder
            shapes = {"safe_masks": ((self._n, self._h, (self._w + 7) // 8), np.uint8),
                      "object_ids": ((self._n, self._h, self._w), np.uint16)}
            for name, (shape, dtype) in shapes.items():
                fh = open(self._dir / f"{name}.npy", "wb")
                self._files[name] = fh
                np.lib.format.write_array_header_1_0(
                    fh, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False,
                         "shape": shape})
        except OSError as err:
            self._cleanup()
            raise OutputError(self._parent, f"cannot spool ground truth ({err})") from err
        return self

    def add(self, safe: np.ndarray, object_id: np.ndarray) -> None:
        """Append one frame's (H, W) safe mask and object ids."""
        if self.written >= self._n or safe.shape != (self._h, self._w) or object_id.shape != (self._h, self._w):
            raise ValueError(f"truth frame {self.written}: expected {self._n} frames of {self._h}x{self._w}")
        try:
            self._files["safe_masks"].write(np.packbits(safe.astype(bool), axis=-1).tobytes())
            self._files["object_ids"].write(np.ascontiguousarray(object_id, dtype=np.uint16).tobytes())
        except OSError as err:
            raise OutputError(self._dir or self._parent, f"cannot spool ground truth ({err.strerror or err})") from err
        self.written += 1

    def members(self) -> dict[str, Path]:
        """The finished spool files by member name (all N frames must have been added)."""
        if self.written != self._n or self._dir is None:
            raise ValueError(f"ground truth has {self.written} of {self._n} frames")
        for fh in self._files.values():
            fh.close()
        return {name: self._dir / f"{name}.npy" for name in self._files}

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._cleanup()

    def _cleanup(self) -> None:
        for fh in self._files.values():
            fh.close()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)


def _header(out: Path, options: SynthOptions, scene: Scene, world: World, frames: int,
            objects: tuple[dict[str, object], ...], config: Config) -> dict[str, object]:
    intr = world.intrinsics
    r = world.raster
    return {
        "format": GT_FORMAT, "version": GT_VERSION, "recording": Path(out).name,
        "scene": scene.name, "variants": list(scene.variants), "scene_file": Path(scene.source).name,
        "seed": options.seed, "frames": frames, "rate_hz": options.rate_hz, "path": options.path,
        "start_m": list(options.start_m or ()), "pose_topic": GT_POSE_TOPIC,
        "world_frame": f"{WORLD_FRAME} (ENU, z up)",
        "camera_frame": f"{CAMERA_FRAME} (optical: x right, y down, z forward)",
        "image": {"width": intr.width, "height": intr.height, "fx": intr.fx, "fy": intr.fy, "cx": intr.cx,
                  "cy": intr.cy},
        "raster": {"origin_xy": list(r.origin_xy), "resolution_m": r.resolution_m, "shape": list(r.safe.shape),
                   "row_axis": "world +y", "col_axis": "world +x"},
        "rules": {"max_slope_deg": config.uav.max_slope_deg, "footprint_m": list(config.uav.footprint_m),
                  "margin_m": config.uav.margin_m,
                  "touchdown_dispersion_m": config.uav.touchdown_dispersion_m,
                  "step_m": config.synth.ground_truth.step_m,
                  "slope_tolerance_deg": config.synth.ground_truth.slope_tolerance_deg},
        "sensor": config.to_dict()["synth"]["sensor"],
        "objects": list(objects), "config_hash": config.hash(), "config": config.to_dict(),
    }


def write_sidecar(npz_path: Path, json_path: Path, members: dict[str, np.ndarray | Path],
                  header: dict[str, object]) -> None:
    """Write ``.gt.npz`` (fixed member times: byte-identical per seed) and ``.gt.json``.

    ``members``: name -> array, or -> path of a complete ``.npy`` file (copied in chunks). Members
    in ``STORED_MEMBERS`` are stored uncompressed so that the loader can memory-map them; the
    rest are deflated.
    """
    files.write_npz_streamed(npz_path, members, stored=frozenset(STORED_MEMBERS))
    files.write_text(json_path, files.json_text(header, indent=1, sort_keys=True) + "\n")


def _write_png(path: Path, rgb: np.ndarray) -> None:
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OutputError(path, "PNG encoding failed")
    path.write_bytes(safe_output.tag_png(data.tobytes()))
