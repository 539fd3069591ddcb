"""Every detection's candidate clusters (sites.csv) and the sites found, as a run goes.

With a folder (``slz detect``), candidate rows are appended to a CSV file there and each
site's points (its mask-filtered map points and its chosen cluster) to an on-disk spool:
per site, memory keeps only its summary (frame, Site), so a long recording's detections do
not add up in memory. Without one (``slz compare``, tests) everything stays in memory.
"""

from __future__ import annotations

import csv
import io
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from slzcli.outputs.files import ArraySpool, atomic_path, naming_write_errors
from slzcli.types import FoundSite, FrameRef, RaisedReadings, Site

SITE_COLUMNS = ("frame", "stamp_ns", "cluster", "points", "x", "y", "z", "normal_variance", "extent_x_m",
                "extent_y_m", "qualifies", "reason", "chosen", "segment", "raised_m", "raised_cells")
POINT_SPEC = {"xyz": (np.float64, (3,)), "site": (np.int64, ()), "chosen": (np.bool_, ()), "cluster": (np.int64, ())}


class SiteLog:
    """Candidate rows and sites of one run; ``sites``: a ``types.FoundSite`` each.

    Positions (rows' x, y, z and sites) are in the world frame of their SLAM map segment.
    """

    def __init__(self, folder: Path | None = None) -> None:
        self.folder = Path(folder) if folder is not None else None
        self.rows = 0
        self.sites: list[FoundSite] = []
        self._rows: list[Mapping[str, object]] = []  # SITE_COLUMNS -> value, as csv writes it (str)
        self._points: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._clusters: dict[int, np.ndarray] = {}
        self._raised: list[np.ndarray] = []   # per detection: (k, 5) x, y, segment, refused, margin of its clusters
        self._spool = ArraySpool(self.folder / "site_points", POINT_SPEC) if self.folder is not None else None
        self._csv = self.folder / "sites.csv" if self.folder is not None else None
        if self._csv is not None:
            with naming_write_errors(self._csv):
                self._csv.write_text(",".join(SITE_COLUMNS) + "\n")

    def add_rows(self, rows: Sequence[Mapping[str, object]]) -> None:
        self.rows += len(rows)
        if self._csv is None:
            self._rows.extend(rows)
            return
        with naming_write_errors(self._csv), open(self._csv, "a", newline="") as fh:
            csv.DictWriter(fh, fieldnames=SITE_COLUMNS, lineterminator="\n").writerows(rows)

    def add_raised(self, xy: np.ndarray, segment: int, refused: np.ndarray, margin_m: np.ndarray) -> None:
        """One detection's raised-surface readings: its measured clusters' plan centres, whether each was refused
        and its margin (a few floats a detection: kept in memory)."""
        if len(xy):
            self._raised.append(np.column_stack([np.asarray(xy, np.float64).reshape(-1, 2),
                                                 np.full(len(xy), float(segment)), np.asarray(refused, np.float64),
                                                 np.asarray(margin_m, np.float64)]))

    def raised_readings(self) -> RaisedReadings:
        """Every raised-surface reading of the run so far."""
        if not self._raised:
            return RaisedReadings.empty()
        a = np.vstack(self._raised)
        return RaisedReadings(a[:, :2].copy(), a[:, 2].astype(np.int64), a[:, 3] > 0.5, a[:, 4].copy())

    def add_site(self, frame: FrameRef, site: Site, kept_xyz: np.ndarray, chosen_xyz: np.ndarray,
                 limits: dict[str, object] | None = None, segment: int = 0,
                 kept_cluster: np.ndarray | None = None) -> None:
        """``limits``: what the depth noise of the site's frame let the maps see (``Working.as_dict``);
        ``segment``: the SLAM map segment whose world frame the site is in; ``kept_cluster``: the k-means
        cluster of each kept point (None: -1 for all)."""
        i = len(self.sites)
        self.sites.append(FoundSite(frame, site, i, limits, segment))
        kept, chosen = np.asarray(kept_xyz).reshape(-1, 3), np.asarray(chosen_xyz).reshape(-1, 3)
        labels = np.full(len(kept), -1, np.int64) if kept_cluster is None else np.asarray(kept_cluster, np.int64)
        if self._spool is None:
            self._points[i] = (np.asarray(kept_xyz), np.asarray(chosen_xyz))
            self._clusters[i] = labels
            return
        self._spool.append(xyz=np.vstack([kept, chosen]), site=np.full(len(kept) + len(chosen), i),
                           chosen=np.r_[np.zeros(len(kept), bool), np.ones(len(chosen), bool)],
                           cluster=np.r_[labels, np.full(len(chosen), -1, np.int64)])

    def points(self, entry: FoundSite) -> tuple[np.ndarray, np.ndarray]:
        """(kept_xyz, chosen_xyz) of one site of ``sites``."""
        if self._spool is None:
            return self._points[entry.id]
        xyz = np.load(self._spool.npy("xyz"), mmap_mode="r")
        mine = np.load(self._spool.npy("site"), mmap_mode="r") == entry.id
        chosen = np.load(self._spool.npy("chosen"), mmap_mode="r")
        return np.array(xyz[mine & ~chosen]), np.array(xyz[mine & chosen])

    def kept_clusters(self, entry: FoundSite) -> np.ndarray:
        """The k-means cluster of each kept point of one site of ``sites`` (in the order of ``points``)."""
        if self._spool is None:
            return self._clusters[entry.id]
        mine = np.load(self._spool.npy("site"), mmap_mode="r") == entry.id
        chosen = np.load(self._spool.npy("chosen"), mmap_mode="r")
        return np.array(np.load(self._spool.npy("cluster"), mmap_mode="r")[mine & ~chosen])

    def write_csv(self, path: Path) -> None:
        """sites.csv: every candidate of every detection and why it did or did not qualify."""
        with atomic_path(Path(path)) as tmp:
            if self._csv is not None:
                shutil.copyfile(self._csv, tmp)
                return
            buf = io.StringIO()
            writer = csv.DictWriter(buf, fieldnames=SITE_COLUMNS, lineterminator="\n")
            writer.writeheader()
            writer.writerows(self._rows)
            tmp.write_text(buf.getvalue())
