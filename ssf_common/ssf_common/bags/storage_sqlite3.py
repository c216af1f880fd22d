"""Read one sqlite3 storage file of a rosbag2 bag (every schema version rosbag2 has written)."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

from ssf_common.bags.qos import parse_profiles
from ssf_common.bags.types import BagMessage, TopicInfo, TypeDefinition
from ssf_common.errors import BagError

SQLITE_MAGIC = b"SQLite format 3\x00"


class Sqlite3File:
    """One .db3 file: topics, counts, and messages in timestamp order."""

    storage = "sqlite3"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size_bytes = path.stat().st_size
        self.damage: str | None = None
        with path.open("rb") as stream:
            if stream.read(len(SQLITE_MAGIC)) != SQLITE_MAGIC:
                raise BagError(f"{path}: not an sqlite3 database (bad magic bytes)")
        self._db = sqlite3.connect(f"file:{quote(str(path.resolve()))}?mode=ro", uri=True)
        try:
            self._load()
        except sqlite3.Error as err:
            self._db.close()
            raise BagError(f"{path}: cannot read the sqlite3 bag ({err})") from None

    def _load(self) -> None:
        tables = {row[0] for row in self._db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not {"topics", "messages"} <= tables:
            raise BagError(f"{self.path}: not a rosbag2 database (no 'topics' and 'messages' tables)")
        columns = {row[1] for row in self._db.execute("PRAGMA table_info(topics)")}
        qos_column = "offered_qos_profiles" if "offered_qos_profiles" in columns else "''"
        hash_column = "type_description_hash" if "type_description_hash" in columns else "''"
        rows = self._db.execute(
            f"SELECT id, name, type, serialization_format, {qos_column}, {hash_column} FROM topics"  # noqa: S608
        ).fetchall()
        self._topics = {row[0]: row[1:] for row in rows}
        stats = self._db.execute(
            "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) FROM messages GROUP BY topic_id"
        ).fetchall()
        self._counts = {topic_id: count for topic_id, count, _, _ in stats}
        unknown = set(self._counts) - set(self._topics)
        if unknown:
            raise BagError(f"{self.path}: messages refer to undeclared topic ids {sorted(unknown)}")
        self.start_ns = min((row[2] for row in stats), default=0)
        self.end_ns = max((row[3] for row in stats), default=0)
        self._definitions: list[TypeDefinition] = []
        if "message_definitions" in tables:
            self._definitions = [
                TypeDefinition(*row)
                for row in self._db.execute(
                    "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
                )
            ]

    def close(self) -> None:
        """Release the database."""
        self._db.close()

    @property
    def message_count(self) -> int:
        """Messages stored in this file."""
        return sum(self._counts.values())

    def topics(self) -> list[TopicInfo]:
        """Topics with their types, counts and offered QoS."""
        return [
            TopicInfo(
                name=name,
                type_name=type_name,
                message_count=self._counts.get(topic_id, 0),
                serialization_format=fmt,
                offered_qos=parse_profiles(qos, f"{self.path.name}: topic {name}"),
                type_hash=type_hash or "",
            )
            for topic_id, (name, type_name, fmt, qos, type_hash) in self._topics.items()
        ]

    def definitions(self) -> list[TypeDefinition]:
        """Definitions from the message_definitions table (rosbag2 Iron and later)."""
        return list(self._definitions)

    def messages(self, topics: frozenset[str] | None = None) -> Iterator[BagMessage]:
        """Messages in timestamp order."""
        wanted = {tid: row for tid, row in self._topics.items() if topics is None or row[0] in topics}
        if not wanted:
            return
        marks = ",".join("?" * len(wanted))
        query = f"SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({marks}) ORDER BY timestamp, id"  # noqa: S608
        try:
            for topic_id, timestamp, data in self._db.execute(query, tuple(wanted)):
                name, type_name = wanted[topic_id][:2]
                yield BagMessage(name, type_name, int(timestamp), bytes(data))
        except sqlite3.Error as err:
            raise BagError(f"{self.path}: cannot read messages ({err})") from None
