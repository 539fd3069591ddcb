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

from slzcli.geometry import Pose
from slzcli.outputs.files import ArraySpool, write_npz_streamed, write_text
from slzcli.types import MapPoints


def tum_text(stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> str:
    """TUM trajectory text of the frames that have a pose (seconds with nanosecond digits)."""
    rows = [(t, p) for t, p in zip(stamps_ns, poses, strict=True) if p is not None]
    if not rows:
        return "# timestamp tx ty tz qx qy qz qw\n"
    T = np.stack([np.asarray(p, np.float64) for _, p in rows])
    q = Pose.from_matrix(T).as_quat()
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
    T = Pose.from_quat(v[:, 3:7], v[:, :3]).as_matrix() if len(v) else np.zeros((0, 4, 4))
    return stamps, T


def write_tum(path: Path, stamps_ns: Sequence[int], poses: Sequence[np.ndarray | None]) -> None:
    write_text(Path(path), tum_text(stamps_ns, poses))


def segment_tum_name(segment: int) -> str:
    """The file of one map segment's poses in a run with several segments."""
    return f"trajectory.seg{segment}.tum"


def trajectory_files(log: PoseLog) -> dict[int, str]:
    """Segment -> the TUM file that holds it alone (with one segment, ``trajectory.tum``); nothing is written."""
    present = sorted({int(k) for k, p in zip(log.segments(), log.poses(), strict=True) if p is not None})
    if len(present) <= 1:
        return {k: "trajectory.tum" for k in present}
    return {k: segment_tum_name(k) for k in present}


def write_trajectories(run_dir: Path, log: PoseLog, primary: int | None) -> dict[int, str]:
    """trajectory.tum (segment ``primary``) and, with several segments, one file per segment.

    Returns segment -> file name (``trajectory_files``: the per-segment files; with one segment, ``trajectory.tum``).
    """
    stamps, poses, segs = log.stamps, log.poses(), log.segments()
    names = trajectory_files(log)

    def of(k: int | None) -> list[np.ndarray | None]:
        return [p if s == k else None for p, s in zip(poses, segs, strict=True)]

    write_tum(Path(run_dir) / "trajectory.tum", stamps, of(primary))
    if len(names) > 1:
        for k, name in names.items():
            write_tum(Path(run_dir) / name, stamps, of(k))
    return names


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
