"""Bag timestamps out of order or implausible, and sqlite3 columns of the wrong type: reported, skipped, one line."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from ssf_bringup.cli import main
from ssf_common import messages
from ssf_common.bags.play import Player, PlayOptions
from ssf_common.bags.reader import open_bag
from support import FakeTime
from ssf_common.bags.timeline import MAX_GAP_NS, judge
from ssf_common.bags.writer import BagWriter

T0 = 1_650_000_000_000_000_000
PERIOD_NS = 100_000_000
COUNT = 20


def chatter(i: int) -> bytes:
    return messages.serialize(messages.msg_type("std_msgs/msg/String")(data=f"hello {i}"))


def write_sqlite_bag(path: Path, rows: list[tuple[int, object, object]]) -> Path:
    """A rosbag2 sqlite3 file (the Jazzy schema) holding (id, timestamp, data) rows on /chatter."""
    db = sqlite3.connect(path)
    db.executescript(
        """
        CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
        CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
            type_description_hash TEXT DEFAULT "" NOT NULL);
        CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL,
            data BLOB NOT NULL);
        INSERT INTO schema VALUES (4, 'jazzy');
        INSERT INTO topics VALUES (1, '/chatter', 'std_msgs/msg/String', 'cdr', '', '');
        """
    )
    db.executemany("INSERT INTO messages VALUES (?, 1, ?, ?)", rows)
    db.commit()
    db.close()
    return path


@pytest.fixture
def outlier_db(tmp_path) -> Path:
    """20 messages 0.1 s apart, two stored out of order, one stamped -5 ns, one at 1.5e18 ns, two TEXT rows."""
    rows = [(i + 1, T0 + i * PERIOD_NS, chatter(i)) for i in range(COUNT)]
    rows[3], rows[4] = (4, rows[4][1], rows[4][2]), (5, rows[3][1], rows[3][2])  # stored swapped
    rows += [(30, -5, chatter(30)), (31, 1_500_000_000_000_000_000, chatter(31))]
    rows += [(32, "yesterday", chatter(32)), (33, T0 + 5, "not bytes")]
    return write_sqlite_bag(tmp_path / "outliers.db3", rows)


def test_the_timeline_keeps_the_recording_and_names_what_lies_outside():
    stored = [np.array([T0, T0 + 10, -5, T0 + 5, T0 + 3 * MAX_GAP_NS], dtype=np.int64), np.array([T0 + 20])]
    timeline = judge(stored)
    assert (timeline.start_ns, timeline.end_ns, timeline.messages) == (T0, T0 + 20, 6)
    assert (timeline.outside, timeline.negative, timeline.out_of_order) == (2, 1, 1)
    assert timeline.outside_examples == (-5, T0 + 3 * MAX_GAP_NS)
    assert not timeline.contains(-5) and timeline.contains(T0 + 10)
    assert "2 of 6 messages have implausible timestamps (1 stamped before 0, 1 more than 1 h from the rest" in (
        timeline.problem()
    )
    assert judge([np.array([T0, T0 + MAX_GAP_NS], dtype=np.int64)]).problem() is None  # an hour apart is one recording
    assert judge([]).messages == 0


def test_sqlite_rows_of_the_wrong_type_are_skipped_and_reported(outlier_db):
    with open_bag(outlier_db) as bag:
        got = list(bag.messages())
        (damage,) = bag.info.damage
        assert bag.info.message_count == COUNT + 2
    assert "2 message rows (the first with id 32) have a timestamp that is not an INTEGER or data that is not a BLOB" in damage
    assert len(got) == COUNT + 2 and all(isinstance(m.data, bytes) for m in got)


def test_bag_info_shows_the_plausible_span_and_warns_in_one_line(outlier_db, capsys):
    assert main(["bag", "info", str(outlier_db)]) == 1
    out, err = capsys.readouterr()
    assert f"Duration:          {(COUNT - 1) * PERIOD_NS / 1e9:.9f}s" in out
    assert f"({T0 // 10**9}.000000000)" in out  # the start is the recording's, not -5 ns
    assert "Timestamps:        2 of 22 messages have implausible timestamps" in out
    assert "2 messages were stored after a later one; they are read in time order" in out  # the swap and -5 ns
    (line,) = err.strip().splitlines()
    assert line.startswith(f"ssf: warning: {outlier_db}: damaged") and "bag play skips them" in line
    assert main(["bag", "info", str(outlier_db), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["start_ns"] == T0 and report["duration_ns"] == (COUNT - 1) * PERIOD_NS
    assert report["timestamps"]["outside_span"] == 2 and report["timestamps"]["negative"] == 1


class Recorder(FakeTime):
    """A fake node whose publishers log what they send, and a fake clock that waiting advances."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: list[tuple[float, bytes]] = []

    def create_publisher(self, _type: str, _topic: str, _qos):
        recorder = self

        class Publisher:
            def publish_raw(self, data: bytes) -> None:
                recorder.sent.append((recorder.now, data))

            def publish(self, _msg) -> None:
                pass

        return Publisher()


def test_bag_play_skips_implausible_stamps_instead_of_sleeping_for_years(outlier_db):
    fake = Recorder()
    with open_bag(outlier_db) as bag:
        stats = Player(bag, PlayOptions(clock=True), fake, fake, clock=fake).run()
    assert stats.messages == COUNT and stats.skipped == 2
    assert fake.now == pytest.approx((COUNT - 1) * PERIOD_NS * 1e-9)  # not 47 years
    assert [data for _, data in fake.sent] == [chatter(i) for i in range(COUNT)]  # in time order, swap undone


def test_an_mcap_bag_with_one_stray_stamp(tmp_path, capsys):
    with BagWriter(tmp_path / "stray") as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(COUNT):
            writer.write("/chatter", chatter(i), i * PERIOD_NS)  # sim time from 0
        writer.write("/chatter", chatter(99), 1_500_000_000_000_000_000)
    assert main(["bag", "info", str(tmp_path / "stray")]) == 1
    out, err = capsys.readouterr()
    assert f"Duration:          {(COUNT - 1) * PERIOD_NS / 1e9:.9f}s" in out
    assert "1 more than 1 h from the rest; 1500000000000000000 ns" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("flag", "value", "fragment"),
    [("--delay", "inf", "--delay must be a finite number"), ("--delay", "-1", "--delay must be at least 0"),
     ("--rate", "nan", "--rate must be a finite number"), ("--rate", "inf", "--rate must be a finite number"),
     ("--rate", "0", "--rate must be above 0")],
)
def test_bag_play_refuses_bad_numbers_before_opening_anything(tmp_path, capsys, flag, value, fragment):
    assert main(["bag", "play", str(tmp_path / "not_read"), flag, value]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"ssf: error: {fragment}, got {value!r}" or line.startswith(f"ssf: error: {fragment}")


def test_a_topics_table_of_the_wrong_types_is_one_line(tmp_path, capsys):
    path = write_sqlite_bag(tmp_path / "topics.db3", [(1, T0, chatter(0))])
    db = sqlite3.connect(path)
    db.execute("UPDATE topics SET type = x'00ff'")  # a BLOB: TEXT affinity would turn a number into text
    db.commit()
    db.close()
    assert main(["bag", "info", str(path)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"ssf: error: {path}: topics table, topic id 1: type b'\\x00\\xff' is not text"
