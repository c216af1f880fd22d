"""Read one MCAP storage file: from its summary when intact, by scanning up to the damage when not."""

from __future__ import annotations

import heapq
import itertools
import struct
from collections import Counter
from collections.abc import Callable, Iterator
from io import BytesIO
from pathlib import Path
from typing import BinaryIO, NamedTuple, TypeVar

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, MessageIndex, Schema
from mcap.stream_reader import breakup_chunk

from ssf_common.bags.qos import parse_profiles
from ssf_common.bags.types import BagMessage, TopicInfo, TypeDefinition
from ssf_common.errors import BagError

MCAP_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_INT64_MAX = 2**63 - 1

T = TypeVar("T")


class _Span(NamedTuple):
    """A chunk or a loose message record: where it starts and its earliest log time."""

    start_ns: int
    offset: int


class McapFile:
    """One MCAP file of a rosbag2 bag: topics, counts, and messages in log-time order."""

    storage = "mcap"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size_bytes = path.stat().st_size
        self.damage: str | None = None
        self._stream: BinaryIO = path.open("rb")
        try:
            if self._stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise BagError(f"{path}: not an MCAP file (bad magic bytes)")
            self._schemas: dict[int, Schema] = {}
            self._channels: dict[int, Channel] = {}
            self._counts: Counter[int] = Counter()
            self._spans: list[_Span] = []
            self._chunk_indexes: list[ChunkIndex] = []
            self._scanned_times: list[int] | None = None
            self.start_ns = 0
            self.end_ns = 0
            if not self._read_summary():
                self._scan()
        except BaseException:
            self._stream.close()
            raise

    def close(self) -> None:
        """Release the file."""
        self._stream.close()

    @property
    def message_count(self) -> int:
        """Messages readable from this file."""
        return sum(self._counts.values())

    def topics(self) -> list[TopicInfo]:
        """Topics of the file with their types, counts and offered QoS."""
        infos = []
        for channel in self._channels.values():
            where = f"{self.path.name}: topic {channel.topic}"
            infos.append(
                TopicInfo(
                    name=channel.topic,
                    type_name=self._type_name(channel),
                    message_count=self._counts[channel.id],
                    serialization_format=channel.message_encoding,
                    offered_qos=parse_profiles(channel.metadata.get("offered_qos_profiles"), where),
                    type_hash=channel.metadata.get("topic_type_hash", ""),
                )
            )
        return infos

    def definitions(self) -> list[TypeDefinition]:
        """Message definitions embedded as schemas."""
        return [
            TypeDefinition(schema.name, schema.encoding, schema.data.decode("utf-8", errors="replace"))
            for schema in self._schemas.values()
            if schema.name and schema.data
        ]

    def messages(self, topics: frozenset[str] | None = None) -> Iterator[BagMessage]:
        """Messages in log-time order, chunks decompressed lazily."""
        wanted = {cid for cid, ch in self._channels.items() if topics is None or ch.topic in topics}
        if not wanted:
            return iter(())
        sources = [(span.start_ns, self._span_reader(span, wanted)) for span in self._spans]
        return merge_by_time(sources, key=lambda message: message.timestamp_ns)

    def timestamps(self) -> np.ndarray:
        """Every readable message's log time (int64 ns; beyond int64 clipped) in the order they are stored."""
        times = self._scanned_times if self._scanned_times is not None else self._indexed_times()
        return np.array(times, dtype=np.uint64).clip(max=_INT64_MAX).astype(np.int64)

    def _indexed_times(self) -> list[int]:
        """Log times from the message indexes after each chunk (the chunk itself when it has none)."""
        times: list[int] = []
        for index in self._chunk_indexes:
            try:
                times.extend(self._chunk_times(index))
            except Exception as err:  # noqa: BLE001 - corrupt bytes raise many kinds
                raise BagError(f"{self.path}: message index of the chunk at byte {index.chunk_start_offset} is "
                               f"corrupt ({_describe(err)})") from None
        return times

    def _chunk_times(self, index: ChunkIndex) -> list[int]:
        if not index.message_index_offsets:
            record = self._read_record(index.chunk_start_offset)
            if record is None:
                raise ValueError("chunk cut off")
            records = breakup_chunk(Chunk.read(ReadDataStream(BytesIO(record[1]))), validate_crc=True)
            return [r.log_time for r in records if isinstance(r, Message)]
        start = index.chunk_start_offset + index.chunk_length
        self._stream.seek(start)
        data = self._stream.read(index.message_index_length)
        entries: list[tuple[int, int]] = []
        position = 0
        while position + _RECORD_HEAD.size <= len(data):
            opcode, length = _RECORD_HEAD.unpack_from(data, position)
            body = data[position + _RECORD_HEAD.size : position + _RECORD_HEAD.size + length]
            if opcode == Opcode.MESSAGE_INDEX:
                entries += MessageIndex.read(ReadDataStream(BytesIO(body))).records
            position += _RECORD_HEAD.size + length
        return [log_time for log_time, _ in sorted(entries, key=lambda entry: entry[1])]

    # reading

    def _type_name(self, channel: Channel) -> str:
        schema = self._schemas.get(channel.schema_id)
        return schema.name if schema is not None else ""

    def _read_summary(self) -> bool:
        """Use the summary section when the file is complete; False when it must be scanned."""
        if self.size_bytes < 2 * len(MCAP_MAGIC) or not self._magic_at(self.size_bytes - len(MCAP_MAGIC)):
            return False
        self._stream.seek(0)
        try:
            summary = SeekingReader(self._stream).get_summary()
        except Exception:  # noqa: BLE001 - any failure here means: no usable summary, scan instead
            return False
        if summary is None or summary.statistics is None:
            return False
        stats = summary.statistics
        if stats.message_count and not summary.chunk_indexes:
            return False  # messages outside chunks: only a scan finds them
        if any(index.chunk_start_offset + index.chunk_length > self.size_bytes for index in summary.chunk_indexes):
            return False
        self._schemas = dict(summary.schemas)
        self._channels = dict(summary.channels)
        self._counts = Counter(stats.channel_message_counts)
        self._spans = sorted(_Span(i.message_start_time, i.chunk_start_offset) for i in summary.chunk_indexes)
        self._chunk_indexes = sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
        if stats.message_count:
            self.start_ns, self.end_ns = stats.message_start_time, stats.message_end_time
        return True

    def _scan(self) -> None:
        """Walk the records from the start, stopping at the first truncated or corrupt one."""
        position = len(MCAP_MAGIC)
        times: list[int] = []
        self._scanned_times = []
        while True:
            record = self._read_record(position)
            if record is None:
                self.damage = f"truncated at byte {position} of {self.size_bytes} (no footer); read up to the last complete chunk"
                break
            opcode, body = record
            counts_before = Counter(self._counts)
            try:
                self._scan_record(opcode, body, position, times)
            except Exception as err:  # noqa: BLE001 - corrupt bytes raise many kinds
                self._counts = counts_before
                self.damage = f"corrupt record at byte {position} ({_describe(err)}); read up to the chunk before it"
                break
            position += _RECORD_HEAD.size + len(body)
            if opcode == Opcode.FOOTER:
                if not self._magic_at(position):
                    self.damage = f"summary present but the closing magic bytes at byte {position} are missing"
                break
        if times:
            self.start_ns, self.end_ns = min(times), max(times)
        self._spans.sort()

    def _scan_record(self, opcode: int, body: bytes, position: int, times: list[int]) -> None:
        stream = ReadDataStream(BytesIO(body))
        if opcode == Opcode.CHUNK:
            records = breakup_chunk(Chunk.read(stream), validate_crc=True)
            messages = [r for r in records if isinstance(r, Message)]
            for record in records:
                self._remember(record)
            if messages:
                self._spans.append(_Span(min(m.log_time for m in messages), position))
                times.extend((min(m.log_time for m in messages), max(m.log_time for m in messages)))
                self._scanned_times.extend(m.log_time for m in messages)
        elif opcode == Opcode.MESSAGE:
            message = Message.read(stream, len(body))
            self._remember(message)
            self._spans.append(_Span(message.log_time, position))
            times.append(message.log_time)
            self._scanned_times.append(message.log_time)
        elif opcode == Opcode.SCHEMA:
            self._remember(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            self._remember(Channel.read(stream))

    def _remember(self, record: object) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channels[record.id] = record
        elif isinstance(record, Message):
            if record.channel_id not in self._channels:
                raise ValueError(f"message on undeclared channel {record.channel_id}")
            self._counts[record.channel_id] += 1

    def _magic_at(self, position: int) -> bool:
        self._stream.seek(position)
        return self._stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC

    def _read_record(self, position: int) -> tuple[int, bytes] | None:
        """Opcode and body of the record at `position`, None when the file ends inside it."""
        if position + _RECORD_HEAD.size > self.size_bytes:
            return None
        self._stream.seek(position)
        opcode, length = _RECORD_HEAD.unpack(self._stream.read(_RECORD_HEAD.size))
        if position + _RECORD_HEAD.size + length > self.size_bytes:
            return None
        return opcode, self._stream.read(length)

    def _span_reader(self, span: _Span, wanted: set[int]) -> Callable[[], Iterator[BagMessage]]:
        def read() -> Iterator[BagMessage]:
            record = self._read_record(span.offset)
            if record is None:
                raise BagError(f"{self.path}: record at byte {span.offset} is cut off")
            opcode, body = record
            try:
                if opcode == Opcode.CHUNK:
                    records = breakup_chunk(Chunk.read(ReadDataStream(BytesIO(body))), validate_crc=True)
                else:
                    records = [Message.read(ReadDataStream(BytesIO(body)), len(body))]
            except Exception as err:  # noqa: BLE001 - corrupt bytes raise many kinds
                raise BagError(f"{self.path}: chunk at byte {span.offset} is corrupt ({_describe(err)})") from None
            found = [r for r in records if isinstance(r, Message) and r.channel_id in wanted]
            found.sort(key=lambda m: m.log_time)
            for message in found:
                channel = self._channels[message.channel_id]
                yield BagMessage(channel.topic, self._type_name(channel), message.log_time, message.data)

        return read


def merge_by_time(
    sources: list[tuple[int, Callable[[], Iterator[T]]]], key: Callable[[T], int]
) -> Iterator[T]:
    """Merge time-sorted sources, opening each only once the merge reaches its start time."""
    pending = sorted(sources, key=lambda source: source[0])
    heap: list[tuple[int, int, T, Iterator[T]]] = []
    tie = itertools.count()
    next_source = 0
    while heap or next_source < len(pending):
        while next_source < len(pending) and (not heap or pending[next_source][0] <= heap[0][0]):
            iterator = pending[next_source][1]()
            next_source += 1
            for item in iterator:
                heapq.heappush(heap, (key(item), next(tie), item, iterator))
                break
        if not heap:
            continue
        _, _, item, iterator = heapq.heappop(heap)
        yield item
        for following in iterator:
            heapq.heappush(heap, (key(following), next(tie), following, iterator))
            break


def _describe(err: BaseException) -> str:
    text = str(err).splitlines()[0] if str(err) else ""
    return f"{type(err).__name__}: {text}" if text else type(err).__name__
