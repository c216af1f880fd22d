"""Records shared by the bag reader, writer and tools."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from ssf_common.bags.qos import Qos


class BagMessage(NamedTuple):
    """One stored message: its topic, ROS type, receive time and CDR bytes (header included)."""

    topic: str
    type_name: str
    timestamp_ns: int
    data: bytes


class TopicInfo(NamedTuple):
    """What a bag holds for one topic."""

    name: str
    type_name: str
    message_count: int
    serialization_format: str = "cdr"
    offered_qos: tuple[Qos, ...] = ()
    type_hash: str = ""


class TypeDefinition(NamedTuple):
    """A message definition embedded in a bag (MCAP schema or sqlite3 message_definitions row)."""

    type_name: str
    encoding: str
    text: str


class FileInfo(NamedTuple):
    """One storage file of a bag."""

    path: Path
    size_bytes: int
    message_count: int
    start_ns: int
    end_ns: int
    damage: str | None = None


class BagInfo(NamedTuple):
    """Summary of a whole bag, as `ssf bag info` prints it."""

    path: Path
    storage: str
    metadata_version: int | None
    ros_distro: str
    files: tuple[FileInfo, ...]
    topics: tuple[TopicInfo, ...]
    message_count: int
    start_ns: int
    end_ns: int
    compression_format: str = ""
    compression_mode: str = ""
    custom_data: tuple[tuple[str, str], ...] = ()

    @property
    def duration_ns(self) -> int:
        """Time between the first and the last message."""
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    @property
    def damage(self) -> tuple[str, ...]:
        """One line per damaged storage file ('' when the bag is intact)."""
        return tuple(f"{f.path.name}: {f.damage}" for f in self.files if f.damage)
