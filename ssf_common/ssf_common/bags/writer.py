"""Write rosbag2 bags: one MCAP file (profile ros2, ros2msg schemas, cdr channels) plus metadata.yaml v9.

Chunks are finished and handed to the operating system at least every `chunk_seconds` and whenever they
reach `chunk_bytes`, so a recorder killed with SIGKILL leaves a file readable up to its last chunk.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from enum import Enum
from pathlib import Path
from typing import Any, NamedTuple

import yaml
from mcap.writer import CompressionType, Writer
from pydantic import Field

from ssf_common import messages
from ssf_common.bags.qos import Qos, profiles_to_dicts, profiles_to_yaml
from ssf_common.config import Section
from ssf_common.errors import BagError, MessageError

METADATA_VERSION = 9
ROS_DISTRO = "jazzy"
LIBRARY = "ssf-pan bag writer (mcap-python)"
_MESSAGE_OVERHEAD = 31  # opcode, length, channel id, sequence, two times


class ChunkCompression(str, Enum):
    """How chunks are compressed (rosbag2's MCAP plugin uses zstd by default)."""

    ZSTD = "zstd"
    LZ4 = "lz4"
    NONE = "none"


class BagWriterConfig(Section):
    """How a bag is chunked and compressed."""

    chunk_bytes: int = Field(4 * 1024 * 1024, ge=1024, le=1 << 30, description="finish a chunk at this size")
    chunk_seconds: float = Field(1.0, gt=0.0, le=3600.0, description="finish a chunk at least this often")
    compression: ChunkCompression = ChunkCompression.ZSTD


class _Topic(NamedTuple):
    channel_id: int
    type_name: str
    serialization_format: str
    offered_qos: tuple[Qos, ...]
    type_hash: str


_COMPRESSION = {
    ChunkCompression.ZSTD: CompressionType.ZSTD,
    ChunkCompression.LZ4: CompressionType.LZ4,
    ChunkCompression.NONE: CompressionType.NONE,
}


class BagWriter:
    """Record messages into a new rosbag2 directory; `close` writes the summary and metadata.yaml."""

    def __init__(
        self,
        directory: str | Path,
        config: BagWriterConfig | None = None,
        *,
        custom_data: Mapping[str, str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.directory = Path(directory)
        self.config = config or BagWriterConfig()
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._clock = clock
        if self.directory.exists() and (not self.directory.is_dir() or any(self.directory.iterdir())):
            raise BagError(f"{self.directory}: already exists; choose a new bag directory")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.file_path = self.directory / f"{self.directory.name}_0.mcap"
            self._stream = self.file_path.open("xb")
        except OSError as err:
            raise BagError(f"{self.directory}: cannot create the bag ({err.strerror or err})") from None
        self._mcap = Writer(
            self._stream, chunk_size=1 << 62, compression=_COMPRESSION[self.config.compression]
        )
        self._mcap.start(profile="ros2", library=LIBRARY)
        self._stream.flush()
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._counts: Counter[str] = Counter()
        self._sequence: Counter[str] = Counter()
        self._start_ns: int | None = None
        self._end_ns = 0
        self._chunk_bytes = 0
        self._chunk_opened_at: float | None = None
        self._closed = False

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def topics(self) -> tuple[str, ...]:
        """Topics added so far."""
        return tuple(self._topics)

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(self._counts.values())

    def add_topic(
        self,
        topic: str,
        type_name: str,
        offered_qos: Sequence[Qos] = (),
        serialization_format: str = "cdr",
    ) -> None:
        """Declare a topic (once) with its ROS type and the QoS its publishers offer."""
        if topic in self._topics:
            return
        type_name = messages.normalize_type_name(type_name)
        try:
            messages.msg_type(type_name)
            definition = messages.msgdef(type_name)
            type_hash = messages.type_hash(type_name)
        except (MessageError, KeyError) as err:
            raise BagError(f"topic {topic}: cannot record type '{type_name}' ({err})") from None
        if type_name not in self._schemas:
            self._schemas[type_name] = self._mcap.register_schema(type_name, "ros2msg", definition.encode())
        qos = tuple(offered_qos)
        channel_id = self._mcap.register_channel(
            topic,
            serialization_format,
            self._schemas[type_name],
            {"offered_qos_profiles": profiles_to_yaml(qos), "topic_type_hash": type_hash},
        )
        self._topics[topic] = _Topic(channel_id, type_name, serialization_format, qos, type_hash)

    def write(self, topic: str, data: bytes, timestamp_ns: int, publish_time_ns: int | None = None) -> None:
        """Append one serialised message received at `timestamp_ns`."""
        declared = self._topics.get(topic)
        if declared is None:
            raise BagError(f"topic {topic} was not added to the bag before writing to it")
        if self._closed:
            raise BagError(f"{self.directory}: bag is closed")
        self._sequence[topic] += 1
        self._mcap.add_message(
            channel_id=declared.channel_id,
            log_time=int(timestamp_ns),
            data=bytes(data),
            publish_time=int(timestamp_ns if publish_time_ns is None else publish_time_ns),
            sequence=self._sequence[topic] & 0xFFFFFFFF,
        )
        self._counts[topic] += 1
        self._start_ns = timestamp_ns if self._start_ns is None else min(self._start_ns, timestamp_ns)
        self._end_ns = max(self._end_ns, timestamp_ns)
        self._chunk_bytes += len(data) + _MESSAGE_OVERHEAD
        if self._chunk_opened_at is None:
            self._chunk_opened_at = self._clock()
        if self._chunk_bytes >= self.config.chunk_bytes:
            self.flush()
        else:
            self.flush_if_due()

    def flush_if_due(self) -> None:
        """Finish the open chunk if it is older than chunk_seconds (call it from a timer when idle)."""
        if self._chunk_opened_at is not None and self._clock() - self._chunk_opened_at >= self.config.chunk_seconds:
            self.flush()

    def flush(self) -> None:
        """Finish the open chunk and hand everything written so far to the operating system."""
        if self._closed:
            return
        self._mcap.flush()
        self._chunk_bytes = 0
        self._chunk_opened_at = None

    def close(self) -> None:
        """Write the rosbag2 metadata record, the MCAP summary and metadata.yaml."""
        if self._closed:
            return
        metadata = self.metadata()
        serialized = yaml.safe_dump(metadata["rosbag2_bagfile_information"], sort_keys=False)
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": serialized, "ROS_DISTRO": ROS_DISTRO})
        self._mcap.finish()
        self._stream.close()
        self._closed = True
        staging = self.directory / "metadata.yaml.tmp"
        staging.write_text(yaml.safe_dump(metadata, sort_keys=False))
        os.replace(staging, self.directory / "metadata.yaml")

    def metadata(self) -> dict[str, Any]:
        """The metadata.yaml document (version 9) for what has been written so far."""
        start = self._start_ns or 0
        duration = self._end_ns - start if self._start_ns is not None else 0
        count = self.message_count
        return {
            "rosbag2_bagfile_information": {
                "version": METADATA_VERSION,
                "storage_identifier": "mcap",
                "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": count,
                "topics_with_message_count": [
                    {
                        "topic_metadata": {
                            "name": name,
                            "type": topic.type_name,
                            "serialization_format": topic.serialization_format,
                            "offered_qos_profiles": profiles_to_dicts(topic.offered_qos),
                            "type_description_hash": topic.type_hash,
                        },
                        "message_count": self._counts[name],
                    }
                    for name, topic in self._topics.items()
                ],
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [self.file_path.name],
                "files": [
                    {
                        "path": self.file_path.name,
                        "starting_time": {"nanoseconds_since_epoch": start},
                        "duration": {"nanoseconds": duration},
                        "message_count": count,
                    }
                ],
                "custom_data": dict(self.custom_data) or None,
                "ros_distro": ROS_DISTRO,
            }
        }
