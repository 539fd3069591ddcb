"""The format-specific part of a message recording (ROS 1/2 bags, MCAP): topics, raw messages in log-time
order, deserialisation. A format reader (rosbag.py, mcap.py) implements ``MessageLog``; everything else
(``camera_setup.py``, ``frame_stream.py``, ``messages.py``) is shared by every such format."""

from __future__ import annotations

import abc
from collections.abc import Collection, Generator, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slzcli.errors import DatasetError, SlzError
from slzcli.sources.ros_types import Message


@dataclass(frozen=True)
class RawMessage:
    """One serialised message as stored; ``log_ns`` is the recording (receive) time."""

    topic: str
    log_ns: int
    data: bytes | memoryview  # as stored: rosbags gives bytes, mcap bytes or a memoryview of its chunk


class MessageLog(abc.ABC):
    """The format-specific part: topics, raw messages in log-time order, deserialisation."""

    format: str = ""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.warnings: list[str] = []

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def topics(self) -> dict[str, str]:
        """topic -> message type name as stored."""

    @abc.abstractmethod
    def is_ros1(self, topic: str) -> bool:
        """Whether the topic's messages use the ROS 1 wire format (else CDR)."""

    @abc.abstractmethod
    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        """Messages of ``topics`` (all when empty) in log-time order, streamed."""

    def log_times(self) -> dict[str, np.ndarray] | None:
        """Every message's log time (ns, sorted) per topic, from the file's own index, no message's data read;
        None when the format or this file has no index that accounts for every message (a run then reads
        every message once before its first frame, as ``slz info`` does)."""
        return None

    @abc.abstractmethod
    def deserialize(self, topic: str, data: bytes | memoryview) -> Message:
        """The message (of the topic's type: see ``ros_types``); DecodeError naming the topic when damaged."""

    def read(self, topics: Collection[str]) -> Generator[RawMessage, None, None]:
        """``messages(topics)`` with the third-party reader's own errors wrapped once, as DatasetError naming
        the file (slz's own errors pass through)."""
        try:
            yield from self.messages(topics)
        except SlzError:
            raise
        except Exception as err:  # third-party reader errors, wrapped once here
            raise DatasetError(self.path, f"cannot read messages ({type(err).__name__}: {err})") from err
