"""Bare ``.mcap`` files with ROS 2 (cdr) or ROS 1 (ros1) encoded messages, read as a stream.

The mcap StreamReader reads records in file order without seeking, so a file cut
short (a recorder killed mid-write) still gives every message before the cut; the
loss is logged with the number of messages recovered. Message schemas stored in the
file are registered into a rosbags typestore per message encoding; schemaless
channels fall back to the ROS 2 Humble / ROS 1 Noetic typestores.
"""

from __future__ import annotations

import io
import logging
import struct
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, McapRecord, Message, MessageIndex, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from slzcli.config import Config
from slzcli.errors import DatasetError, DecodeError
from slzcli.sources.formats import MCAP_MAGIC as MAGIC
from slzcli.sources.message_log import MessageLog, RawMessage
from slzcli.sources.messages import MessageRecording
from slzcli.sources.ros_types import Message as RosMessage
from slzcli.sources.topics import normalise_msgtype

log = logging.getLogger(__name__)
ROS1_ENCODING = "ros1"
CDR_ENCODING = "cdr"


class _ChunkTooLarge(Exception):
    """A chunk whose declared or real uncompressed size is beyond the bound: damage, read as a torn chunk."""


def open_mcap(path: Path, config: Config) -> MessageRecording:
    """``formats.FORMATS["mcap"]``: a bare MCAP file."""
    return MessageRecording(McapLog(path), config)


class McapLog(MessageLog):
    """A MessageLog over one bare MCAP file."""

    format = "mcap"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self._topics: dict[str, str] = {}
        self._encoding: dict[str, str] = {}
        self._stores: dict[str, Typestore] = {}
        self._registered: set[tuple[str, str]] = set()
        self._schemas: dict[int, Schema] = {}
        self._truncation_reported = False
        self._summary: Summary | None = None

    # ------------------------------------------------------------------ open
    def open(self) -> None:
        try:
            size = self.path.stat().st_size
        except OSError as err:
            raise DatasetError(self.path, f"cannot open ({err.strerror or err})") from err
        if size == 0:
            raise DatasetError(self.path, "empty file (0 bytes)")
        with self.path.open("rb") as f:
            head = f.read(len(MAGIC))
        if head != MAGIC:
            raise DatasetError(self.path, "not an MCAP file (bad magic bytes at the start)")
        if not self._read_summary():
            self._scan_channels()
        encodings = {self._encoding[t] for t in self._topics}
        unknown = encodings - {CDR_ENCODING, ROS1_ENCODING}
        if unknown and not (encodings - unknown):
            raise DatasetError(self.path, f"message encoding {', '.join(sorted(unknown))} is not ROS "
                                          "(only cdr and ros1 MCAP are read)")
        self.format = "mcap (ros1)" if encodings == {ROS1_ENCODING} else "mcap (ros2 cdr)"

    def _read_summary(self) -> bool:
        """Channels from the summary section; False when it is missing or unreadable (cut short)."""
        summary = read_summary(self.path)
        if summary is None or not summary.channels:
            return False
        self._summary = summary
        for ch in summary.channels.values():
            self._add_channel(ch, summary.schemas.get(ch.schema_id))
        return True

    def _scan_channels(self) -> None:
        """No usable summary: one streaming pass to collect the channels (and count the loss)."""
        for _ in self._records(topics=None, want_messages=False):
            pass

    def _add_channel(self, ch: Channel, schema: Schema | None) -> None:
        self._topics[ch.topic] = normalise_msgtype(schema.name) if schema is not None else ""
        self._encoding[ch.topic] = ch.message_encoding
        if schema is not None:
            self._register(ch.message_encoding, schema)

    def _register(self, encoding: str, schema: Schema) -> None:
        key = (encoding, schema.name)
        if key in self._registered or encoding not in (CDR_ENCODING, ROS1_ENCODING) or not schema.data:
            return
        self._registered.add(key)
        store = self._store(encoding)
        text = schema.data.decode("utf-8", "replace")
        try:
            types = get_types_from_idl(text) if schema.encoding == "ros2idl" else \
                get_types_from_msg(text, normalise_msgtype(schema.name))
            store.register({k: v for k, v in types.items() if k not in store.fielddefs})
        except Exception as err:  # rosbags parser errors, wrapped once here
            raise DatasetError(self.path,
                               f"schema {schema.name!r} is not a valid ROS message definition ({err})") from err

    def _store(self, encoding: str) -> Typestore:
        if encoding not in self._stores:
            self._stores[encoding] = get_typestore(Stores.EMPTY)
        return self._stores[encoding]

    def close(self) -> None:
        return None

    # ------------------------------------------------------------------ reading
    def topics(self) -> dict[str, str]:
        return dict(self._topics)

    def is_ros1(self, topic: str) -> bool:
        return self._encoding.get(topic) == ROS1_ENCODING

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        yield from self._records(set(topics) if topics else None, want_messages=True)

    def _records(self, topics: set[str] | None, want_messages: bool) -> Iterator[RawMessage]:
        channels: dict[int, Channel] = {}
        n = 0
        with self.path.open("rb") as f:
            reader = StreamReader(f, record_size_limit=_file_size(f), emit_chunks=True)
            try:
                for rec in self._unchunked(reader.records, f):
                    if isinstance(rec, Schema):
                        self._schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
                        if rec.topic not in self._topics:
                            self._add_channel(rec, self._schemas.get(rec.schema_id))
                    elif isinstance(rec, Message):
                        ch = channels.get(rec.channel_id)
                        if ch is None:
                            continue
                        n += 1
                        if want_messages and (topics is None or ch.topic in topics):
                            yield RawMessage(ch.topic, rec.log_time, rec.data)
            except InvalidMagic as err:
                raise DatasetError(self.path, "not an MCAP file (bad magic bytes)") from err
            except (EndOfFile, McapError, struct.error, ValueError, EOFError, _ChunkTooLarge) as err:
                self._truncated(n, f.tell(), err)
            except Exception as err:  # decompression errors of a torn chunk (zstd/lz4 raise their own types)
                if "compress" not in type(err).__module__ + type(err).__name__.lower() + str(err).lower():
                    raise
                self._truncated(n, f.tell(), err)

    def _unchunked(self, records: Iterator[McapRecord], f: BinaryIO) -> Iterator[McapRecord]:
        """The records with each chunk broken up, after its declared size is checked against
        ``bounds.MAX_MCAP_CHUNK_BYTES`` (zstd allocates what a chunk declares before it reads a byte)."""
        from slzcli.bounds import MAX_MCAP_CHUNK_BYTES

        for rec in records:
            if not isinstance(rec, Chunk):
                yield rec
                continue
            if rec.uncompressed_size > MAX_MCAP_CHUNK_BYTES:  # damaged: read as a torn chunk is (_truncated)
                raise _ChunkTooLarge(f"a chunk declares {rec.uncompressed_size} bytes uncompressed, more than "
                                     f"{MAX_MCAP_CHUNK_BYTES >> 20} MiB")
            try:
                inner = breakup_chunk(rec)
            except MemoryError:  # e.g. an lz4 frame whose header declares more than memory holds
                raise _ChunkTooLarge("a chunk does not decompress within memory") from None
            yield from inner

    def _truncated(self, n: int, pos: int, err: Exception) -> None:
        kind = str(err) if isinstance(err, _ChunkTooLarge) else \
            f"{type(err).__module__.split('.')[0]}.{type(err).__name__}"
        text = (f"file ends early or is damaged near byte {pos} ({kind}); "
                f"recovered {n} messages before it")
        if text not in self.warnings:
            self.warnings.append(text)
        if not self._truncation_reported:
            self._truncation_reported = True
            log.warning("%s: %s", self.path, text)

    def log_times(self) -> dict[str, np.ndarray] | None:
        """From the file's summary and message indexes (``index_log_times``)."""
        return None if self._summary is None else index_log_times(self.path, self._summary)

    def deserialize(self, topic: str, data: bytes | memoryview) -> RosMessage:
        enc = self._encoding.get(topic, "")
        msgtype = self._topics.get(topic, "")
        store = self._stores.get(enc)
        if store is None or msgtype not in store.fielddefs:
            store = self._fallback(enc)
        try:
            if enc == ROS1_ENCODING:
                return store.deserialize_ros1(bytes(data), msgtype)
            return store.deserialize_cdr(bytes(data), msgtype)
        except Exception as err:  # rosbags SerdeError and friends
            raise DecodeError(f"{topic}: cannot deserialise {msgtype or 'schemaless message'} ({err})") from err

    def _fallback(self, encoding: str) -> Typestore:
        key = f"default-{encoding}"
        if key not in self._stores:
            self._stores[key] = get_typestore(Stores.ROS1_NOETIC if encoding == ROS1_ENCODING else Stores.ROS2_HUMBLE)
        return self._stores[key]


def index_log_times(path: Path, s: Summary) -> dict[str, np.ndarray] | None:
    """Every message's log time per topic from an MCAP's summary (its chunk indexes) and the message index
    records written after each chunk (read, never decompressed). None unless they account for every message
    the summary's statistics count: a file without statistics, with messages outside chunks, or with a chunk
    whose indexes are missing."""
    if s.statistics is None or not s.chunk_indexes:
        return None
    per_channel: dict[int, list[np.ndarray]] = {}
    try:
        with path.open("rb") as f:
            for ci in s.chunk_indexes:
                f.seek(ci.chunk_start_offset + ci.chunk_length)
                block = f.read(ci.message_index_length)
                if len(block) != ci.message_index_length:
                    return None
                for channel_id, times in _message_indexes(block):
                    per_channel.setdefault(channel_id, []).append(times)
    except (OSError, McapError, struct.error, ValueError):
        return None
    counts = {c: sum(len(t) for t in ts) for c, ts in per_channel.items()}
    stats = s.statistics
    if sum(counts.values()) != stats.message_count or any(
            counts.get(c, 0) != n for c, n in stats.channel_message_counts.items()):
        return None
    out: dict[str, list[np.ndarray]] = {}
    for c, ts in per_channel.items():
        ch = s.channels.get(c)
        if ch is None:
            return None
        out.setdefault(ch.topic, []).extend(ts)
    return {topic: np.sort(np.concatenate(ts)) for topic, ts in out.items()}


def read_summary(path: Path) -> Summary | None:
    """The file's summary section; None when it is missing or unreadable (a file cut short has none)."""
    try:
        with path.open("rb") as f:
            return SeekingReader(f).get_summary()
    except (McapError, struct.error, ValueError, OSError):
        return None


def mcap_file_log_times(path: Path) -> dict[str, np.ndarray] | None:
    """``index_log_times`` of an MCAP file by its path (None: no readable summary)."""
    summary = read_summary(path)
    return None if summary is None else index_log_times(path, summary)


def _message_indexes(block: bytes) -> Iterator[tuple[int, np.ndarray]]:
    """(channel id, log times) of each MessageIndex record in the bytes after a chunk, read by mcap's own
    reader; ValueError on any other record (the spec puts only message indexes there) and on a log time beyond
    int64 ns (the full pass counts and skips those)."""
    try:
        for rec in StreamReader(io.BytesIO(block), skip_magic=True).records:
            if not isinstance(rec, MessageIndex):
                raise ValueError(f"{type(rec).__name__} among the message indexes")
            yield rec.channel_id, np.fromiter((t for t, _ in rec.records), np.int64, len(rec.records))
    except EndOfFile:
        return
    except OverflowError as err:
        raise ValueError(str(err)) from err


def _file_size(f: BinaryIO) -> int:
    """Records cannot be longer than the file: a garbage length fails fast instead of allocating."""
    pos = f.tell()
    f.seek(0, 2)
    size = f.tell()
    f.seek(pos)
    return max(size, 1)
