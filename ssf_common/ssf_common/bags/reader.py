"""Open any rosbag2 input and read its messages in time order.

Accepted: a bag directory with metadata.yaml (versions 1-9, MCAP or sqlite3 storage, split into several
files), a directory whose metadata.yaml is missing (the recorder was killed), or a bare .mcap / .db3
file. Types the project's store does not know are registered from the definitions the bag embeds.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from ssf_common import messages
from ssf_common.config import read_yaml_document
from ssf_common.bags.qos import parse_profiles
from ssf_common.bags.storage_mcap import MCAP_MAGIC, McapFile, merge_by_time
from ssf_common.bags.storage_sqlite3 import SQLITE_MAGIC, Sqlite3File
from ssf_common.bags.timeline import Timeline, judge
from ssf_common.bags.types import BagInfo, BagMessage, FileInfo, TopicInfo, TypeDefinition
from ssf_common.errors import BagError, ConfigError, MessageError

METADATA_FILE = "metadata.yaml"
MAX_METADATA_VERSION = 9


class StorageFile(Protocol):
    """What the reader needs from one storage file."""

    path: Path
    size_bytes: int
    storage: str
    damage: str | None
    start_ns: int
    end_ns: int

    @property
    def message_count(self) -> int: ...

    def topics(self) -> list[TopicInfo]: ...

    def definitions(self) -> list[TypeDefinition]: ...

    def messages(self, topics: frozenset[str] | None = None) -> Iterator[BagMessage]: ...

    def timestamps(self) -> np.ndarray: ...

    def close(self) -> None: ...


STORAGES: dict[str, type] = {"mcap": McapFile, "sqlite3": Sqlite3File}
SUFFIXES = {".mcap": "mcap", ".db3": "sqlite3"}


class BagMetadata(NamedTuple):
    """The parts of metadata.yaml the reader uses."""

    version: int
    storage: str
    file_names: tuple[str, ...]
    topics: dict[str, TopicInfo]
    compression_format: str
    compression_mode: str
    ros_distro: str
    custom_data: tuple[tuple[str, str], ...]


def read_metadata(path: Path) -> BagMetadata:
    """Parse a rosbag2 metadata.yaml, naming the first problem in one line."""
    try:
        document = read_yaml_document(path)
    except ConfigError as err:
        raise BagError(str(err)) from None
    info = document.get("rosbag2_bagfile_information") if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{path}: no 'rosbag2_bagfile_information' mapping")
    try:
        version = int(info["version"])
        storage = str(info["storage_identifier"])
        file_names = tuple(Path(str(name)).name for name in info["relative_file_paths"])
        topics = {}
        for entry in info.get("topics_with_message_count") or []:
            meta = entry["topic_metadata"]
            where = f"{path}: topic {meta['name']}"
            topics[meta["name"]] = TopicInfo(
                name=meta["name"],
                type_name=meta["type"],
                message_count=int(entry.get("message_count", 0)),
                serialization_format=meta.get("serialization_format", "cdr"),
                offered_qos=parse_profiles(meta.get("offered_qos_profiles"), where),
                type_hash=meta.get("type_description_hash") or "",
            )
        custom = info.get("custom_data") or {}
        return BagMetadata(
            version=version,
            storage=storage,
            file_names=file_names,
            topics=topics,
            compression_format=str(info.get("compression_format") or ""),
            compression_mode=str(info.get("compression_mode") or ""),
            ros_distro=str(info.get("ros_distro") or ""),
            custom_data=tuple((str(k), str(v)) for k, v in dict(custom).items()),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise BagError(f"{path}: malformed rosbag2 metadata ({type(err).__name__}: {err})") from None


class BagReader:
    """An open bag: its summary, its topics, and its messages merged across files in time order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.metadata, storage_paths = _locate(self.path)
        except OSError as err:
            raise BagError(f"{self.path}: cannot read ({err.strerror or type(err).__name__})") from None
        self._files: list[StorageFile] = []
        try:
            for storage, file_path in storage_paths:
                self._files.append(_open_storage(storage, file_path))
        except BaseException:
            self.close()
            raise
        self.topics = self._merge_topics()
        self.unknown_types = self._register_definitions()
        self.info = self._summarize()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close every storage file."""
        for storage_file in self._files:
            storage_file.close()
        self._files = []

    def _summarize(self) -> BagInfo:
        """What the bag holds, from its storage files (metadata.yaml fills in what they lack)."""
        readable = [f for f in self._files if f.message_count]
        meta = self.metadata
        return BagInfo(
            path=self.path,
            storage=self._files[0].storage,
            metadata_version=meta.version if meta else None,
            ros_distro=meta.ros_distro if meta else "",
            files=tuple(
                FileInfo(f.path, f.size_bytes, f.message_count, f.start_ns, f.end_ns, f.damage) for f in self._files
            ),
            topics=tuple(self.topics.values()),
            message_count=sum(f.message_count for f in self._files),
            start_ns=min((f.start_ns for f in readable), default=0),
            end_ns=max((f.end_ns for f in readable), default=0),
            compression_format=meta.compression_format if meta else "",
            compression_mode=meta.compression_mode if meta else "",
            custom_data=meta.custom_data if meta else (),
        )

    @functools.cached_property
    def timeline(self) -> Timeline:
        """The span the recording covers and the messages stamped outside it (read from indexes, not data)."""
        return judge([f.timestamps() for f in self._files if f.message_count])

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Every message (or those of `topics`) in receive-time order across all files."""
        selected = None if topics is None else frozenset(topics)
        if selected is not None and (missing := sorted(selected - set(self.topics))):
            raise BagError(f"{self.path}: no topic {', '.join(missing)} in the bag")
        sources = [(f.start_ns, _bind_messages(f, selected)) for f in self._files if f.message_count]
        return merge_by_time(sources, key=lambda message: message.timestamp_ns)

    def decode(self, message: BagMessage) -> Any:
        """The message as a dataclass of the project's type store."""
        self.require_types([message.topic])
        try:
            return messages.deserialize(message.data, message.type_name)
        except MessageError as err:
            raise BagError(f"{self.path}: topic {message.topic} at {message.timestamp_ns} ns: {err}") from None

    def require_types(self, topics: Iterable[str] | None = None) -> None:
        """Raise one BagError line if a topic's type is unknown and the bag holds no definition of it."""
        names = self.topics if topics is None else topics
        for name in names:
            type_name = self.topics[name].type_name
            if type_name in self.unknown_types:
                raise BagError(
                    f"{self.path}: topic {name} has type '{type_name or '(none)'}', which is neither a ROS 2 Jazzy"
                    " nor an ssf_interfaces type, and the bag embeds no usable definition of it"
                )

    def _merge_topics(self) -> dict[str, TopicInfo]:
        merged: dict[str, TopicInfo] = {}
        for storage_file in self._files:
            for topic in storage_file.topics():
                known = merged.get(topic.name)
                if known is None:
                    merged[topic.name] = topic
                else:
                    merged[topic.name] = known._replace(
                        message_count=known.message_count + topic.message_count,
                        offered_qos=known.offered_qos or topic.offered_qos,
                        type_hash=known.type_hash or topic.type_hash,
                    )
        for name, described in (self.metadata.topics if self.metadata else {}).items():
            stored = merged.get(name)
            if stored is None:
                merged[name] = described._replace(message_count=0)
            else:
                merged[name] = stored._replace(
                    type_name=stored.type_name or described.type_name,
                    offered_qos=stored.offered_qos or described.offered_qos,
                    type_hash=stored.type_hash or described.type_hash,
                )
        return merged

    def _register_definitions(self) -> frozenset[str]:
        """Teach the type store the bag's embedded definitions; return the types still unknown."""
        store_types = messages.typestore().types
        for storage_file in self._files:
            for definition in storage_file.definitions():
                name = messages.normalize_type_name(definition.type_name)
                if name in store_types or definition.encoding != "ros2msg":
                    continue
                try:
                    messages.register_definitions({name: definition.text})
                except Exception:  # noqa: BLE001 - a broken definition leaves the type unknown, reported on use
                    continue
        return frozenset(t.type_name for t in self.topics.values() if t.type_name not in store_types)


def open_bag(path: str | Path) -> BagReader:
    """Open a bag directory or storage file."""
    return BagReader(path)


def _bind_messages(storage_file: StorageFile, topics: frozenset[str] | None):
    return lambda: storage_file.messages(topics)


def _open_storage(storage: str, path: Path) -> StorageFile:
    try:
        return STORAGES[storage](path)
    except OSError as err:
        raise BagError(f"{path}: cannot open ({err.strerror or type(err).__name__})") from None


def _locate(path: Path) -> tuple[BagMetadata | None, list[tuple[str, Path]]]:
    """metadata.yaml (if any) and the storage files of a bag path."""
    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    if path.is_file() and path.name == METADATA_FILE:
        path = path.parent
    if path.is_file():
        return None, [(_sniff_storage(path), path)]
    metadata_path = path / METADATA_FILE
    if metadata_path.is_file():
        meta = read_metadata(metadata_path)
        _check_metadata(meta, metadata_path)
        files = [path / name for name in meta.file_names]
        if missing := [f.name for f in files if not f.is_file()]:
            raise BagError(f"{path}: storage file {missing[0]} listed in metadata.yaml is missing")
        return meta, [(meta.storage, f) for f in files]
    files = sorted((f for f in path.iterdir() if f.suffix in SUFFIXES and f.is_file()), key=_split_order)
    if not files:
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml, no .mcap or .db3 file)")
    storages = {SUFFIXES[f.suffix] for f in files}
    if len(storages) > 1:
        raise BagError(f"{path}: holds both .mcap and .db3 files and no metadata.yaml to tell which form the bag")
    storage = storages.pop()
    return None, [(storage, f) for f in files]


def _check_metadata(meta: BagMetadata, where: Path) -> None:
    if not 1 <= meta.version <= MAX_METADATA_VERSION:
        raise BagError(f"{where}: metadata version {meta.version} is not supported (1 to {MAX_METADATA_VERSION})")
    if meta.storage not in STORAGES:
        raise BagError(f"{where}: storage '{meta.storage}' is not supported (mcap or sqlite3)")
    if meta.compression_mode:
        raise BagError(
            f"{where}: rosbag2 {meta.compression_mode}-compressed bags are not supported;"
            " decompress it with `ros2 bag convert` first"
        )
    if not meta.file_names:
        raise BagError(f"{where}: lists no storage files")


def _sniff_storage(path: Path) -> str:
    if path.suffix in SUFFIXES:
        return SUFFIXES[path.suffix]
    with path.open("rb") as stream:
        head = stream.read(16)
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(SQLITE_MAGIC):
        return "sqlite3"
    raise BagError(f"{path}: not a rosbag2 storage file (neither MCAP nor sqlite3)")


def _split_order(path: Path) -> tuple[str, int, str]:
    """Order split files by their trailing index: bag_2 before bag_10."""
    match = re.match(r"^(.*?)(\d+)$", path.stem)
    if match:
        return match.group(1), int(match.group(2)), path.suffix
    return path.stem, -1, path.suffix
