"""ROS 1 ``.bag`` files and ROS 2 bag folders (sqlite3 or mcap storage) through rosbags' AnyReader.

Message definitions embedded in the bag are used; bags without them fall back to the
ROS 1 Noetic or ROS 2 Humble typestore.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Collection, Iterator
from pathlib import Path

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from slzcli.bounds import MAX_BAG_METADATA_BYTES, file_kind, read_regular
from slzcli.config import Config
from slzcli.errors import DatasetError, DecodeError, SlzError
from slzcli.sources.formats import ROS1_MAGIC
from slzcli.sources.mcap import mcap_file_log_times
from slzcli.sources.message_log import MessageLog, RawMessage
from slzcli.sources.messages import MessageRecording
from slzcli.sources.ros_types import Message


def open_ros1(path: Path, config: Config) -> MessageRecording:
    """``formats.FORMATS["ros1"]``: a ROS 1 ``.bag`` file."""
    return MessageRecording(RosbagLog(path, ros1=True), config)


def open_ros2(path: Path, config: Config) -> MessageRecording:
    """``formats.FORMATS["ros2"]``: a rosbag2 folder."""
    return MessageRecording(RosbagLog(path, ros1=False), config)


class RosbagLog(MessageLog):
    """A MessageLog over a ROS 1 bag (``ros1``) or a rosbag2 folder (``ros2``)."""

    def __init__(self, path: Path, *, ros1: bool) -> None:
        super().__init__(path)
        self.ros1 = ros1
        self.format = "ros1 bag" if self.ros1 else "ros2 bag"
        self._reader: AnyReader | None = None
        self._types: dict[str, str] = {}

    def open(self) -> None:
        if self.ros1:
            with self.path.open("rb") as f:
                if f.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                    raise DatasetError(self.path, "not a ROS 1 bag (no '#ROSBAG V2.0' header)")
        else:
            _check_bag_folder(self.path)
        store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        try:
            reader = AnyReader([self.path], default_typestore=store)
            reader.open()
        except Exception as err:  # rosbags raises several unrelated types; wrapped once here
            hint = "; cut short? `rosbag reindex` can repair a ROS 1 bag" if "index" in str(err).lower() else ""
            raise DatasetError(self.path, f"not a readable {self.format} ({_reason(err)}{hint})") from err
        self._reader = reader
        if not self.ros1:
            storage = _storage(self.path)
            if storage:
                self.format = f"ros2 bag ({storage})"
        self._types = {c.topic: c.msgtype for c in reader.connections}

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def topics(self) -> dict[str, str]:
        return dict(self._types)

    def is_ros1(self, topic: str) -> bool:
        return self.ros1

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        reader = self._open_reader()
        conns = [c for c in reader.connections if not topics or c.topic in topics]
        if not conns:
            return
        for conn, stamp, data in reader.messages(connections=conns):
            yield RawMessage(conn.topic, stamp, data)

    def log_times(self) -> dict[str, np.ndarray] | None:
        """A ROS 1 bag: its index, which rosbags reads on opening (every message's time per connection; a bag
        without one is refused then). A rosbag2 folder: its storage files' (``_ros2_log_times``)."""
        readers = getattr(self._reader, "readers", None)
        if not readers or len(readers) != 1:
            return None
        if not self.ros1:
            return _ros2_log_times(self.path, readers[0])
        bag = readers[0]
        indexes = getattr(bag, "indexes", None)
        if not isinstance(indexes, dict):
            return None
        out: dict[str, list[np.ndarray]] = {}
        for c in bag.connections:
            entries = indexes.get(c.id)
            if entries is None:
                return None
            out.setdefault(c.topic, []).append(np.fromiter((e.time for e in entries), np.int64, len(entries)))
        return {topic: np.sort(np.concatenate(ts)) for topic, ts in out.items()}

    def deserialize(self, topic: str, data: bytes | memoryview) -> Message:
        try:
            return self._open_reader().deserialize(data if isinstance(data, bytes) else bytes(data), self._types[topic])
        except Exception as err:  # AnyReaderError / SerdeError on a damaged message
            raise DecodeError(f"{topic}: cannot deserialise {self._types[topic]} ({_reason(err)})") from err

    def _open_reader(self) -> AnyReader:
        if self._reader is None:
            raise DatasetError(self.path, "bag is not open")
        return self._reader


def _ros2_log_times(folder: Path, bag: object) -> dict[str, np.ndarray] | None:
    """Every message's log time per topic of a rosbag2 folder without reading a message's data: an MCAP storage
    file's summary and message indexes (``mcap.mcap_file_log_times``), a sqlite3 one's timestamp column (the
    rows' data stays on its overflow pages). None for whole-file compression (the files are compressed on disk)
    and when the times do not add up to the counts the metadata gives (``connections``' msgcount)."""
    if getattr(bag, "compression_mode", None) == "file":
        return None
    files = [p for p in bag_folder_files(folder)[1:] if p.suffix in (".mcap", ".db3")]
    if not files:
        return None
    out: dict[str, list[np.ndarray]] = {}
    for p in files:
        times = mcap_file_log_times(p) if p.suffix == ".mcap" else _sqlite_log_times(p)
        if times is None:
            return None
        for topic, ts in times.items():
            out.setdefault(topic, []).append(ts)
    merged = {topic: np.sort(np.concatenate(ts)) for topic, ts in out.items()}
    counts: dict[str, int] = {}
    for c in getattr(bag, "connections", []):
        counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
    if any(len(merged.get(t, ())) != n for t, n in counts.items()) or set(merged) - set(counts):
        return None
    return merged


def _sqlite_log_times(path: Path) -> dict[str, np.ndarray] | None:
    """A rosbag2 sqlite3 file's message timestamps per topic (read-only; None when it cannot be read)."""
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            names = dict(con.execute("SELECT id, name FROM topics").fetchall())
            n = int(con.execute("SELECT COUNT(*) FROM messages").fetchone()[0])
            # streamed into one array (16 bytes a message): a list of row tuples first was ~10x that, an hour
            # with a 1 kHz IMU 3.6 million of them
            rows = np.fromiter(con.execute("SELECT topic_id, timestamp FROM messages"),
                               np.dtype([("topic", np.int64), ("t", np.int64)]), count=n)
        finally:
            con.close()
    except (sqlite3.Error, OverflowError, ValueError, TypeError):
        return None
    return {name: rows["t"][rows["topic"] == tid] for tid, name in names.items()}


def _reason(err: Exception) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) < 200 else text[:197] + "..."


def _check_bag_folder(path: Path) -> None:
    """Before rosbags reads it: metadata.yaml a regular file within ``bounds.MAX_BAG_METADATA_BYTES`` and
    the storage files regular files (rosbags reads the whole YAML, and a FIFO would block the read)."""
    read_regular(path / "metadata.yaml", MAX_BAG_METADATA_BYTES, "rosbag2 metadata.yaml")
    for p in path.iterdir():
        if p.suffix in (".db3", ".mcap"):
            try:
                mode = os.stat(p).st_mode
            except OSError:
                continue  # a broken link: the reader names it
            if not stat.S_ISREG(mode):
                raise DatasetError(p, f"not a regular file ({file_kind(mode)}); a rosbag2 storage file is a file")


def _storage(path: Path) -> str:
    """The rosbag2 storage plugin named in metadata.yaml ('sqlite3' or 'mcap'), or ''."""
    try:
        text = read_regular(path / "metadata.yaml", MAX_BAG_METADATA_BYTES, "rosbag2 metadata.yaml")
    except DatasetError:
        return ""
    for line in text.decode(errors="replace").splitlines():
        if "storage_identifier:" in line:
            return line.split(":", 1)[1].strip()
    return ""


def bag_folder_files(folder: Path) -> list[Path]:
    """The files a rosbag2 folder's reader reads: ``metadata.yaml`` and the storage files it lists (every
    ``.db3`` / ``.mcap`` in the folder when the metadata cannot be read: the reader reports that)."""
    meta = folder / "metadata.yaml"
    try:
        text = read_regular(meta, MAX_BAG_METADATA_BYTES, "rosbag2 metadata.yaml")
        info = yaml.safe_load(text)["rosbag2_bagfile_information"]
        listed = [folder / str(n) for n in info["relative_file_paths"]]
    except (SlzError, yaml.YAMLError, KeyError, TypeError):  # a broken bag: the reader reports it
        listed = sorted(q for q in folder.iterdir() if q.suffix in (".db3", ".mcap"))
    return [meta, *(q for q in listed if q.is_file())]
