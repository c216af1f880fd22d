"""Read one sqlite3 storage file of a rosbag2 bag (every schema version rosbag2 has written)."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ssf_common.bags.qos import parse_profiles
from ssf_common.bags.types import BagMessage, TopicInfo, TypeDefinition
from ssf_common.errors import BagError

SQLITE_MAGIC = b"SQLite format 3\x00"
# rosbag2 stores INTEGER timestamps and BLOB data; rows that hold anything else are skipped and reported.
_VALID_ROW = "typeof(topic_id) = 'integer' AND typeof(timestamp) = 'integer' AND typeof(data) = 'blob'"


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
        except (sqlite3.Error, UnicodeDecodeError) as err:  # text columns that are not UTF-8 raise the latter
            self._db.close()
            raise BagError(f"{path}: cannot read the sqlite3 bag ({type(err).__name__}: {err})") from None

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
        for row in rows:
            self._check_topic_row(row)
        self._topics = {row[0]: row[1:] for row in rows}
        stats = self._db.execute(
            f"SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) FROM messages WHERE {_VALID_ROW} "  # noqa: S608
            "GROUP BY topic_id"
        ).fetchall()
        self._counts = {topic_id: count for topic_id, count, _, _ in stats}
        unknown = set(self._counts) - set(self._topics)
        if unknown:
            raise BagError(f"{self.path}: messages refer to undeclared topic ids {sorted(unknown)}")
        bad, first_bad = self._db.execute(
            f"SELECT COUNT(*), MIN(id) FROM messages WHERE NOT ({_VALID_ROW})"  # noqa: S608
        ).fetchone()
        if bad:
            self.damage = (
                f"{bad} message rows (the first with id {first_bad}) have a timestamp that is not an INTEGER or data "
                "that is not a BLOB; skipped"
            )
        self.start_ns = min((row[2] for row in stats), default=0)
        self.end_ns = max((row[3] for row in stats), default=0)
        self._definitions: list[TypeDefinition] = []
        if "message_definitions" in tables:
            self._definitions = [
                TypeDefinition(*(str(value) if value is not None else "" for value in row))
                for row in self._db.execute(
                    "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
                )
            ]

    def _check_topic_row(self, row: tuple) -> None:
        topic_id, name, type_name, fmt, qos, type_hash = row
        if not isinstance(topic_id, int) or isinstance(topic_id, bool):
            raise BagError(f"{self.path}: topics table: id {topic_id!r} is not an integer")
        for column, value in (("name", name), ("type", type_name), ("serialization_format", fmt)):
            if not isinstance(value, str):
                raise BagError(f"{self.path}: topics table, topic id {topic_id}: {column} {value!r} is not text")
        for column, value in (("offered_qos_profiles", qos), ("type_description_hash", type_hash)):
            if value is not None and not isinstance(value, str):
                raise BagError(f"{self.path}: topics table, topic {name}: {column} is not text")

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
        query = (
            f"SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({marks}) AND {_VALID_ROW} "  # noqa: S608
            "ORDER BY timestamp, id"
        )
        try:
            for topic_id, timestamp, data in self._db.execute(query, tuple(wanted)):
                name, type_name = wanted[topic_id][:2]
                yield BagMessage(name, type_name, int(timestamp), bytes(data))
        except sqlite3.Error as err:
            raise BagError(f"{self.path}: cannot read messages ({err})") from None

    def timestamps(self) -> np.ndarray:
        """Every readable message's timestamp (int64 ns) in the order the rows were stored."""
        try:
            rows = self._db.execute(f"SELECT timestamp FROM messages WHERE {_VALID_ROW} ORDER BY id").fetchall()  # noqa: S608
        except sqlite3.Error as err:
            raise BagError(f"{self.path}: cannot read message timestamps ({err})") from None
        return np.fromiter((row[0] for row in rows), dtype=np.int64, count=len(rows))
