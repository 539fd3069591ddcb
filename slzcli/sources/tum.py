"""TUM RGB-D benchmark folders: ``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt``.

Lists hold ``timestamp filename`` lines (``#`` comments); depth PNGs are 16-bit counts
of 1 / ``depth_scale`` metres, 0 = no data: camera.yaml's ``depth_scale`` (counts per
metre: Open3D's name, ORB-SLAM's DepthMapFactor; 1000 for the millimetre PNGs RealSense
tools write) when given, else ``sources.tum_depth_scale`` (5000 per metre in the benchmark).
Ground truth lines are ``t tx ty tz qx qy qz qw``, the colour camera's optical centre in
the world; being ground truth, it is used as the pose input only with
``sources.use_ground_truth_pose``. TUM has no intrinsics file: an optional
``camera.yaml`` in the folder (fx, fy, cx, cy, width, height [, distortion_model,
distortion, depth_scale]; any other key is refused, naming it) is read, else the camera
preset's (tum_fr1/2/3: the benchmark's published calibration, guessed from a folder name
such as rgbd_dataset_freiburg1_xyz, or --camera), else the config camera section (with a
warning). Distortion is removed from colour and depth alike (the depth is registered to
the distorted colour image by the camera's driver).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from slzcli.config import Config, read_yaml_text, safe_yaml_load, yaml_float, yaml_floats, yaml_int, yaml_mapping
from slzcli.errors import DatasetError, DecodeError, SlzError
from slzcli.sources import decode
from slzcli.sources.color_camera import ALIGNED, to_color_camera
from slzcli.sources.image_limits import FrameTooLarge, check_file
from slzcli.sources.presets import PresetChoice, choose_preset
from slzcli.sources.recording import Recording, RecordingInfo
from slzcli.sources.sync import PoseTrack, pair_stamps
from slzcli.sources.undistort import distortion_problem, has_distortion
from slzcli.sources.validate import (
    depth_shape_problem,
    intrinsics_problem,
    pixel_aspect_problem,
    pose_problem,
    size_problem,
    stamp_problem,
)
from slzcli.sources.window import WindowFilter
from slzcli.types import Frame, Intrinsics, PairingReport, StreamChoice, StreamInfo

log = logging.getLogger(__name__)
NS_PER_MS = 1_000_000
CAMERA_YAML_KEYS = ("fx", "fy", "cx", "cy", "width", "height", "distortion_model", "distortion", "depth_scale")


def parse_stamp(text: str) -> int:
    """Seconds as written ('1305031102.175304') -> integer nanoseconds, without float rounding."""
    whole, _, frac = text.strip().partition(".")
    return int(whole) * 1_000_000_000 + int((frac + "000000000")[:9] or 0) * (1 if not whole.startswith("-") else -1)


def unique_stamps(rows: list[tuple[int, str]], name: str) -> tuple[list[tuple[int, str]], list[str]]:
    """Rows with usable, distinct stamps (the first of a repeated stamp kept) and what was wrong, counted."""
    out, seen, bad, repeated, zero = [], set(), 0, 0, 0
    for stamp, file in rows:
        if stamp_problem(stamp) is not None:
            bad += 1
            continue
        zero += stamp == 0
        if stamp in seen:
            repeated += 1
            continue
        seen.add(stamp)
        out.append((stamp, file))
    n = len(rows)
    problems = [text for count, text in (
        (bad, f"{name}: {bad} of {n} stamp(s) out of range (negative or beyond 2^63 ns) were skipped"),
        (zero, f"{name}: {zero} of {n} stamp(s) are 0"),
        (repeated, f"{name}: {repeated} of {n} line(s) repeat an earlier stamp and were skipped")) if count]
    return out, problems


def read_list(path: Path, min_fields: int) -> list[list[str]]:
    """Non-comment lines of a TUM list, split on whitespace or commas; DatasetError on a short line."""
    rows = []
    from slzcli.bounds import MAX_TEXT_LIST_BYTES, read_regular

    try:
        text = read_regular(path, MAX_TEXT_LIST_BYTES, "TUM list").decode()
    except UnicodeDecodeError as err:
        raise DatasetError(path, f"not a text list (byte {err.start} is not UTF-8)") from err
    for no, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < min_fields:
            raise DatasetError(path, f"line {no}: expected {min_fields} fields, got {len(parts)}")
        rows.append(parts)
    return rows


def _depth_scale(cam_file: Path, value: object) -> float:
    """camera.yaml's ``depth_scale``: a finite number of counts per metre above 0, else DatasetError naming it."""
    try:
        scale = yaml_float(value)
    except (TypeError, ValueError) as err:
        raise DatasetError(cam_file, f"depth_scale {value!r} is not a number (counts per metre: 1000 for "
                                     "millimetre PNGs, 5000 for the TUM benchmark)") from err
    if not (np.isfinite(scale) and scale > 0):
        raise DatasetError(cam_file, f"depth_scale {value!r} must be a finite number of counts per metre above 0")
    return scale


def tum_files(folder: Path) -> list[Path]:
    """The files a TUM folder's reader reads: its lists, ``camera.yaml`` and the images the lists name (not
    the run folders or notes a user keeps beside them); a missing or malformed list adds none."""
    out = [folder / n for n in ("rgb.txt", "depth.txt", "groundtruth.txt", "camera.yaml") if (folder / n).is_file()]
    images: set[Path] = set()
    for name in ("rgb.txt", "depth.txt"):
        try:
            images.update(folder / row[1] for row in read_list(folder / name, 2))
        except (OSError, SlzError):  # the reader reports it
            continue
    return out + sorted(q for q in images if q.is_file())


class TumRecording(Recording):
    """A TUM RGB-D folder; lists are read at open, images one frame at a time."""

    def __init__(self, path: Path, config: Config) -> None:
        super().__init__(path)
        self.config = config
        self.cfg = config.sources
        self._rgb: list[tuple[int, str]] = []
        self._depth: list[tuple[int, str]] = []
        self._gt: list[tuple[int, np.ndarray]] = []
        self._intr: Intrinsics | None = None
        self._intr_source = ""
        self._depth_scale = config.sources.tum_depth_scale  # counts per metre (camera.yaml's depth_scale beats it)
        self._depth_scale_source = "sources.tum_depth_scale"
        self._pairs: list[tuple[int, int]] = []
        self._notes: list[str] = []
        self.preset = PresetChoice(None, "")
        self.camera_warnings: list[str] = []

    def _warn(self, text: str) -> None:
        """A fallback: one warning line on stderr and in RecordingInfo.warnings (run.json)."""
        if text not in self.camera_warnings:
            self.camera_warnings.append(text)
            log.warning("%s: %s", self.path, text)

    def open(self) -> None:
        for name in ("rgb.txt", "depth.txt"):
            if not (self.path / name).is_file():
                raise DatasetError(self.path, f"TUM folder without {name} "
                                              f"({'no colour' if name == 'rgb.txt' else 'no depth'} stream)")
        try:
            self._rgb = [(parse_stamp(r[0]), r[1]) for r in read_list(self.path / "rgb.txt", 2)]
            self._depth = [(parse_stamp(r[0]), r[1]) for r in read_list(self.path / "depth.txt", 2)]
            gt_file = self.path / "groundtruth.txt"
            if gt_file.is_file():
                for r in read_list(gt_file, 8):
                    T = np.eye(4)
                    T[:3, :3] = decode.quat_to_matrix(*map(float, r[4:8]))
                    T[:3, 3] = list(map(float, r[1:4]))
                    problem = pose_problem(T)
                    if problem is not None:
                        raise DecodeError(f"groundtruth.txt at {r[0]}: {problem}")
                    self._gt.append((parse_stamp(r[0]), T))
        except (ValueError, DecodeError) as err:
            raise DatasetError(self.path, f"malformed TUM list ({err})") from err
        self._rgb, rgb_problems = unique_stamps(self._rgb, "rgb.txt")
        self._depth, depth_problems = unique_stamps(self._depth, "depth.txt")
        for problem in rgb_problems + depth_problems:
            log.warning("%s: %s", self.path, problem)
            self._notes.append(problem)
        if not self._rgb:
            raise DatasetError(self.path / "rgb.txt", "no colour images listed")
        if not self._depth:
            raise DatasetError(self.path / "depth.txt", "no depth images listed")
        self.preset = choose_preset(self.config.camera.preset, folder=self.path)
        self._intr, self._intr_source = self._read_intrinsics()
        problem = distortion_problem(self._intr)
        if problem is not None:
            self._warn(f"{self._intr_source}: {problem}")
        elif has_distortion(self._intr):
            self._intr_source += f"; {self._intr.distortion_model} distortion removed from every frame"
        tol = int(self.cfg.sync_tolerance_ms * NS_PER_MS)
        self._pairs = pair_stamps([s for s, _ in self._rgb], [s for s, _ in self._depth], tol)

    def close(self) -> None:
        return None

    def _read_intrinsics(self) -> tuple[Intrinsics, str]:
        cam_file = self.path / "camera.yaml"
        if cam_file.is_file():
            try:
                c = yaml_mapping(safe_yaml_load(read_yaml_text(cam_file)))
                unknown = sorted(str(key) for key in c if key not in CAMERA_YAML_KEYS)
                if unknown:
                    raise DatasetError(cam_file, f"unknown key {unknown[0]!r} (keys: {', '.join(CAMERA_YAML_KEYS)})")
                k = Intrinsics(yaml_float(c["fx"]), yaml_float(c["fy"]), yaml_float(c["cx"]), yaml_float(c["cy"]),
                               yaml_int(c["width"]), yaml_int(c["height"]), str(c.get("distortion_model", "")),
                               yaml_floats(c.get("distortion", ())))
            except (yaml.YAMLError, KeyError, TypeError, ValueError, OverflowError, RecursionError) as err:
                raise DatasetError(cam_file, f"needs fx, fy, cx, cy, width, height ({err})") from err
            lim = self.cfg.intrinsics
            problem = intrinsics_problem(k, lim.min_fov_deg, lim.max_fov_deg)
            if problem is not None:
                raise DatasetError(cam_file, problem)
            problem = pixel_aspect_problem(k, lim.max_pixel_aspect)
            if problem is not None:
                self._warn(f"{cam_file.name}: {problem}")
            if "depth_scale" in c:
                self._depth_scale, self._depth_scale_source = _depth_scale(cam_file, c["depth_scale"]), str(cam_file)
            return k, str(cam_file)
        preset = self.preset.preset
        if preset is not None and preset.intrinsics is not None:
            return preset.intrinsics, f"camera preset {preset.name}"
        cam = self.config.camera
        self._warn(f"no camera.yaml and no camera preset ({self.preset.reason}): intrinsics from the config camera "
                   f"section (fx {cam.fx:g} px, {cam.width}x{cam.height}), not this camera's calibration; add "
                   "camera.yaml or use --camera tum_fr1/tum_fr2/tum_fr3")
        return Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height), "config camera section"

    def _pose_choice(self) -> StreamChoice:
        if not self._gt:
            return StreamChoice("pose", None, "no groundtruth.txt: frames carry no pose")
        if not self.cfg.use_ground_truth_pose:
            return StreamChoice("pose", None, "skipped groundtruth.txt (ground truth; set "
                                              "sources.use_ground_truth_pose to use it): frames carry no pose")
        return StreamChoice("pose", "groundtruth.txt", "TUM ground truth (sources.use_ground_truth_pose)")

    def _choices(self) -> tuple[StreamChoice, ...]:
        return (StreamChoice("color", "rgb.txt", "TUM colour list"),
                StreamChoice("depth", "depth.txt", f"TUM depth list, {self._depth_scale:g} counts per metre "
                                                   f"({self._depth_scale_source})"),
                StreamChoice("camera_info", None, f"intrinsics from {self._intr_source}"),
                self._pose_choice())

    def _report(self, without_pose: int, undecodable: int, notes: tuple[str, ...] = ()) -> PairingReport:
        n = len(self._pairs)
        read, win = self._windowed()
        window_note = win.note()
        return PairingReport(len(read), len(self._rgb) - n, len(self._depth) - n, without_pose, undecodable,
                             tuple(self._notes) + notes + ((window_note,) if window_note else ()), win.left_out)

    def _windowed(self) -> tuple[list[tuple[int, int]], WindowFilter]:
        """The pairs within sources.window (the lists are in memory: every pair is judged, none decoded)."""
        win = WindowFilter(self.config.sources.window)
        return [p for p in self._pairs if win.keep(self._rgb[p[0]][0])], win

    def _within_pixel_bound(self, rgb_name: str, depth_name: str, too_large: list[str]) -> bool:
        """Check both images' declared sizes (file headers) before reading them; warn once, then count."""
        try:
            for name, what in ((rgb_name, "colour"), (depth_name, "depth")):
                check_file(self.path / name, self.cfg.max_image_px, f"{name}: {what} image")
        except FrameTooLarge as err:
            if not too_large and not self.quiet_frames:
                log.warning("%s: %s; skipped (further frames over the bound are counted, not shown)", self.path, err)
            too_large.append(str(err))
            return False
        except DecodeError:   # neither PNG nor JPEG: not read (OpenCV would decode any size of TIFF, BMP, ...)
            if not self.quiet_frames:
                log.warning("%s: %s / %s: missing or not an 8-bit colour / 16-bit depth PNG", self.path, rgb_name,
                            depth_name)
            return False
        except OSError:
            return True   # missing: cv2.imread below says so as before
        return True

    def info(self) -> RecordingInfo:
        def stream(name: str, rows: list) -> StreamInfo:
            stamps = [r[0] for r in rows]
            return StreamInfo(name, "TUM list", len(rows), min(stamps, default=None), max(stamps, default=None))

        streams = [stream("rgb.txt", self._rgb), stream("depth.txt", self._depth)]
        if self._gt:
            streams.append(stream("groundtruth.txt", self._gt))
        all_stamps = [s for s, _ in self._rgb] + [s for s, _ in self._depth]
        return RecordingInfo(str(self.path), "tum folder", (max(all_stamps) - min(all_stamps)) * 1e-9,
                             tuple(streams), self._choices(), self._intr, self._intr_source, self._report(0, 0),
                             tuple(self.camera_warnings), self.preset.name, self.preset.reason,
                             "registered to colour by the camera's driver (TUM)")

    def pose_stamps(self, limit: int) -> list[int]:
        """The stamps of the first ``limit`` rows of groundtruth.txt when it is the pose input."""
        return [s for s, _ in self._gt[:limit]] if self._pose_choice().topic else []

    def frames(self) -> Iterator[Frame]:
        """The frames (see Recording); a configured points topic is refused here: TUM has no point clouds."""
        if self.config.slam.points_topic:
            raise DatasetError(self.path, f"slam.points_topic {self.config.slam.points_topic!r}: TUM folders carry "
                                          "no point clouds")
        return self._frames()

    def _frames(self) -> Iterator[Frame]:
        track = None
        if self._pose_choice().topic:
            track = PoseTrack(int(self.cfg.pose_tolerance_ms * NS_PER_MS))
            for stamp, T in self._gt:
                track.add(stamp, T)
        without_pose = undecodable = index = 0
        first_error = ""
        too_large: list[str] = []   # the files skipped for their size (one warning, then counted)
        assert self._intr is not None
        for i, j in self._windowed()[0]:
            stamp, rgb_name = self._rgb[i]
            if not self._within_pixel_bound(rgb_name, self._depth[j][1], too_large):
                undecodable += 1
                continue
            bgr = cv2.imread(str(self.path / rgb_name), cv2.IMREAD_COLOR)
            raw = cv2.imread(str(self.path / self._depth[j][1]), cv2.IMREAD_UNCHANGED)
            if bgr is None or raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
                undecodable += 1
                if not first_error:  # one line; the rest are counted (run.json pairing.undecodable)
                    first_error = f"{rgb_name} / {self._depth[j][1]}: missing or not an 8-bit colour / 16-bit depth PNG"
                    if not self.quiet_frames:
                        log.warning("%s: %s (further unreadable frames are counted, not shown)", self.path,
                                    first_error)
                continue
            depth = decode.depth_to_metres(raw, 1.0 / self._depth_scale, self.cfg.max_depth_m)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            problem = depth_shape_problem(depth.shape[1], depth.shape[0], rgb.shape[1], rgb.shape[0],
                                          self.cfg.intrinsics.aspect_tolerance)
            if problem is not None:
                raise DatasetError(self.path, f"frame {index} ({self._depth[j][1]}): {problem}")
            depth = decode.match_depth_to_color(depth, rgb.shape[:2])
            problem = size_problem(self._intr, rgb.shape[1], rgb.shape[0], self.cfg.intrinsics.aspect_tolerance)
            if problem is not None:
                raise DatasetError(self.path, f"frame {index} ({rgb_name}): {self._intr_source}: {problem}")
            intr = self._intr if (self._intr.width, self._intr.height) == (rgb.shape[1], rgb.shape[0]) \
                else self._intr.scaled(rgb.shape[1], rgb.shape[0])
            rgb, depth, intr = to_color_camera(rgb, depth, intr, ALIGNED)
            pose = track.at(stamp) if track is not None else None
            if track is not None and pose is None:
                without_pose += 1
            yield Frame(index, stamp, rgb, depth, intr, pose, str(self.path))
            index += 1
        notes = ((f"{undecodable - len(too_large)} of {len(self._windowed()[0])} frame(s) not readable "
                  f"(first: {first_error})",) if undecodable > len(too_large) else ())
        self.report = self._report(without_pose, undecodable, notes)
        if too_large:
            note = f"{len(too_large)} frame(s) over sources.max_image_px {self.cfg.max_image_px} px were skipped"
            self.report = replace(self.report, notes=(*self.report.notes, note))
        if index == 0 and too_large:
            raise DatasetError(self.path, f"no frame could be read: {too_large[0]}")
        if index == 0 and self._pairs:
            raise DatasetError(self.path, "no frame could be read (images missing or of the wrong kind)")
