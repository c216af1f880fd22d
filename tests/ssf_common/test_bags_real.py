"""Every real bag written by ROS 2's rosbag2 opens, lists its topics, and every message decodes."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ssf_common.bags.qos import QosDurability, QosReliability
from ssf_common.bags.reader import open_bag

BAGS = {
    "talker_mcap": ("mcap", 20, {"/topic": 10, "/rosout": 10, "/parameter_events": 0}),
    "talker_sqlite3": ("sqlite3", 20, {"/topic": 10, "/rosout": 10, "/parameter_events": 0}),
    "cdr_test_mcap": ("mcap", 7, {"/test_topic": 3, "/array_topic": 4}),
    "split_bag_mcap": ("mcap", 6074, {"AAA": 804, "HHH": 726}),
}


@pytest.mark.parametrize("name", sorted(BAGS))
def test_real_bag_opens_iterates_in_time_order_and_decodes(shared_data, name):
    storage, total, counts = BAGS[name]
    directory = shared_data / "ros2_bags" / name
    with open_bag(directory) as bag:
        info = bag.info
        assert info.storage == storage
        assert info.message_count == total
        assert not info.damage
        for topic, count in counts.items():
            assert bag.topics[topic].message_count == count
        stamps = []
        per_topic: dict[str, int] = {}
        for message in bag.messages():
            decoded = bag.decode(message)
            assert decoded.__msgtype__ == message.type_name
            stamps.append(message.timestamp_ns)
            per_topic[message.topic] = per_topic.get(message.topic, 0) + 1
        assert len(stamps) == total
        assert stamps == sorted(stamps)
        assert info.start_ns == stamps[0] and info.end_ns == stamps[-1]
        assert per_topic == {name: t.message_count for name, t in bag.topics.items() if t.message_count}


@pytest.mark.parametrize("name", sorted(BAGS))
def test_each_bare_storage_file_opens_without_metadata(shared_data, name):
    directory = shared_data / "ros2_bags" / name
    files = sorted(p for p in directory.iterdir() if p.suffix in (".mcap", ".db3"))
    total = 0
    for path in files:
        with open_bag(path) as bag:
            assert bag.info.metadata_version is None
            count = sum(1 for _ in bag.messages())
            assert count == bag.info.message_count
            total += count
    assert total == BAGS[name][1]


def test_directory_without_metadata_is_read_from_its_split_files(shared_data, tmp_path):
    source = shared_data / "ros2_bags" / "split_bag_mcap"
    copy = tmp_path / "killed"
    copy.mkdir()
    for path in source.glob("*.mcap"):
        (copy / path.name).write_bytes(path.read_bytes())
    with open_bag(copy) as bag, open_bag(source) as original:
        assert bag.info.metadata_version is None
        assert [f.path.name for f in bag.info.files] == [f"wbag_{i}.mcap" for i in range(5)]
        assert list(bag.messages()) == list(original.messages())


def test_cdr_test_types_come_from_the_embedded_schemas(shared_data):
    with open_bag(shared_data / "ros2_bags" / "cdr_test_mcap") as bag:
        assert bag.unknown_types == frozenset()
        basic = [bag.decode(m) for m in bag.messages(["/test_topic"])]
        arrays = [bag.decode(m) for m in bag.messages(["/array_topic"])]
    assert len(basic) == 3 and len(arrays) == 4
    assert basic[0].__msgtype__ == "test_msgs/msg/BasicTypes"
    assert [b.int32_value for b in basic] == [123, 123, 123]
    assert arrays[0].__msgtype__ == "test_msgs/msg/Arrays"
    assert arrays[0].bool_values.tolist() == [True, False, True]
    assert isinstance(arrays[0].float64_values, np.ndarray) and arrays[0].float64_values.shape == (3,)
    assert arrays[0].string_values_default == ["", "max value", "min value"]


def test_cdr_test_decoding_matches_the_mcap_ros2_decoder(shared_data):
    path = shared_data / "ros2_bags" / "cdr_test_mcap" / "cdr_test_0.mcap"
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        independent = [(channel.topic, decoded) for _, channel, _, decoded in reader.iter_decoded_messages()]
    with open_bag(path) as bag:
        ours = [(m.topic, bag.decode(m)) for m in bag.messages()]
    assert [topic for topic, _ in ours] == [topic for topic, _ in independent]
    for (_, mine), (_, theirs) in zip(ours, independent):
        for field in ("int32_value", "bool_values", "float32_values", "string_values", "uint64_values"):
            if hasattr(mine, field):
                assert np.asarray(getattr(mine, field)).tolist() == np.asarray(getattr(theirs, field)).tolist()


def test_offered_qos_is_parsed_from_integer_profiles(shared_data):
    for name in ("talker_mcap", "talker_sqlite3"):
        with open_bag(shared_data / "ros2_bags" / name) as bag:
            (rosout,) = bag.topics["/rosout"].offered_qos
            (topic,) = bag.topics["/topic"].offered_qos
        assert rosout.reliability is QosReliability.RELIABLE
        assert rosout.durability is QosDurability.TRANSIENT_LOCAL
        assert rosout.lifespan.sec == 10
        assert topic.durability is QosDurability.VOLATILE


def test_split_bag_merges_files_in_time_order(shared_data):
    with open_bag(shared_data / "ros2_bags" / "split_bag_mcap") as bag:
        stamps = [m.timestamp_ns for m in bag.messages(["AAA", "BBB"])]
        assert len(stamps) == 804 + 742
        assert stamps == sorted(stamps)
        assert len(bag.info.files) == 5


def run_ssf(*args: str) -> subprocess.CompletedProcess:
    """The `ssf` command line in a child process."""
    return subprocess.run(
        [sys.executable, "-m", "ssf_bringup.cli", *args], capture_output=True, text=True, timeout=60
    )


@pytest.mark.parametrize("name", sorted(BAGS))
def test_bag_info_cli_prints_a_table_and_json(shared_data, name):
    directory = shared_data / "ros2_bags" / name
    table = run_ssf("bag", "info", str(directory))
    assert table.returncode == 0, table.stderr
    assert f"Messages:          {BAGS[name][1]}" in table.stdout
    assert f"Storage id:        {BAGS[name][0]}" in table.stdout
    as_json = run_ssf("bag", "info", str(directory), "--json")
    assert as_json.returncode == 0, as_json.stderr
    document = json.loads(as_json.stdout)
    assert document["message_count"] == BAGS[name][1]
    metadata = yaml.safe_load((directory / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert document["metadata_version"] == metadata["version"]
    assert {t["name"] for t in document["topics"]} == {
        t["topic_metadata"]["name"] for t in metadata["topics_with_message_count"]
    }


@pytest.mark.parametrize("version", [4, 5, 6, 7, 8, 9])
def test_every_metadata_version_from_4_to_9_opens(shared_data, tmp_path, version):
    source = shared_data / "ros2_bags" / "talker_mcap"
    metadata = yaml.safe_load((source / "metadata.yaml").read_text())
    info = metadata["rosbag2_bagfile_information"]
    info["version"] = version
    if version >= 5:
        info["files"] = [{"path": "talker.mcap", "starting_time": info["starting_time"],
                          "duration": info["duration"], "message_count": info["message_count"]}]  # fmt: skip
    if version >= 6:
        info["custom_data"] = {"note": "copied"}
    if version >= 7:
        for entry in info["topics_with_message_count"]:
            entry["topic_metadata"]["type_description_hash"] = ""
    if version >= 8:
        info["ros_distro"] = "rolling"
    if version >= 9:
        for entry in info["topics_with_message_count"]:
            entry["topic_metadata"]["offered_qos_profiles"] = [
                {"history": "keep_last", "depth": 7, "reliability": "best_effort", "durability": "volatile"}
            ]
    bag_dir = tmp_path / "talker"
    bag_dir.mkdir()
    (bag_dir / "talker.mcap").write_bytes((source / "talker.mcap").read_bytes())
    (bag_dir / "metadata.yaml").write_text(yaml.safe_dump(metadata))
    with open_bag(bag_dir) as bag:
        assert bag.info.metadata_version == version
        assert sum(1 for _ in bag.messages()) == 20
        assert dict(bag.info.custom_data) == ({"note": "copied"} if version >= 6 else {})
        assert bag.info.ros_distro == ("rolling" if version >= 8 else "")
