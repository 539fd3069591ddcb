"""The real ORB-SLAM3 (RGB-D, or monocular as in the paper) through the optional ``pyorbslam3`` wheel
(GPL-3.0: ``slz[orbslam3]``).

The native library runs in a worker process (a fresh interpreter) fed over a socket: a crash there (a bad
vocabulary, an assertion in the native code) becomes an ``SlzError`` naming the cause instead
of killing the batch. The vocabulary is validated before the native loader sees it.
pyorbslam3 reports neither keyframes nor map point identities, so keyframes are chosen by
``slam.keyframe`` (motion / tracked ratio) and map point ids are -1; a map point's pixel is its
projection through the tracked pose.

Monocular (``slam.orbslam3.sensor: monocular``, the paper's sec. 2.2): ORB-SLAM3 sees the colour image
only and its map has an arbitrary scale. The paper does not say how it fixed the scale; slz measures it
from the recording's depth at the tracked map points: per frame the median of measured depth over map
depth (at least ``scale_min_points`` points), per map segment the median of those per-frame values so
far, applied to the pose's translation and the map points. Until a segment has a scale its frames have
no (metric) pose.

A monocular map starts from two views (ORB-SLAM3's TwoViewReconstruction) and needs parallax (1 deg at the
50th point) and relief in view: it takes the fundamental matrix unless the homography scores over half
(RH > 0.50), over near-planar ground seen straight down RH sits just under 0.5 (0.47-0.49 measured), and F is
degenerate on a plane. On the synth transects it started on 18 of 24 flights, never over flat grass
(docs/METHOD.md 2.2, benchmarks/monocular_init.py). slz warns after ``init_warn_frames`` frames without a map,
and again at the end of a run that never had one.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import mmap
import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections import deque
from multiprocessing.connection import Connection
from pathlib import Path
from typing import IO, TYPE_CHECKING, Literal

import numpy as np

from slzcli.errors import SlzError
from slzcli.geometry import project
from slzcli.slam.base import BackendBase, MapPoints, TrackingState, TrackResult
from slzcli.slam.keyframes import is_new_keyframe
from slzcli.slam.orbslam3_worker import SLOTS, frame_bytes, frame_views
from slzcli.slam.vocabulary import DEFAULT_VOCABULARY, read_vocabulary
from slzcli.types import Frame, Intrinsics

if TYPE_CHECKING:
    from slzcli.config import OrbCfg, SlamCfg

log = logging.getLogger(__name__)
_WORKER = Path(__file__).with_name("orbslam3_worker.py")   # run as a script: see its docstring
# Process housekeeping, not tuning: how long to wait for a worker that was told to stop or died.
_EXIT_GRACE_S = 5.0
# A new ORB-SLAM3 map starts at exactly the identity pose; this tolerance only absorbs float noise.
_IDENTITY_ATOL = 1e-9
# Camera.fps where the frame rate is unknown (a one-frame recording; frames fed in without a recording):
# ORB-SLAM3's own value when the settings give none (Tracking.cc, ParseCamParamFile: fps 0 -> 30)
UNKNOWN_RATE_FPS = 30.0

# ORB-SLAM3 Tracking::eTrackingState values -> our coarse state.
_STATES = {-1: TrackingState.INITIALISING, 0: TrackingState.INITIALISING, 1: TrackingState.INITIALISING,
           2: TrackingState.OK, 3: TrackingState.LOST, 4: TrackingState.LOST, 5: TrackingState.OK}


# What the worker sends back: started, a tracked frame (state, pose or None, tracked points, map points,
# its own ms), the native code's error text, or closed.
Reply = (tuple[Literal["ready"], None] | tuple[Literal["closed"], None] | tuple[Literal["error"], str]
         | tuple[Literal["ok"], int, np.ndarray | None, int, np.ndarray, float])


class SlamWorkerError(SlzError):
    """The ORB-SLAM3 worker failed or died."""


def available() -> bool:
    """True when the optional pyorbslam3 wheel is importable (checked without loading the native code)."""
    return importlib.util.find_spec("pyorbslam3") is not None


def settings_yaml(K: Intrinsics, orb: OrbCfg, close_depth_m: float, baseline_m: float, fps: float) -> str:
    """An ORB-SLAM3 v1.0 settings file for an undistorted RGB-D camera with metric float depth.

    Every ``Viewer.*`` key must be present even without a viewer, or the native code exits; their
    values are ORB-SLAM3's example values and have no effect without a viewer. No distortion:
    slz assumes rectified images (types.Intrinsics).
    ``Stereo.ThDepth`` is in baselines: close points (full RGB-D constraints) reach close_depth_m.
    """
    return "\n".join([
        "%YAML:1.0", 'File.version: "1.0"', 'Camera.type: "PinHole"',
        f"Camera1.fx: {K.fx:.6f}", f"Camera1.fy: {K.fy:.6f}", f"Camera1.cx: {K.cx:.6f}", f"Camera1.cy: {K.cy:.6f}",
        "Camera1.k1: 0.0", "Camera1.k2: 0.0", "Camera1.p1: 0.0", "Camera1.p2: 0.0",
        f"Camera.width: {K.width}", f"Camera.height: {K.height}", f"Camera.fps: {max(1, round(fps))}",
        "Camera.RGB: 1",
        f"Stereo.ThDepth: {close_depth_m / baseline_m:.6f}", f"Stereo.b: {baseline_m:.6f}",
        "RGBD.DepthMapFactor: 1.0",
        f"ORBextractor.nFeatures: {orb.n_features}", f"ORBextractor.scaleFactor: {orb.scale_factor:.6f}",
        f"ORBextractor.nLevels: {orb.n_levels}", f"ORBextractor.iniThFAST: {orb.fast_threshold}",
        f"ORBextractor.minThFAST: {orb.fast_min_threshold}",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8",
        "Viewer.ViewpointF: 500.0", "Viewer.imageViewScale: 1.0", "",
    ])


def depth_for_tracker(depth_m: np.ndarray, out: np.ndarray) -> None:
    """Depth as ORB-SLAM3 reads it, written into ``out`` (float32): it takes a depth <= 0 as none, so NaN (no
    measurement) and anything below zero become 0, and +inf the largest float32 (a far point, not a NaN in its
    back-projection)."""
    np.fmin(np.fmax(depth_m, 0.0, out=out), np.finfo(np.float32).max, out=out)


def _anonymous_file(size: int) -> int:
    """A file descriptor of ``size`` bytes that lives in memory only and has no name to leak if a process dies
    (Linux's memfd; an unlinked temporary file elsewhere)."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("slz-orbslam3-frame")
    else:
        with tempfile.TemporaryFile() as f:
            fd = os.dup(f.fileno())
    try:
        os.ftruncate(fd, size)
    except OSError:
        os.close(fd)
        raise
    return fd


class OrbSlam3Backend(BackendBase):
    """ORB-SLAM3 in RGB-D mode, or monocular with the scale from depth (monocular can report OK on a wrong
    trajectory over planar ground: the paper's mode, kept for comparison)."""

    name = "orbslam3"
    in_flight = SLOTS   # one frame tracked, the next waiting in the worker's socket: it never idles between them

    def __init__(self, slam: SlamCfg, vocabulary: str | Path | None = None) -> None:
        if not available():
            raise SlzError("slam.backend: orbslam3 needs the optional pyorbslam3 package "
                           "(pip install 'slz[orbslam3]'; GPL-3.0)")
        cfg = slam
        path = Path(vocabulary or cfg.vocabulary or DEFAULT_VOCABULARY)
        read_vocabulary(path)  # validate before the native loader trusts it
        self.vocab_path = str(path)
        self.cfg = cfg
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._log: IO[bytes] | None = None
        self._intrinsics: Intrinsics | None = None
        self._last_kf_pose: np.ndarray | None = None
        self._last_kf_tracked = 0
        self._keyframe: MapPoints | None = None
        self._n_keyframes = 0
        self._segment = 0
        self._was_ok = False
        self._ever_ok = False
        self.monocular = cfg.orbslam3.sensor == "monocular"
        self._scales: dict[int, list[float]] = {}   # monocular: per map segment, each frame's measured scale
        self._frames_uninitialised = 0
        self._uninitialised_span_ns: tuple[int, int] | None = None   # first and last stamp without a map
        self._source = ""
        self._warned_init = False
        self._track_ms: float | None = None  # the worker's own time for the last frame
        self._ready = False  # the worker said it loaded the vocabulary
        self._buf: mmap.mmap | None = None   # the frame buffer shared with the worker (orbslam3_worker.frame_views)
        self._views: list[tuple[np.ndarray, np.ndarray]] = []   # its slots
        self._in_worker: deque[Frame] = deque()   # submitted, not yet collected (oldest first)
        self._slot = 0   # the slot the next frame is written to

    # -- worker plumbing
    def prepare(self, intrinsics: Intrinsics) -> None:
        """Start the worker now, for frames of ``intrinsics``: it loads the vocabulary while the run is still being
        set up, and the first frame waits only for what is left (a worker prepared for other intrinsics than the
        frames' is replaced then)."""
        if self._proc is None:
            self._spawn(intrinsics)

    def _spawn(self, intrinsics: Intrinsics) -> None:
        """The worker process, sent its settings; not waited for (``_start``)."""
        self._intrinsics = intrinsics
        period = self.cfg.orbslam3.nominal_period_s   # "auto" is resolved from the recording (with_frame_period)
        fps = UNKNOWN_RATE_FPS if period == "auto" else 1.0 / period
        text = settings_yaml(intrinsics, self.cfg.orb, self.cfg.orbslam3.close_depth_m,
                             self.cfg.orbslam3.baseline_m, fps)
        ours, theirs = socket.socketpair()
        size = SLOTS * frame_bytes(intrinsics.height, intrinsics.width)
        buf_fd = _anonymous_file(size)
        # ORB-SLAM3 prints progress to stdout; keep it off ours (--json) and keep stderr for the cause.
        self._log = tempfile.TemporaryFile(mode="w+b")  # noqa: SIM115  # lives as long as the worker; _stop closes it
        try:
            self._proc = subprocess.Popen([sys.executable, str(_WORKER), str(theirs.fileno()), str(buf_fd)],
                                          pass_fds=(theirs.fileno(), buf_fd), stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=self._log)
            self._buf = mmap.mmap(buf_fd, size)
        finally:
            os.close(buf_fd)   # the mappings (ours, the worker's) keep the memory; it goes with the last
            theirs.close()
        self._views = frame_views(self._buf, intrinsics.height, intrinsics.width)
        self._conn = Connection(ours.detach())
        self._conn.send(("init", self.vocab_path, text, self.cfg.orbslam3.sensor,
                         (intrinsics.height, intrinsics.width)))

    def _start(self, frame: Frame) -> None:
        """The worker ready for ``frame``'s camera: the prepared one, or a new one."""
        if any(frame.intrinsics.distortion):
            log.warning("%s: camera distortion %s ignored; ORB-SLAM3 is run as an undistorted pinhole",
                        frame.source or "recording", frame.intrinsics.distortion_model or "coefficients")
        if self._proc is not None and frame.intrinsics != self._intrinsics:
            log.debug("orbslam3: the worker was prepared for other intrinsics than the frames'; starting another")
            self._stop()
        if self._proc is None:
            self._spawn(frame.intrinsics)
        kind, detail = self._recv(f"starting on {frame.source or 'the recording'} (loading the vocabulary)",
                                  self.cfg.orbslam3.load_timeout_s)[:2]
        if kind == "error":
            self._stop()
            raise SlamWorkerError(f"{self.vocab_path}: ORB-SLAM3 failed to start on {frame.source or 'the recording'}: "
                                  f"{detail}")
        self._ready = True

    def _recv(self, doing: str, timeout_s: float) -> Reply:
        conn, proc = self._conn, self._proc
        assert conn is not None and proc is not None  # _start opened both
        try:
            if conn.poll(timeout_s):
                reply: Reply = conn.recv()
                return reply
        except (EOFError, OSError):
            pass
        try:
            code = proc.wait(timeout=_EXIT_GRACE_S)
        except subprocess.TimeoutExpired:
            code = None
        last = self._last_log_line()
        self._stop()
        said = f"; it said: {last}" if last else ""
        if code is None:
            raise SlamWorkerError(f"ORB-SLAM3 worker did not answer within {timeout_s:g} s while {doing} "
                                  f"(vocabulary {self.vocab_path}){said}")
        cause = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
        raise SlamWorkerError(f"ORB-SLAM3 worker died ({cause}) while {doing} (vocabulary {self.vocab_path}){said}")

    def _last_log_line(self) -> str:
        if self._log is None:
            return ""
        self._log.seek(0)
        lines = [ln.strip() for ln in self._log.read().decode(errors="replace").splitlines() if ln.strip()]
        return lines[-1][:200] if lines else ""

    def _stop(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(timeout=_EXIT_GRACE_S)
        self._proc = None
        self._ready = False
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._log is not None:
            self._log.close()
            self._log = None
        self._views = []
        self._in_worker.clear()
        if self._buf is not None:
            self._buf.close()
            self._buf = None

    def abort(self) -> None:
        """Kill the worker: after an error it may be stuck in the very call that failed."""
        self._stop()

    def close(self) -> None:
        self._say_never_initialised()
        proc, conn = self._proc, self._conn
        if proc is not None and conn is not None and proc.poll() is None:
            try:
                conn.send(("close",))
                if conn.poll(self.cfg.orbslam3.load_timeout_s):
                    conn.recv()
                proc.wait(timeout=_EXIT_GRACE_S)
            except (EOFError, OSError, subprocess.TimeoutExpired):
                pass
        self._stop()

    # -- tracking
    def track(self, frame: Frame) -> TrackResult:
        if self._in_worker:   # collect would answer for the oldest frame in the worker, not for this one
            raise RuntimeError(f"orbslam3: frame {self._in_worker[0].index} was submitted and never collected")
        self.submit(frame)
        return self.collect()

    def submit(self, frame: Frame) -> None:
        """Send the frame to the worker and return at once: it tracks while the caller computes (``collect``); with
        one frame still in the worker, this one waits in its socket and is tracked right after."""
        if len(self._in_worker) >= self.in_flight:
            raise RuntimeError(f"orbslam3: frame {self._in_worker[0].index} was submitted and never collected")
        if not self._ready:
            self._start(frame)
        elif frame.intrinsics != self._intrinsics:
            raise SlzError(f"{frame.source or 'recording'}: frame {frame.index} has other intrinsics than the first "
                           "frame; ORB-SLAM3 is configured once per run")
        assert self._conn is not None and self._views  # _start opened them
        # the slot of the frame SLOTS submissions ago, which was collected: the worker copied it out long since
        slot = self._slot
        rgb, depth = self._views[slot]
        if frame.rgb.shape != rgb.shape or (not self.monocular and frame.depth_m.shape != depth.shape):
            raise SlzError(f"{frame.source or 'recording'}: frame {frame.index} is {frame.rgb.shape[1]}x"
                           f"{frame.rgb.shape[0]} px (depth {frame.depth_m.shape[1]}x{frame.depth_m.shape[0]}), its "
                           f"camera {rgb.shape[1]}x{rgb.shape[0]}: ORB-SLAM3 is configured for the camera's size")
        self._slot = (slot + 1) % SLOTS
        np.copyto(rgb, frame.rgb)
        if not self.monocular:
            depth_for_tracker(frame.depth_m, depth)
        with contextlib.suppress(BrokenPipeError, OSError):  # _recv reports how the worker died
            self._conn.send(("track", slot, not self.monocular, frame.stamp_ns * 1e-9))
        self._in_worker.append(frame)

    def last_track_ms(self) -> float | None:
        return self._track_ms

    def collect(self) -> TrackResult:
        if not self._in_worker:
            raise RuntimeError("orbslam3: collect() without a submitted frame")
        frame = self._in_worker.popleft()
        reply = self._recv(f"tracking frame {frame.index} of {frame.source or 'the recording'}",
                           self.cfg.orbslam3.frame_timeout_s)
        if reply[0] != "ok":  # the native tracker threw: the worker is alive, the frame is not usable
            h, w = frame.rgb.shape[:2]
            raise SlamWorkerError(f"{frame.source or 'recording'}: ORB-SLAM3 cannot track frame {frame.index} "
                                  f"({w}x{h} px): {reply[1]}; try --set slam.backend=odometry")
        _, state_code, pose, n_tracked, pts, self._track_ms = reply
        state = _STATES.get(state_code, TrackingState.LOST)
        if state is not TrackingState.OK:
            pose = None  # RECENTLY_LOST carries a motion-model guess; not a measurement
        self._keyframe = None
        is_kf = False
        if (pose is not None and self._ever_ok and not self._was_ok
                and np.allclose(pose, np.eye(4), atol=_IDENTITY_ATOL)):
            # ORB-SLAM3 started a new map (Atlas) at the identity: a new world frame.
            self._segment += 1
            self._last_kf_pose = None
        self._was_ok = pose is not None
        self._ever_ok |= self._was_ok
        if self.monocular:
            pose, pts = self._metric(frame, pose, pts)
        if pose is not None:
            kf = self.cfg.keyframe
            is_kf = is_new_keyframe(self._last_kf_pose, pose, n_tracked, self._last_kf_tracked,
                                    kf.min_translation_m, kf.min_rotation_deg, kf.min_tracked_ratio)
            if is_kf:
                uv, ok = project(pts, pose, frame.K, (frame.intrinsics.height, frame.intrinsics.width))
                self._keyframe = MapPoints(np.full(int(ok.sum()), -1, np.int64), pts[ok], uv[ok],
                                           self._n_keyframes, frame.stamp_ns, pose)
                self._n_keyframes += 1
                self._last_kf_pose, self._last_kf_tracked = pose, n_tracked
        return TrackResult(frame.index, frame.stamp_ns, state, pose, is_kf, n_tracked, self._segment)

    def keyframe(self) -> MapPoints | None:
        return self._keyframe

    def _metric(self, frame: Frame, pose: np.ndarray | None,
                pts: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
        """Monocular: the pose and map points in metres (see the module docstring), or no pose yet."""
        if pose is None:
            if not self._ever_ok:
                self._frames_uninitialised += 1
                self._source = frame.source or "recording"
                first = frame.stamp_ns if self._uninitialised_span_ns is None else self._uninitialised_span_ns[0]
                self._uninitialised_span_ns = (first, frame.stamp_ns)
                if self._frames_uninitialised >= self.cfg.orbslam3.init_warn_frames and not self._warned_init:
                    self._warned_init = True
                    log.warning("%s: monocular ORB-SLAM3 has not initialised after %d frames: a monocular map needs "
                                "the camera to move sideways (parallax); a hover or a straight descent gives too "
                                "little. Use --set slam.orbslam3.sensor=rgbd (depth starts the map at once)",
                                frame.source or "recording", self._frames_uninitialised)
            return None, pts
        ratio = monocular_scale(pose, pts, frame.depth_m, frame.K, self.cfg.orbslam3.scale_min_points)
        seen = self._scales.setdefault(self._segment, [])
        if ratio is not None:
            seen.append(ratio)
        if not seen:
            return None, pts  # no frame of this map has measured its scale yet: no metric pose
        scale = float(np.median(seen))
        metric = pose.copy()
        metric[:3, 3] *= scale
        return metric, pts * scale


    def _say_never_initialised(self) -> None:
        """At the end of a monocular run that never had a map: one warning saying so, why, and what to do."""
        if not self.monocular or self._ever_ok or not self._frames_uninitialised or self._uninitialised_span_ns is None:
            return
        first, last = self._uninitialised_span_ns
        n = self._frames_uninitialised
        self._frames_uninitialised = 0   # said once, even if close() is called again
        log.warning("%s: monocular ORB-SLAM3 never initialised (%d frames, %.1f s), so no pose and no detection: "
                    "it starts a map from two views and needs sideways motion (parallax; a hover or a straight "
                    "descent gives too little) over ground with some relief. Fly a transect, or use "
                    "--set slam.orbslam3.sensor=rgbd (depth starts the map at once)",
                    self._source, n, (last - first) * 1e-9)


def monocular_scale(T_world_camera: np.ndarray, points_world: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
                    min_points: int) -> float | None:
    """Metres per map unit of one frame: the median of measured depth / map depth over the tracked map
    points that project onto a pixel with depth (None: fewer than ``min_points`` such points).

    Map depth is the point's z in the camera; the measured depth is the recording's at its pixel.
    """
    pts = np.asarray(points_world, np.float64).reshape(-1, 3)
    if len(pts) < min_points:
        return None
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    cam = (pts - t) @ R                                   # R^T (p - t), row-wise
    z = cam[:, 2]
    front = z > 0
    cam, z = cam[front], z[front]
    u = np.rint(K[0, 0] * cam[:, 0] / z + K[0, 2]).astype(np.int64)
    v = np.rint(K[1, 1] * cam[:, 1] / z + K[1, 2]).astype(np.int64)
    h, w = depth_m.shape[:2]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    measured = np.full(len(z), np.nan)
    measured[inside] = depth_m[v[inside], u[inside]]
    ok = np.isfinite(measured) & (measured > 0)
    if int(ok.sum()) < min_points:
        return None
    return float(np.median(measured[ok] / z[ok]))

