"""Damaged input: truncated or corrupt files, a killed recorder, bad metadata, unknown types, missing paths."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer

from ssf_common import messages
from ssf_common.bags.reader import open_bag
from ssf_common.bags.writer import BagWriter, BagWriterConfig
from ssf_common.errors import BagError

T0 = 1_600_000_000_000_000_000


def run_ssf(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """The `ssf` command line in a child process."""
    return subprocess.run(
        [sys.executable, "-m", "ssf_bringup.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def assert_one_line_error(result: subprocess.CompletedProcess, *fragments: str) -> None:
    """Non-zero exit, one stderr line, no traceback."""
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


@pytest.fixture
def small_chunk_bag(tmp_path):
    """A complete bag of 300 String messages in many small chunks, and the list of what was written."""
    string = messages.msg_type("std_msgs/msg/String")
    sent = []
    with BagWriter(tmp_path / "bag", BagWriterConfig(chunk_bytes=1024)) as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(300):
            data = messages.serialize(string(data=f"message number {i:04d}"))
            writer.write("/chatter", data, T0 + i * 1_000_000)
            sent.append(("/chatter", T0 + i * 1_000_000, data))
    (path,) = (tmp_path / "bag").glob("*.mcap")
    return path, sent


def complete_chunk_messages(path: Path, cut: int) -> int:
    """How many messages lie in chunks that end at or before byte `cut` of the intact file."""
    total = 0
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
        for index in summary.chunk_indexes:
            if index.chunk_start_offset + index.chunk_length <= cut:
                stream.seek(index.chunk_start_offset + 9)
                chunk = Chunk.read(ReadDataStream(stream))
                total += sum(1 for r in breakup_chunk(chunk) if r.__class__.__name__ == "Message")
    return total


def test_truncated_file_yields_every_complete_chunk_or_a_bag_error(small_chunk_bag, tmp_path):
    path, sent = small_chunk_bag
    data = path.read_bytes()
    assert complete_chunk_messages(path, len(data)) == len(sent)
    cuts = sorted({0, 4, 8, 9, 30, 200, len(data) // 3, len(data) // 2, len(data) - 200, len(data) - 9, len(data) - 1})
    for cut in cuts:
        damaged = tmp_path / f"cut_{cut}.mcap"
        damaged.write_bytes(data[:cut])
        try:
            with open_bag(damaged) as bag:
                got = [(m.topic, m.timestamp_ns, m.data) for m in bag.messages()]
                assert bag.info.damage, cut
        except BagError as err:
            assert "\n" not in str(err)
            assert cut < 8  # only a file without even the magic bytes is unreadable
            continue
        assert got == sent[: len(got)], cut
        assert len(got) == complete_chunk_messages(path, cut), cut


def test_random_corruption_never_escapes_as_anything_but_bag_error(small_chunk_bag, tmp_path):
    path, sent = small_chunk_bag
    data = path.read_bytes()
    rng = random.Random(7)
    for trial in range(40):
        corrupt = bytearray(data)
        start = rng.randrange(len(data))
        corrupt[start : start + rng.randint(1, 12)] = bytes(rng.randrange(256) for _ in range(12))[: len(corrupt) - start]
        damaged = tmp_path / f"corrupt_{trial}.mcap"
        damaged.write_bytes(bytes(corrupt))
        try:
            with open_bag(damaged) as bag:
                got = [(m.topic, m.timestamp_ns, m.data) for m in bag.messages()]
        except BagError as err:
            assert "\n" not in str(err)
            continue
        assert all(item in sent for item in got)


KILLED_WRITER = textwrap.dedent(
    """
    import sys
    from ssf_common import messages
    from ssf_common.bags.writer import BagWriter, BagWriterConfig
    writer = BagWriter(sys.argv[1], BagWriterConfig(chunk_bytes=1024, chunk_seconds=0.05))
    writer.add_topic("/chatter", "std_msgs/msg/String")
    string = messages.msg_type("std_msgs/msg/String")
    i = 0
    while True:
        writer.write("/chatter", messages.serialize(string(data=f"killed recording {i}")), 1000 + i)
        i += 1
        if i % 50 == 0:
            print(i, flush=True)
    """
)


def test_finished_chunks_survive_sigkill(tmp_path):
    directory = tmp_path / "killed"
    child = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, str(directory)], stdout=subprocess.PIPE, text=True
    )
    try:
        for line in child.stdout:
            if int(line) >= 400:
                break
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=10)
    assert not (directory / "metadata.yaml").exists()
    string = messages.msg_type("std_msgs/msg/String")
    with open_bag(directory) as bag:
        got = list(bag.messages())
        assert bag.info.damage
        assert bag.info.message_count == len(got)
    assert len(got) >= 380  # at most one chunk (< 1 KiB, ~20 messages) was still open
    assert [m.timestamp_ns for m in got] == list(range(1000, 1000 + len(got)))
    assert [bag.decode(m).data for m in got[:3]] == [f"killed recording {i}" for i in range(3)]
    assert got[0].data == messages.serialize(string(data="killed recording 0"))
    result = run_ssf("bag", "info", str(directory))
    assert result.returncode == 1
    assert f"Messages:          {len(got)}" in result.stdout
    assert_one_line_error(result, "damaged")


def test_bag_info_missing_path_is_one_line(tmp_path):
    assert_one_line_error(run_ssf("bag", "info", str(tmp_path / "nothing_here")), "no such file or directory")


def test_bag_info_on_garbage_is_one_line(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(bytes(random.Random(1).randrange(256) for _ in range(5000)))
    assert_one_line_error(run_ssf("bag", "info", str(garbage)), "not an MCAP file")
    fake_db = tmp_path / "fake.db3"
    fake_db.write_bytes(b"SQLite format 3\x00" + b"\x07" * 4000)
    assert_one_line_error(run_ssf("bag", "info", str(fake_db)), "fake.db3")
    empty_dir = tmp_path / "empty"
    empty_dir.mkdir()
    assert_one_line_error(run_ssf("bag", "info", str(empty_dir)), "not a rosbag2 bag")


@pytest.mark.parametrize(
    ("metadata", "fragment"),
    [
        ("rosbag2_bagfile_information: [unclosed", "not valid YAML at line 1"),
        ("something_else: 1", "rosbag2_bagfile_information"),
        ("rosbag2_bagfile_information:\n  version: 99\n  storage_identifier: mcap\n  relative_file_paths: [a.mcap]",
         "version 99"),
        ("rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  relative_file_paths: [gone.mcap]",
         "gone.mcap"),
        ("rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap", "malformed"),
    ],
)
def test_bad_metadata_is_one_line(tmp_path, metadata, fragment):
    (tmp_path / "metadata.yaml").write_text(metadata)
    assert_one_line_error(run_ssf("bag", "info", str(tmp_path)), fragment)


def write_unknown_type_bag(path: Path) -> None:
    """An MCAP file with one message of a type nobody knows and no definition."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("nope_msgs/msg/Mystery", "ros2msg", b"")
        channel = writer.register_channel("/mystery", "cdr", schema, {"offered_qos_profiles": ""})
        writer.add_message(channel, log_time=5, data=b"\x00\x01\x00\x00\x2a\x00\x00\x00", publish_time=5)
        writer.finish()


def test_unknown_type_is_listed_but_cannot_be_decoded_or_played(tmp_path):
    path = tmp_path / "mystery.mcap"
    write_unknown_type_bag(path)
    with open_bag(path) as bag:
        assert bag.unknown_types == {"nope_msgs/msg/Mystery"}
        (message,) = bag.messages()
        with pytest.raises(BagError, match="nope_msgs/msg/Mystery"):
            bag.decode(message)
    info = run_ssf("bag", "info", str(path))
    assert "nope_msgs/msg/Mystery" in info.stdout
    assert_one_line_error(info, "nope_msgs/msg/Mystery")
    assert_one_line_error(run_ssf("bag", "play", str(path)), "nope_msgs/msg/Mystery")


def test_play_rejects_bad_options_in_one_line(shared_data):
    bag = str(shared_data / "ros2_bags" / "talker_mcap")
    assert_one_line_error(run_ssf("bag", "play", bag, "--rate", "0"), "--rate")
    assert_one_line_error(run_ssf("bag", "play", bag, "--topics", "/nope"), "/nope")


def test_truncated_sqlite_bag_is_one_line(shared_data, tmp_path):
    data = (shared_data / "ros2_bags" / "talker_sqlite3" / "talker.db3").read_bytes()
    cut = tmp_path / "cut.db3"
    cut.write_bytes(data[: len(data) // 2])
    assert_one_line_error(run_ssf("bag", "info", str(cut)), "cut.db3", "malformed")
