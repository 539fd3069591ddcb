"""Writers for SLAM results: trajectory.tum (``t x y z qx qy qz qw``) and keyframes.npz.

Frames without a pose are left out of the TUM file (the format has no "unknown" row).
keyframes.npz holds flat arrays: per keyframe (``kf_*``, ``kf_segment`` its SLAM map
segment) and per observed map point (``point_*``, with ``point_kf`` the row of its
keyframe), so a reader needs only numpy.

Map segments. A SLAM backend that loses tracking may start a new map in a world frame of
its own (``slzcli.slam.segments``). A TUM file holds one world frame, so there is one file
per segment rather than one file with a segment column (which evo and every other TUM
reader would take as one trajectory): ``trajectory.tum`` is the run's world frame (the
segment of the committed site, see ``segments.primary_segment``), and when the run has
more than one segment, ``trajectory.seg<K>.tum`` holds segment K, for every K (so the
primary segment is in two files, byte for byte the same). run.json ``summary.slam``
lists the segments and their files.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from slzcli.outputs.files import ArraySpool, write_npz_streamed, write_text
from slzcli.slam.base import MapPoints


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), w >= 0, of rotation matrices (N,3,3) (Shepperd's method, vectorised)."""
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    which = np.argmax(np.concatenate([tr[:, None], diag], 1), axis=1)
    q = np.zeros((len(R), 4))
    s = np.sqrt(np.maximum(1.0 + tr, 1e-12)) * 2  # which == 0
    q0 = np.stack([(R[:, 2, 1] - R[:, 1, 2]) / s, (R[:, 0, 2] - R[:, 2, 0]) / s,
                   (R[:, 1, 0] - R[:, 0, 1]) / s, s / 4], 1)
    s1 = np.sqrt(np.maximum(1.0 + R[:, 0, 0] - R[:, 1, 1] - R[:, 2, 2], 1e-12)) * 2
    q1 = np.stack([s1 / 4, (R[:, 0, 1] + R[:, 1, 0]) / s1,
                   (R[:, 0, 2] + R[:, 2, 0]) / s1, (R[:, 2, 1] - R[:, 1, 2]) / s1], 1)
    s2 = np.sqrt(np.maximum(1.0 + R[:, 1, 1] - R[:, 0, 0] - R[:, 2, 2], 1e-12)) * 2
    q2 = np.stack([(R[:, 0, 1] + R[:, 1, 0]) / s2, s2 / 4,
                   (R[:, 1, 2] + R[:, 2, 1]) / s2, (R[:, 0, 2] - R[:, 2, 0]) / s2], 1)
    s3 = np.sqrt(np.maximum(1.0 + R[:, 2, 2] - R[:, 0, 0] - R[:, 1, 1], 1e-12)) * 2
    q3 = np.stack([(R[:, 0, 2] + R[:, 2, 0]) / s3, (R[:, 1, 2] + R[:, 2, 1]) / s3,
                   s3 / 4, (R[:, 1, 0] - R[:, 0, 1]) / s3], 1)
    q = np.choose(which[:, None], [q0, q1, q2, q3])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, 3:4] < 0, -q, q)


def tum_text(stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> str:
    """TUM trajectory text of the frames that have a pose (seconds with nanosecond digits)."""
    rows = [(t, p) for t, p in zip(stamps_ns, poses, strict=True) if p is not None]
    if not rows:
        return "# timestamp tx ty tz qx qy qz qw\n"
    T = np.stack([np.asarray(p, np.float64) for _, p in rows])
    q = _quat_xyzw(T[:, :3, :3])
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for (t, _), xyz, qq in zip(rows, T[:, :3, 3], q, strict=True):
        lines.append(f"{t // 1_000_000_000}.{t % 1_000_000_000:09d} " + " ".join(f"{v:.9f}" for v in (*xyz, *qq)))
    return "\n".join(lines) + "\n"


def parse_tum(text: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_ns (N,), poses (N,4,4)) from TUM trajectory text (the inverse of ``tum_text``)."""
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    stamps = np.array([round(float(r[0]) * 1e9) if "." not in r[0] else
                       int(r[0].split(".")[0]) * 1_000_000_000 + int(r[0].split(".")[1].ljust(9, "0")[:9])
                       for r in rows], dtype=np.int64)
    v = np.array([[float(x) for x in r[1:8]] for r in rows]).reshape(-1, 7)
    x, y, z, w = v[:, 3], v[:, 4], v[:, 5], v[:, 6]
    T = np.tile(np.eye(4), (len(v), 1, 1))
    T[:, :3, :3] = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    T[:, :3, 3] = v[:, :3]
    return stamps, T


def write_tum(path: Path, stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> None:
    write_text(Path(path), tum_text(stamps_ns, poses))


def segment_tum_name(segment: int) -> str:
    """The file of one map segment's poses in a run with several segments."""
    return f"trajectory.seg{segment}.tum"


def write_trajectories(run_dir: Path, log: PoseLog, primary: int | None) -> dict[int, str]:
    """trajectory.tum (segment ``primary``) and, with several segments, one file per segment.

    Returns segment -> file name (the per-segment files; with one segment, ``trajectory.tum``).
    """
    stamps, poses, segs = log.stamps, log.poses(), log.segments()
    present = sorted({int(k) for k, p in zip(segs, poses, strict=True) if p is not None})

    def of(k: int | None) -> list[np.ndarray | None]:
        return [p if s == k else None for p, s in zip(poses, segs, strict=True)]

    write_tum(Path(run_dir) / "trajectory.tum", stamps, of(primary))
    if len(present) <= 1:
        return {k: "trajectory.tum" for k in present}
    for k in present:
        write_tum(Path(run_dir) / segment_tum_name(k), stamps, of(k))
    return {k: segment_tum_name(k) for k in present}


class PoseLog:
    """Stamps, poses and map segments of every frame, in arrays that grow by doubling.

    A frame costs 140 B here; a list of 4x4 arrays and a list of ints cost ~300 B a frame.
    A frame without a pose is stored as NaN and comes back as None; its segment is the one
    the backend reported (meaningless without a pose).
    """

    def __init__(self, capacity: int = 1024) -> None:
        self._stamps = np.zeros(capacity, np.int64)
        self._T = np.full((capacity, 4, 4), np.nan)
        self._seg = np.zeros(capacity, np.int32)
        self._n = 0

    def append(self, stamp_ns: int, T: np.ndarray | None, segment: int = 0) -> None:
        if self._n == len(self._stamps):
            self._stamps = np.concatenate([self._stamps, np.zeros_like(self._stamps)])
            self._T = np.concatenate([self._T, np.full_like(self._T, np.nan)])
            self._seg = np.concatenate([self._seg, np.zeros_like(self._seg)])
        self._stamps[self._n] = stamp_ns
        self._T[self._n] = np.nan if T is None else T
        self._seg[self._n] = segment
        self._n += 1

    def segments(self) -> np.ndarray:
        """Each frame's map segment (int)."""
        return self._seg[: self._n].copy()

    def has_pose(self) -> np.ndarray:
        """Each frame: whether it has a pose (bool)."""
        return np.isfinite(self._T[: self._n, 0, 0])

    def __len__(self) -> int:
        return self._n

    @property
    def stamps(self) -> list[int]:
        return self._stamps[: self._n].tolist()

    def poses(self) -> list[np.ndarray | None]:
        """Each frame's 4x4 pose, or None where it had none."""
        return [T if np.isfinite(T[0, 0]) else None for T in self._T[: self._n]]


KEYFRAME_SPEC = {"kf_index": (np.int64, ()), "kf_stamp_ns": (np.int64, ()), "kf_T_world_camera": (np.float64, (4, 4)),
                 "kf_segment": (np.int64, ()),
                 "point_kf": (np.int64, ()), "point_ids": (np.int64, ()), "point_xyz_world": (np.float64, (3,)),
                 "point_pixels": (np.float64, (2,))}


class KeyframeLog:
    """A run's keyframes, on disk as they come: memory does not grow with the keyframes of a long flight.

    With ``folder`` None only the count is kept (``slz compare`` writes no map). ``write_npz``
    gives keyframes.npz (flat arrays, see the module docstring); ``map_xyz`` memory-maps the points.
    """

    def __init__(self, folder: Path | None = None) -> None:
        self.spool = ArraySpool(folder, KEYFRAME_SPEC) if folder is not None else None
        self.count = 0
        self.per_segment: dict[int, int] = {}  # map segment -> keyframes

    def append(self, kf: MapPoints, segment: int = 0) -> None:
        if self.spool is not None:
            self.spool.append(kf_index=[kf.keyframe_index], kf_stamp_ns=[kf.stamp_ns],
                              kf_T_world_camera=kf.T_world_camera, kf_segment=np.array([segment]),
                              point_kf=np.full(len(kf), self.count), point_ids=kf.ids,
                              point_xyz_world=kf.xyz_world, point_pixels=kf.pixels)
        self.count += 1
        self.per_segment[segment] = self.per_segment.get(segment, 0) + 1

    def __len__(self) -> int:
        return self.count

    def write_npz(self, path: Path) -> None:
        if self.spool is None:
            raise ValueError("a count-only keyframe log has no arrays to write")
        write_npz_streamed(Path(path), {name: self.spool.npy(name) for name in KEYFRAME_SPEC})

    def map_xyz(self, segment: int | None = None) -> np.ndarray:
        """Every keyframe's map points (memory-mapped), or a copy of those of one map segment."""
        if self.spool is None:
            return np.zeros((0, 3))
        xyz = np.load(self.spool.npy("point_xyz_world"), mmap_mode="r")
        if segment is None:
            return xyz
        kf_segment = np.load(self.spool.npy("kf_segment"), mmap_mode="r")
        point_kf = np.load(self.spool.npy("point_kf"), mmap_mode="r")
        return np.asarray(xyz[np.asarray(kf_segment)[point_kf] == segment])
