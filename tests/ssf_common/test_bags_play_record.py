"""`ssf bag play` into `ssf record` over the embedded DDS backend: bytes, timing, QoS and clean stops."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader as RosbagsReader

from ssf_common import messages
from ssf_common.bags.qos import QosReliability, default_profile
from ssf_common.bags.reader import open_bag
from ssf_common.bags.writer import BagWriter
from support import PointCloud2_

T0 = 1_650_000_000_000_000_000
CHATTER_PERIOD_NS = 50_000_000
CHATTER_COUNT = 40
CLOUD_COUNT = 6


def ssf_command(*args: str) -> list[str]:
    """argv of the `ssf` command line run by this interpreter."""
    return [sys.executable, "-m", "ssf_common.cli", *args]


def start_recorder(directory: Path, *topics: str) -> subprocess.Popen:
    """Start `ssf record` and return once its node has joined the graph."""
    recorder = subprocess.Popen(
        ssf_command("record", "-o", str(directory), *topics), stderr=subprocess.PIPE, text=True
    )
    for line in recorder.stderr:
        if "started" in line:
            return recorder
    raise AssertionError(f"recorder exited early with {recorder.wait()}")


def stop(process: subprocess.Popen, sig: int) -> str:
    """Signal a process, wait for it, and return the rest of its stderr."""
    process.send_signal(sig)
    try:
        _, err = process.communicate(timeout=30)
    finally:
        process.kill()
    return err or ""


@pytest.fixture(scope="module")
def source_bag(tmp_path_factory) -> Path:
    """A 2 s bag: /chatter (reliable, 20 Hz) and /lidar/points (best effort, 3 Hz)."""
    directory = tmp_path_factory.mktemp("source") / "bag"
    string = messages.msg_type("std_msgs/msg/String")
    cloud_type = messages.msg_type("sensor_msgs/msg/PointCloud2")
    field = messages.msg_type("sensor_msgs/msg/PointField")
    with BagWriter(directory) as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String", [default_profile()])
        writer.add_topic("/lidar/points", "sensor_msgs/msg/PointCloud2", [default_profile(reliable=False, depth=5)])
        for i in range(CHATTER_COUNT):
            stamp = T0 + i * CHATTER_PERIOD_NS
            writer.write("/chatter", messages.serialize(string(data=f"hello {i}" + "!" * (i % 4))), stamp)
            if i % 7 == 0:
                points = np.random.default_rng(i).normal(size=(2048, 4)).astype(np.float32)
                cloud = cloud_type(
                    header=messages.header(stamp, "lidar"), height=1, width=2048,
                    fields=[field(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate("xyzi")],
                    is_bigendian=False, point_step=16, row_step=16 * 2048,
                    data=points.view(np.uint8).reshape(-1).copy(), is_dense=True,
                )  # fmt: skip
                writer.write("/lidar/points", messages.serialize(cloud), stamp + 1000)
    return directory


def same_bytes(recorded: bytes, original: bytes) -> bool:
    """Equal, allowing the zero padding DDS adds to reach a multiple of four bytes."""
    padding = recorded[len(original) :]
    return recorded[: len(original)] == original and len(padding) < 4 and not padding.strip(b"\0")


def test_play_then_record_keeps_bytes_timing_qos_and_clock(source_bag, tmp_path):
    recorded_dir = tmp_path / "recorded"
    recorder = start_recorder(recorded_dir)
    player = subprocess.run(
        ssf_command("bag", "play", str(source_bag), "--rate", "2", "--clock", "--delay", "1.5"),
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert player.returncode == 0, player.stderr
    assert f"played {CHATTER_COUNT + CLOUD_COUNT} messages" in player.stderr
    time.sleep(0.5)
    log = stop(recorder, signal.SIGINT)
    assert recorder.returncode == 0, log
    with open_bag(source_bag) as original, open_bag(recorded_dir) as recorded:
        assert not recorded.info.damage and recorded.info.metadata_version == 9
        for topic in ("/chatter", "/lidar/points"):
            sent = [m.data for m in original.messages([topic])]
            got = [m.data for m in recorded.messages([topic])]
            assert len(got) == len(sent), topic
            assert all(same_bytes(g, s) for g, s in zip(got, sent)), topic
        chatter = [m.timestamp_ns for m in recorded.messages(["/chatter"])]
        span_s = (chatter[-1] - chatter[0]) * 1e-9
        expected_s = (CHATTER_COUNT - 1) * CHATTER_PERIOD_NS * 1e-9 / 2
        assert abs(span_s - expected_s) < 0.25 * expected_s
        gaps = np.diff(chatter) * 1e-9
        assert np.median(gaps) == pytest.approx(CHATTER_PERIOD_NS * 1e-9 / 2, rel=0.3)
        (lidar_qos,) = recorded.topics["/lidar/points"].offered_qos
        assert lidar_qos.reliability is QosReliability.BEST_EFFORT
        (chatter_qos,) = recorded.topics["/chatter"].offered_qos
        assert chatter_qos.reliability is QosReliability.RELIABLE
        clock = [recorded.decode(m) for m in recorded.messages(["/clock"])]
        clock_ns = [messages.stamp_ns(c.clock) for c in clock]
        assert clock_ns[0] == T0 and clock_ns == sorted(clock_ns)
        assert len(clock) >= 0.8 * (CHATTER_COUNT - 1) * CHATTER_PERIOD_NS / 10_000_000
        with RosbagsReader(recorded_dir) as reader:
            assert reader.message_count == recorded.info.message_count


def test_record_closes_a_valid_bag_on_sigterm_while_a_looping_player_runs(source_bag, tmp_path):
    recorded_dir = tmp_path / "recorded"
    recorder = start_recorder(recorded_dir, "/chatter")
    player = subprocess.Popen(
        ssf_command("bag", "play", str(source_bag), "--loop", "--rate", "4", "--topics", "/chatter"),
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        time.sleep(3.5)
        log = stop(recorder, signal.SIGTERM)
        assert recorder.returncode == 0, log
    finally:
        player_log = stop(player, signal.SIGINT)
    assert player.returncode == 0, player_log
    assert "pass(es)" in player_log
    assert (recorded_dir / "metadata.yaml").is_file()
    with open_bag(recorded_dir) as bag:
        assert not bag.info.damage
        assert set(bag.topics) == {"/chatter"}
        texts = [bag.decode(m).data for m in bag.messages()]
    assert len(texts) > 10
    assert all(t.startswith("hello ") for t in texts)


def test_a_plain_ros2_type_subscriber_receives_the_played_clouds(source_bag):
    """Stands in for `ros2 topic echo /lidar/points`: plain Cyclone, the ROS 2 DDS type name, no project code."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from ssf_common.middleware.embedded import Participant

    foreign = DomainParticipant(Participant.get().domain_id)
    reader = DataReader(
        foreign,
        Topic(foreign, "rt/lidar/points", PointCloud2_),
        Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(20), Policy.DataRepresentation(use_cdrv0_representation=True)),
    )
    player = subprocess.run(
        ssf_command("bag", "play", str(source_bag), "--topics", "/lidar/points", "--delay", "1.5"),
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert player.returncode == 0, player.stderr
    clouds = [s for s in reader.take(N=20) if isinstance(s, PointCloud2_)]
    with open_bag(source_bag) as bag:
        sent = [bag.decode(m) for m in bag.messages(["/lidar/points"])]
    assert len(clouds) == len(sent) == CLOUD_COUNT
    for got, expected in zip(clouds, sent):
        assert (got.header.stamp.sec, got.header.stamp.nanosec) == (expected.header.stamp.sec, expected.header.stamp.nanosec)
        assert [f.name for f in got.fields] == ["x", "y", "z", "i"]
        assert bytes(got.data) == expected.data.tobytes()


class FakePublisher:
    """Stands in for a middleware publisher: logs what is published."""

    def __init__(self, log: list, topic: str, on_publish=None) -> None:
        self.log, self.topic, self.on_publish = log, topic, on_publish

    def publish(self, msg) -> None:
        self.log.append((self.topic, msg))

    def publish_raw(self, data: bytes) -> None:
        self.log.append((self.topic, data))
        if self.on_publish:
            self.on_publish()


class FakeNode:
    """Stands in for a middleware node: hands out fake publishers and remembers their QoS."""

    def __init__(self, on_publish=None) -> None:
        self.log: list = []
        self.qos: dict = {}
        self.on_publish = on_publish

    def create_publisher(self, type_name: str, topic: str, qos):
        self.qos[topic] = qos
        return FakePublisher(self.log, topic, self.on_publish)


def test_player_keeps_order_recorded_qos_and_ticks_clock_at_100_hz_of_bag_time(shared_data):
    import threading

    from ssf_common.bags.play import Player, PlayOptions
    from ssf_common.middleware import Durability, Reliability

    node = FakeNode()
    with open_bag(shared_data / "ros2_bags" / "talker_mcap") as bag:
        stats = Player(bag, PlayOptions(rate=100.0, clock=True), node, threading.Event()).run()
        expected = [(m.topic, m.data) for m in bag.messages()]
        span_ns = bag.info.duration_ns
    assert stats.messages == 20 and stats.passes == 1
    assert [item for item in node.log if item[0] != "/clock"] == expected
    ticks = [messages.stamp_ns(msg.clock) for topic, msg in node.log if topic == "/clock"]
    assert stats.clock_ticks == len(ticks) == span_ns // 10_000_000 + 1
    assert np.all(np.diff(ticks) == 10_000_000)
    assert node.qos["/rosout"].durability is Durability.TRANSIENT_LOCAL
    assert node.qos["/topic"].durability is Durability.VOLATILE
    assert node.qos["/topic"].reliability is Reliability.RELIABLE


def test_player_loops_until_stopped(shared_data):
    import threading

    from ssf_common.bags.play import Player, PlayOptions

    stop = threading.Event()
    node = FakeNode(on_publish=lambda: len(node.log) >= 50 and stop.set())
    with open_bag(shared_data / "ros2_bags" / "talker_mcap") as bag:
        stats = Player(bag, PlayOptions(rate=1e6, loop=True, topics=("/topic",)), node, stop).run()
    assert stats.messages == 50 and stats.passes == 5
    assert {topic for topic, _ in node.log} == {"/topic"}
