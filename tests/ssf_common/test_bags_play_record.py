"""`ssf bag play` into `ssf record` over the embedded DDS backend: bytes, timing, QoS and clean stops."""

import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader as RosbagsReader

from ssf_common import messages
from ssf_common.bags.qos import QosReliability, default_profile
from ssf_common.bags.reader import open_bag
from ssf_common.bags.writer import BagWriter
from ssf_common.errors import BagError
from support import FakeTime, PointCloud2_, wait_until

T0 = 1_650_000_000_000_000_000
CHATTER_PERIOD_NS = 50_000_000
CHATTER_COUNT = 40
CLOUD_COUNT = 6
CLOCK_PERIOD_NS = 10_000_000  # `ssf bag play --clock` ticks at 100 Hz of bag time


def ssf_command(*args: str) -> list[str]:
    """argv of the `ssf` command line run by this interpreter."""
    return [sys.executable, "-m", "ssf_bringup.cli", *args]


def start_recorder(directory: Path, *arguments: str) -> subprocess.Popen:
    """Start `ssf record` (topics and flags) and return once its node has joined the graph."""
    recorder = subprocess.Popen(
        ssf_command("record", "-o", str(directory), *arguments), stderr=subprocess.PIPE, text=True
    )
    for line in recorder.stderr:
        if "started" in line:
            return recorder
    raise AssertionError(f"recorder exited early with {recorder.wait()}")


def recorded_counts(directory: Path) -> dict[str, int]:
    """Messages per topic in the finished chunks of a recording still being written."""
    try:
        with open_bag(directory) as bag:
            return {name: topic.message_count for name, topic in bag.topics.items()}
    except BagError:
        return {}


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


def test_play_then_record_keeps_bytes_order_qos_and_clock(source_bag, tmp_path):
    recorded_dir = tmp_path / "recorded"
    recorder = start_recorder(recorded_dir)
    player = subprocess.run(
        ssf_command("bag", "play", str(source_bag), "--rate", "2", "--clock", "--delay", "1.5"),
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert player.returncode == 0, player.stderr
    assert f"played {CHATTER_COUNT + CLOUD_COUNT} messages" in player.stderr
    everything = {"/chatter": CHATTER_COUNT, "/lidar/points": CLOUD_COUNT}
    assert wait_until(lambda: all(recorded_counts(recorded_dir).get(t, 0) == n for t, n in everything.items()))
    log = stop(recorder, signal.SIGINT)
    assert recorder.returncode == 0, log
    with open_bag(source_bag) as original, open_bag(recorded_dir) as recorded:
        assert not recorded.info.damage and recorded.info.metadata_version == 9
        for topic in ("/chatter", "/lidar/points"):
            sent = [m.data for m in original.messages([topic])]
            got = [m.data for m in recorded.messages([topic])]
            assert len(got) == len(sent), topic
            assert all(same_bytes(g, s) for g, s in zip(got, sent)), topic
        (lidar_qos,) = recorded.topics["/lidar/points"].offered_qos
        assert lidar_qos.reliability is QosReliability.BEST_EFFORT
        (chatter_qos,) = recorded.topics["/chatter"].offered_qos
        assert chatter_qos.reliability is QosReliability.RELIABLE
        clock_ns = [messages.stamp_ns(recorded.decode(m).clock) for m in recorded.messages(["/clock"])]
        span_ns = (CHATTER_COUNT - 1) * CHATTER_PERIOD_NS + 1000
        assert clock_ns and clock_ns == sorted(set(clock_ns))  # best effort: some ticks may be missing, none twice
        assert all((stamp - T0) % 10_000_000 == 0 and 0 <= stamp - T0 <= span_ns for stamp in clock_ns)
        with RosbagsReader(recorded_dir) as reader:
            assert reader.message_count == recorded.info.message_count


def test_with_use_sim_time_the_recorder_logs_at_the_clock_and_thins_on_request(source_bag, tmp_path):
    """As `ros2 bag record --use-sim-time`: each message is logged at the latest /clock tick, so the recording of a
    replay twice as fast as real time holds the bag's own times (2022, 10 ms ticks), not the wall clock's; `--every
    /chatter:2` keeps the first message and every other."""
    recorded_dir = tmp_path / "recorded"
    recorder = start_recorder(recorded_dir, "/chatter", "--use-sim-time", "--every", "/chatter:2")
    player = subprocess.run(
        ssf_command("bag", "play", str(source_bag), "--rate", "2", "--clock", "--delay", "1.5", "--topics", "/chatter"),
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert player.returncode == 0, player.stderr
    assert wait_until(lambda: recorded_counts(recorded_dir).get("/chatter", 0) == CHATTER_COUNT // 2)
    log = stop(recorder, signal.SIGINT)
    assert recorder.returncode == 0, log
    with open_bag(recorded_dir) as recorded:
        got = [(m.timestamp_ns, recorded.decode(m).data) for m in recorded.messages(["/chatter"])]
        assert ("log_time", "/clock") in recorded.info.custom_data
    assert [text for _, text in got] == [f"hello {i}" + "!" * (i % 4) for i in range(0, CHATTER_COUNT, 2)]
    logged = np.array([stamp for stamp, _ in got])
    sent = T0 + np.arange(0, CHATTER_COUNT, 2) * CHATTER_PERIOD_NS
    assert ((logged - T0) % CLOCK_PERIOD_NS == 0).all() and (logged >= T0).all()  # every log time is a tick
    assert (np.diff(logged) >= 0).all()
    # a tick published before a message may reach the recorder after it (another reader): the message is logged at
    # an earlier tick, or at a later one when the recorder fell behind; never far from its own time
    assert (np.abs(logged - sent) < 10 * CHATTER_PERIOD_NS).all()


def test_bad_recorder_flags_are_one_line(capsys, tmp_path):
    from ssf_bringup.cli import main

    assert main(["record", "-o", str(tmp_path / "bag"), "--every", "/chatter:0"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: --every '/chatter:0': expected TOPIC:N") and not (tmp_path / "bag").exists()


def test_record_closes_a_valid_bag_on_sigterm_while_a_looping_player_runs(source_bag, tmp_path):
    recorded_dir = tmp_path / "recorded"
    recorder = start_recorder(recorded_dir, "/chatter")
    player = subprocess.Popen(
        ssf_command("bag", "play", str(source_bag), "--loop", "--rate", "4", "--topics", "/chatter"),
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert wait_until(lambda: recorded_counts(recorded_dir).get("/chatter", 0) > 2 * CHATTER_COUNT, timeout_s=60)
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
    assert len(texts) > 2 * CHATTER_COUNT
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
    player = subprocess.Popen(
        ssf_command("bag", "play", str(source_bag), "--topics", "/lidar/points", "--loop", "--rate", "4"),
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    with open_bag(source_bag) as bag:
        sent = [bag.decode(m) for m in bag.messages(["/lidar/points"])]
    stamps = [(c.header.stamp.sec, c.header.stamp.nanosec) for c in sent]
    clouds: dict[tuple[int, int], PointCloud2_] = {}

    def take_all() -> bool:  # best effort: the player loops until every cloud has arrived at least once
        for sample in reader.take(N=20):
            if isinstance(sample, PointCloud2_):
                clouds[(sample.header.stamp.sec, sample.header.stamp.nanosec)] = sample
        return set(stamps) <= set(clouds)

    try:
        assert wait_until(take_all, timeout_s=60), f"got {len(clouds)} of {len(stamps)} clouds"
    finally:
        log = stop(player, signal.SIGINT)
    assert player.returncode == 0, log
    assert len(sent) == CLOUD_COUNT and set(clouds) == set(stamps)
    for expected in sent:
        got = clouds[(expected.header.stamp.sec, expected.header.stamp.nanosec)]
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


def test_player_publishes_each_message_at_its_bag_time_over_the_rate(source_bag):
    from ssf_common.bags.play import Player, PlayOptions

    fake = FakeTime()
    published_at: list[float] = []
    node = FakeNode(on_publish=lambda: published_at.append(fake.now))
    with open_bag(source_bag) as bag:
        stamps = [m.timestamp_ns for m in bag.messages()]
        stats = Player(bag, PlayOptions(rate=2.0, clock=True), node, fake, clock=fake).run()
    assert stats.messages == len(stamps) == CHATTER_COUNT + CLOUD_COUNT and stats.skipped == 0
    expected = [(stamp - stamps[0]) * 1e-9 / 2.0 for stamp in stamps]
    assert published_at == pytest.approx(expected, abs=1e-9)
    ticks = [messages.stamp_ns(msg.clock) for topic, msg in node.log if topic == "/clock"]
    assert ticks == list(range(T0, stamps[-1] + 1, 10_000_000))


def test_player_keeps_order_recorded_qos_and_ticks_clock_at_100_hz_of_bag_time(shared_data):
    from ssf_common.bags.play import Player, PlayOptions
    from ssf_common.middleware import Durability, Reliability

    node = FakeNode()
    fake = FakeTime()
    with open_bag(shared_data / "ros2_bags" / "talker_mcap") as bag:
        stats = Player(bag, PlayOptions(rate=100.0, clock=True), node, fake, clock=fake).run()
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
    from ssf_common.bags.play import Player, PlayOptions

    stop = threading.Event()
    node = FakeNode(on_publish=lambda: len(node.log) >= 50 and stop.set())
    with open_bag(shared_data / "ros2_bags" / "talker_mcap") as bag:
        stats = Player(bag, PlayOptions(rate=1e6, loop=True, topics=("/topic",)), node, stop).run()
    assert stats.messages == 50 and stats.passes == 5
    assert {topic for topic, _ in node.log} == {"/topic"}
