"""Middleware: parameters, config, pub/sub on the embedded backend, ROS 2 wire compatibility, sim time."""

import subprocess
import sys
import textwrap
import threading
from dataclasses import dataclass, field

import numpy as np
import pytest
from pydantic import Field

from ssf_common import messages
from ssf_common.config import Section
from ssf_common.errors import ConfigError, MessageError
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, QOS_SENSOR_DATA, Node
from ssf_common.middleware.params import parse_ros_args
from ssf_common.pointcloud import cloud_to_array, xyz_to_cloud
from support import PointCloud2_, wait_until


class Lidar(Section):
    rows: int = Field(default=64, gt=0)
    range_m: float = 100.0


class SensorConfig(Section):
    lidar: Lidar = Lidar()
    frame_id: str = "lidar"


@dataclass
class Inbox:
    items: list = field(default_factory=list)

    def __call__(self, item) -> None:
        self.items.append(item)


@pytest.fixture
def nodes():
    made: list[Node] = []

    def make(name: str, argv: list[str] | None = None) -> Node:
        node = Node(name, argv=argv)
        made.append(node)
        return node

    yield make
    for node in made:
        node.request_shutdown()
        node.destroy_node()


def test_ros_args_parameters_remaps_and_params_file(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  ros__parameters:\n    rate: 5.0\nmy_node:\n  ros__parameters:\n    lidar:\n      rows: 32\n")
    args = parse_ros_args(
        ["positional", "--ros-args", "-p", "rate:=7", "--params-file", str(params), "-r", "a:=/b", "-r", "__node:=renamed"],
        "my_node",
    )
    assert args.unparsed == ["positional"]
    assert args.node_name == "renamed"
    assert args.remappings == {"a": "/b"}
    assert args.parameters["rate"] == 7  # -p wins over the file
    # the file section 'my_node' no longer matches the renamed node, the wildcard still does
    assert "lidar.rows" not in args.parameters
    assert parse_ros_args(["--ros-args", "--params-file", str(params)], "my_node").parameters["lidar.rows"] == 32


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--ros-args", "-p", "rate"], "NAME:=VALUE"),
        (["--ros-args", "--bogus"], "unknown ROS argument"),
        (["--ros-args", "--params-file", "/nonexistent/params.yaml"], "no such file"),
    ],
)
def test_bad_ros_args_are_one_line_errors(argv, message):
    with pytest.raises(ConfigError, match=message):
        parse_ros_args(argv, "n")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"/**:\n  ros__parameters: {name: caf\xe9}\n", r"not UTF-8 text \(byte 0xe9 at offset 34\)"),
        (b"/**:\n  ros__parameters: &p {a: *p}\n", "recursive alias"),
        (b"/**:\n  ros__parameters: {rate: 1}\n/**:\n  ros__parameters: {rate: 2}\n", "appears twice"),
        (b"/**:\n  ros__parameters: 5\n", "must be a mapping"),
    ],
)
def test_bad_params_files_are_one_line_errors(tmp_path, content, message):
    path = tmp_path / "params.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message) as caught:
        parse_ros_args(["--ros-args", "--params-file", str(path)], "n")
    assert str(path) in str(caught.value)


def test_declare_config_uses_dotted_parameter_names(nodes):
    node = nodes("configured", ["--ros-args", "-p", "lidar.rows:=32", "-p", "lidar.range_m:=120"])
    config = node.declare_config(SensorConfig)
    assert config.lidar.rows == 32 and config.lidar.range_m == 120.0 and config.frame_id == "lidar"
    assert node.get_parameter("lidar.rows").value == 32


def test_declare_config_layers_node_defaults_under_overrides(nodes):
    node = nodes("configured", ["--ros-args", "-p", "lidar.rows:=32"])
    config = node.declare_config(SensorConfig, defaults={"lidar": {"rows": 16, "range_m": 50.0}})
    assert config.lidar.rows == 32 and config.lidar.range_m == 50.0  # the override wins over the node default


def test_declare_config_takes_a_renamed_parameter_under_its_old_name(nodes):
    """-p failsafe.sensor_period:=0.05 still sets what is now failsafe.scan_period; both names at once is an error."""
    from ssf_planner_node.core.config import PlannerConfig

    node = nodes("renamed", ["--ros-args", "-p", "failsafe.sensor_period:=0.05"])
    assert node.declare_config(PlannerConfig).failsafe.scan_period == 0.05
    assert node.get_parameter("failsafe.scan_period").value == 0.05
    both = nodes("both", ["--ros-args", "-p", "failsafe.sensor_period:=0.05", "-p", "failsafe.scan_period:=0.2"])
    with pytest.raises(ConfigError, match="'failsafe.sensor_period' is the old name of 'failsafe.scan_period'"):
        both.declare_config(PlannerConfig)


@pytest.mark.parametrize(
    "override, message",
    [("lidar.rows:=-1", "lidar.rows"), ("lidar.rows:=abc", "lidar.rows"), ("lidar.colour:=1", "unknown parameter")],
)
def test_bad_parameters_name_the_field(nodes, override, message):
    node = nodes("configured", ["--ros-args", "-p", override])
    with pytest.raises(ConfigError, match=message):
        node.declare_config(SensorConfig)


@pytest.mark.parametrize("qos", [QOS_DEFAULT, QOS_SENSOR_DATA, QOS_LATCHED], ids=["default", "sensor", "latched"])
def test_publish_subscribe_round_trip_keeps_every_field(nodes, qos):
    talker, listener = nodes("talker"), nodes("listener")
    inbox = Inbox()
    listener.create_subscription("sensor_msgs/msg/PointCloud2", "/test/points", inbox, qos)
    publisher = talker.create_publisher("sensor_msgs/msg/PointCloud2", "/test/points", qos)
    listener.spin_in_thread()
    assert wait_until(lambda: publisher.get_subscription_count() > 0)
    xyz = np.random.default_rng(1).normal(size=(1000, 3)).astype(np.float32)
    publisher.publish(xyz_to_cloud(xyz, messages.header(123_456_789, "lidar"), intensity=xyz[:, 0].copy()))
    assert wait_until(lambda: len(inbox.items) == 1)
    cloud = inbox.items[0]
    assert messages.stamp_ns(cloud.header.stamp) == 123_456_789 and cloud.header.frame_id == "lidar"
    points = cloud_to_array(cloud)
    np.testing.assert_array_equal(np.stack([points["x"], points["y"], points["z"]], axis=1), xyz)


def test_a_bad_message_is_dropped_and_the_node_keeps_running(nodes):
    talker, listener = nodes("talker"), nodes("listener")
    good = Inbox()

    def callback(msg) -> None:
        if msg.data == "bad":
            raise MessageError("malformed content")
        good(msg.data)

    subscription = listener.create_subscription("std_msgs/msg/String", "/test/chatter", callback)
    publisher = talker.create_publisher("std_msgs/msg/String", "/test/chatter")
    listener.spin_in_thread()
    assert wait_until(lambda: publisher.get_subscription_count() > 0)
    String = messages.msg_type("std_msgs/msg/String")
    for text in ("one", "bad", "two"):
        publisher.publish(String(data=text))
    assert wait_until(lambda: len(good.items) == 2)
    assert good.items == ["one", "two"] and subscription.dropped == 1


def test_a_stopped_node_still_takes_what_it_received(nodes):
    talker, recorder = nodes("talker"), nodes("recorder")
    inbox = Inbox()
    recorder.create_subscription("std_msgs/msg/String", "/test/last_words", inbox, QOS_SENSOR_DATA)
    publisher = talker.create_publisher("std_msgs/msg/String", "/test/last_words", QOS_SENSOR_DATA)
    assert wait_until(lambda: publisher.get_subscription_count() > 0)
    String = messages.msg_type("std_msgs/msg/String")
    recorder.request_shutdown()  # asked to stop before its executor took anything: the samples wait in the reader
    for text in ("one", "two", "three"):
        publisher.publish(String(data=text))
    recorder.spin()  # returns at once: it is stopping
    assert inbox.items == []
    assert wait_until(lambda: (recorder.deliver_received(), [m.data for m in inbox.items])[1] == ["one", "two", "three"])


def test_destroying_a_node_lets_its_running_callback_finish_publishing(nodes):
    """A node destroyed while its spinning thread is inside a slow callback (a fusion step under load) waits for the
    callback, whose publish still goes out, instead of releasing the writer under it."""
    talker, relay, listener = nodes("talker"), nodes("relay"), nodes("listener")
    inside, relayed, errors = threading.Event(), Inbox(), Inbox()
    String = messages.msg_type("std_msgs/msg/String")
    forward = relay.create_publisher("std_msgs/msg/String", "/test/relayed")

    def slow(msg) -> None:
        inside.set()
        threading.Event().wait(0.5)
        try:
            forward.publish(String(data=msg.data + "!"))
        except Exception as err:  # noqa: BLE001 - the failure this test is about
            errors(err)

    relay.create_subscription("std_msgs/msg/String", "/test/slow", slow)
    listener.create_subscription("std_msgs/msg/String", "/test/relayed", lambda msg: relayed(msg.data))
    publisher = talker.create_publisher("std_msgs/msg/String", "/test/slow")
    relay.spin_in_thread()
    listener.spin_in_thread()
    assert wait_until(lambda: publisher.get_subscription_count() > 0 and forward.get_subscription_count() > 0)
    publisher.publish(String(data="late"))
    assert inside.wait(10.0)
    relay.destroy_node()
    assert errors.items == []
    assert wait_until(lambda: relayed.items == ["late!"])


def test_two_processes_publish_and_subscribe(nodes):
    listener = nodes("listener")
    inbox = Inbox()
    listener.create_subscription("std_msgs/msg/String", "/test/from_child", inbox)
    ack = listener.create_publisher("std_msgs/msg/String", "/test/ack")
    listener.spin_in_thread()
    child = textwrap.dedent(
        """
        import sys, time
        from ssf_common import messages
        from ssf_common.middleware import Node, shutdown

        def wait_until(predicate, timeout_s=30.0):
            deadline = time.monotonic() + timeout_s
            while not predicate() and time.monotonic() < deadline:
                time.sleep(0.02)
            return predicate()

        node = Node("child_talker")
        acks = []
        node.create_subscription("std_msgs/msg/String", "/test/ack", acks.append)
        node.spin_in_thread()
        pub = node.create_publisher("std_msgs/msg/String", "/test/from_child")
        assert wait_until(lambda: pub.get_subscription_count() > 0)
        for i in range(5):
            pub.publish(messages.msg_type("std_msgs/msg/String")(data=f"msg {i}"))
        received = wait_until(lambda: bool(acks))  # the parent says it has all five: now we may leave
        node.request_shutdown(); node.destroy_node(); shutdown()
        sys.exit(0 if received else 3)
        """
    )
    process = subprocess.Popen([sys.executable, "-P", "-c", child], stderr=subprocess.PIPE, text=True)
    String = messages.msg_type("std_msgs/msg/String")
    try:
        assert wait_until(lambda: len(inbox.items) == 5, timeout_s=60)
        assert wait_until(lambda: ack.publish(String(data="got them")) or process.poll() is not None, timeout_s=60)
    finally:
        _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert [m.data for m in inbox.items] == [f"msg {i}" for i in range(5)]


def test_topics_are_rmw_cyclonedds_names_with_type_hash_in_user_data(nodes):
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication

    from ssf_common.middleware.embedded import Participant

    talker = nodes("talker")
    talker.create_publisher("nav_msgs/msg/Odometry", "/odom")
    reader = BuiltinDataReader(Participant.get().dp, BuiltinTopicDcpsPublication)
    found = []
    assert wait_until(lambda: bool(found.extend(s for s in reader.read(N=100) if getattr(s, "topic_name", "") == "rt/odom") or found))
    sample = found[0]
    assert sample.type_name == "nav_msgs::msg::dds_::Odometry_"
    texts = [getattr(policy, "data", b"") for policy in sample.qos]
    assert f"typehash={messages.type_hash('nav_msgs/msg/Odometry')};".encode() in texts
    assert ("odom" in dict(talker.get_topic_names_and_types()).get("/odom", [""])[0].lower())


def test_a_subscriber_knowing_only_the_ros2_type_name_receives_our_clouds(nodes):
    """Stands in for `ros2 topic echo`: plain Cyclone, the ROS 2 DDS type name, XCDR1, no project code."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from ssf_common.middleware.embedded import Participant

    talker = nodes("talker")
    foreign = DomainParticipant(Participant.get().domain_id)
    reader = DataReader(
        foreign,
        Topic(foreign, "rt/lidar/points", PointCloud2_),
        Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.DataRepresentation(use_cdrv0_representation=True)),
    )
    publisher = talker.create_publisher("sensor_msgs/msg/PointCloud2", "/lidar/points", QOS_SENSOR_DATA)
    assert wait_until(lambda: publisher.get_subscription_count() > 0)
    xyz = np.arange(30, dtype=np.float32).reshape(10, 3)
    samples: list = []

    def publish_and_take() -> bool:  # best effort: publish again until one cloud has arrived
        publisher.publish(xyz_to_cloud(xyz, messages.header(5_000_000_001, "lidar")))
        samples.extend(s for s in reader.take(N=10) if isinstance(s, PointCloud2_))
        return bool(samples)

    assert wait_until(publish_and_take), "the plain ROS 2 type subscriber got nothing"
    cloud = samples[0]
    assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec, cloud.header.frame_id) == (5, 1, "lidar")
    assert [f.name for f in cloud.fields][:3] == ["x", "y", "z"] and cloud.width == 10
    received = np.frombuffer(bytes(cloud.data), dtype=np.float32).reshape(10, cloud.point_step // 4)[:, :3]
    np.testing.assert_array_equal(received, xyz)


def test_sim_time_follows_clock_and_drives_timers(nodes):
    clock_source = nodes("clock_source")
    node = nodes("timed", ["--ros-args", "-p", "use_sim_time:=true"])
    ticks = Inbox()
    node.create_timer(0.1, lambda: ticks(node.get_clock().now_ns()))
    clock_pub = clock_source.create_publisher("rosgraph_msgs/msg/Clock", "/clock", QOS_DEFAULT)
    node.spin_in_thread()
    assert wait_until(lambda: clock_pub.get_subscription_count() > 0)
    assert node.get_clock().now_ns() == 0
    Clock = messages.msg_type("rosgraph_msgs/msg/Clock")
    for step in range(1, 11):
        stamp = step * 50_000_000  # 0.05 s of sim time per step
        clock_pub.publish(Clock(clock=messages.stamp(stamp)))
        assert wait_until(lambda: node.get_clock().now_ns() == stamp)
        handled = threading.Event()  # after this, the executor has run every timer due at `stamp`
        node.call_soon(handled.set)
        assert handled.wait(10)
    # 0.5 s of sim time at 10 Hz, each tick at the sim time it was due, whatever the wall time was
    assert ticks.items == [100_000_000, 200_000_000, 300_000_000, 400_000_000, 500_000_000]


def test_nodes_are_announced_on_ros_discovery_info_for_ros2_node_list(nodes):
    from cyclonedds._clayer import ddspy_take
    from cyclonedds.core import InstanceState, SampleState, ViewState
    from cyclonedds.sub import DataReader

    from ssf_common.middleware.embedded import QOS_DISCOVERY, Participant, dds_qos

    node = nodes("announced_node")
    publisher = node.create_publisher("std_msgs/msg/String", "/announced")
    type_name = "rmw_dds_common/msg/ParticipantEntitiesInfo"
    participant = Participant.get()
    reader = DataReader(  # a late joiner: transient-local durability still hands it the last announcement
        participant.dp,
        participant.topic("", type_name, dds_name="ros_discovery_info"),
        dds_qos(QOS_DISCOVERY, type_name),
    )
    mask = SampleState.Any | ViewState.Any | InstanceState.Any
    infos = []
    assert wait_until(lambda: bool(infos.extend(ddspy_take(reader._ref, mask, 10)) or infos))
    info = messages.deserialize(infos[-1][0], type_name)
    entries = {entry.node_name: entry for entry in info.node_entities_info_seq}
    assert "announced_node" in entries
    writer_gids = [bytes(gid.data) for gid in entries["announced_node"].writer_gid_seq]
    assert publisher._transport.guid in writer_gids
    assert bytes(info.gid.data) == participant.dp.guid.bytes


def test_a_node_that_publishes_and_leaves_at_once_still_delivers_its_last_message(nodes):
    """destroy_node waits (bounded) for matched readers to acknowledge: a big last scan is not lost with its writer."""
    listener = nodes("listener")
    inbox = Inbox()
    listener.create_subscription("sensor_msgs/msg/PointCloud2", "/test/last_scans", inbox)
    listener.spin_in_thread()
    child = textwrap.dedent(
        """
        import sys, time
        import numpy as np
        from ssf_common import messages
        from ssf_common.middleware import Node, shutdown
        from ssf_common.pointcloud import xyz_to_cloud

        node = Node("leaving_talker")
        pub = node.create_publisher("sensor_msgs/msg/PointCloud2", "/test/last_scans")
        deadline = time.monotonic() + 30
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        points = np.random.default_rng(0).normal(size=(120_000, 3)).astype(np.float32)  # ~1.4 MB, many fragments
        for i in range(5):
            pub.publish(xyz_to_cloud(points, messages.header(i + 1, "lidar")))
        node.request_shutdown(); node.destroy_node(); shutdown()
        """
    )
    process = subprocess.run([sys.executable, "-P", "-c", child], stderr=subprocess.PIPE, text=True, timeout=120)
    assert process.returncode == 0, process.stderr
    assert wait_until(lambda: len(inbox.items) == 5, timeout_s=10)
    assert [messages.stamp_ns(m.header.stamp) for m in inbox.items] == [1, 2, 3, 4, 5]


class ManualClock:
    """A steady clock moved by hand (the executor reads only now_s and these flags)."""

    steady, use_sim_time = True, False

    def __init__(self) -> None:
        self.seconds = 1000.0

    def now_s(self) -> float:
        return self.seconds

    def now_ns(self) -> int:
        return int(self.seconds * 1e9)


def test_a_timer_on_simulated_time_starts_a_new_sequence_when_the_clock_jumps_back():
    """A second episode, a restarted simulator or a looping bag sends /clock back to zero: a watchdog must keep its
    period on the new time line instead of staying silent until the clock passes its old due time."""
    node = Node("jumping", argv=["--ros-args", "-p", "use_sim_time:=true"])
    try:
        calls: list[int] = []
        node.get_clock().set_sim_time(50_000_000_000)
        node.create_timer(0.1, lambda: calls.append(node.get_clock().now_ns()))
        for stamp in ( 50_100_000_000, 50_200_000_000, 200_000_000, 300_000_000, 400_000_000):
            node.get_clock().set_sim_time(stamp)
            node._run_due_timers()
        assert calls == [50_100_000_000, 50_200_000_000, 300_000_000, 400_000_000]
    finally:
        node.destroy_node()


def test_a_steady_timer_runs_while_simulated_time_stands_still():
    node = Node("steady", argv=["--ros-args", "-p", "use_sim_time:=true"])
    try:
        steady = ManualClock()
        on_sim, on_steady = [], []
        node.get_clock().set_sim_time(5_000_000_000)  # lockstep: the clock stands at 5 s while the graph thinks
        node.create_timer(0.1, lambda: on_sim.append(1))
        node.create_timer(0.1, lambda: on_steady.append(steady.seconds), clock=steady)
        for _ in range(5):
            steady.seconds += 0.1
            node._run_due_timers()
        assert on_sim == [] and on_steady == pytest.approx([1000.1, 1000.2, 1000.3, 1000.4, 1000.5])
        assert node.get_steady_clock().steady and not node.get_clock().steady
    finally:
        node.destroy_node()


def test_a_subscription_remembers_when_it_last_heard_a_good_message(nodes):
    node = nodes("hearing", ["--ros-args", "-p", "use_sim_time:=true"])
    taken = Inbox()

    def take(msg) -> None:
        if msg.data == "bad":
            raise MessageError("bad data")
        taken(msg)

    subscription = node.create_subscription("std_msgs/msg/String", "/heard", take)
    String = messages.msg_type("std_msgs/msg/String")
    node.get_clock().set_sim_time(7_000_000_000)
    subscription.deliver(messages.serialize(String(data="good"), "std_msgs/msg/String"))
    heard = subscription.heard
    assert heard is not None and heard.clock_ns == 7_000_000_000 and subscription.received == 1
    node.get_clock().set_sim_time(8_000_000_000)
    subscription.deliver(messages.serialize(String(data="bad"), "std_msgs/msg/String"))
    assert subscription.heard == heard and subscription.dropped == 1  # a dropped message is not heard
    assert subscription in node.subscriptions


def test_simulated_time_runs_with_the_steady_clock_in_real_time_not_in_lockstep(monkeypatch):
    """A planner judges input age by the steady clock too only while the simulator runs in real time: in lockstep
    simulated time crawls while the graph thinks (a step per half second), and it stands still when the simulator died."""
    from ssf_common.middleware.node import Clock

    steady = [0]
    monkeypatch.setattr("ssf_common.middleware.node.time.monotonic_ns", lambda: steady[0])
    realtime, lockstep = Clock(), Clock()
    realtime.use_sim_time = lockstep.use_sim_time = True
    for tick in range(12):
        steady[0] = tick * 100_000_000
        realtime.set_sim_time(tick * 100_000_000)  # 0.1 s of simulated time per 0.1 s
        if tick % 5 == 0:
            lockstep.set_sim_time(tick // 5 * 100_000_000)  # 0.1 s per 0.5 s
    assert realtime.running(steady[0] + 50_000_000, 150_000_000)
    assert not lockstep.running(steady[0] + 50_000_000, 150_000_000)
    assert not realtime.running(steady[0] + 300_000_000, 150_000_000)  # no /clock for 0.3 s: stopped
    assert Clock().running(0, 0)  # wall time always runs
