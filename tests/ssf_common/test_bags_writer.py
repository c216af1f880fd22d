"""Bags we write read back identically with our reader, with rosbags, and with the mcap reader + ROS 2 decoder."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader as RosbagsReader

from ssf_common import messages
from ssf_common.bags.qos import QosDurability, QosReliability, default_profile
from ssf_common.bags.reader import open_bag
from ssf_common.bags.writer import BagWriter, BagWriterConfig, ChunkCompression
from ssf_common.errors import BagError

T0 = 1_700_000_000_000_000_000


def make_obstacles(i: int):
    """An ssf_interfaces/ObstacleArray with two obstacles whose values depend on i."""
    obstacle_type = messages.msg_type("ssf_interfaces/msg/Obstacle")
    pose_type = messages.msg_type("geometry_msgs/msg/Pose")
    point_type = messages.msg_type("geometry_msgs/msg/Point")
    quat_type = messages.msg_type("geometry_msgs/msg/Quaternion")
    vec_type = messages.msg_type("geometry_msgs/msg/Vector3")
    obstacles = [
        obstacle_type(
            id=i * 10 + k,
            kind=1 + k,
            pose=pose_type(position=point_type(x=1.5 * i, y=-2.0 * k, z=0.25), orientation=quat_type(x=0, y=0, z=0, w=1)),
            size=vec_type(x=4.5, y=1.8, z=1.5),
            velocity=vec_type(x=3.0 + i, y=0.5 * k, z=0.0),
            velocity_covariance=np.diag([0.1, 0.2, 0.3]).reshape(9) * (1 + k),
            yaw_rate=0.125 * k,
            num_points=100 + i,
            confidence=0.5,
        )
        for k in range(2)
    ]
    return messages.msg_type("ssf_interfaces/msg/ObstacleArray")(
        header=messages.header(T0 + i, "map"), obstacles=obstacles
    )


def make_cloud(i: int):
    """A small PointCloud2 (x, y, z float32)."""
    field = messages.msg_type("sensor_msgs/msg/PointField")
    points = np.arange(30, dtype=np.float32).reshape(10, 3) + i
    return messages.msg_type("sensor_msgs/msg/PointCloud2")(
        header=messages.header(T0 + i, "lidar"),
        height=1,
        width=10,
        fields=[field(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate("xyz")],
        is_bigendian=False,
        point_step=12,
        row_step=120,
        data=points.view(np.uint8).reshape(-1).copy(),
        is_dense=True,
    )


def make_twist(i: int):
    """A geometry_msgs/Twist."""
    vec = messages.msg_type("geometry_msgs/msg/Vector3")
    return messages.msg_type("geometry_msgs/msg/Twist")(linear=vec(x=0.5 * i, y=0.0, z=0.0), angular=vec(x=0, y=0, z=-0.1 * i))


TOPICS = {
    "/ssf/obstacles": ("ssf_interfaces/msg/ObstacleArray", make_obstacles),
    "/lidar/points": ("sensor_msgs/msg/PointCloud2", make_cloud),
    "/cmd_vel": ("geometry_msgs/msg/Twist", make_twist),
}
COUNT = 40


@pytest.fixture(params=list(ChunkCompression))
def written(request, tmp_path):
    """A bag of three topics (custom type included) written with each chunk compression."""
    directory = tmp_path / "bag"
    config = BagWriterConfig(chunk_bytes=2048, compression=request.param)
    sent = []
    with BagWriter(directory, config, custom_data={"purpose": "test"}) as writer:
        writer.add_topic("/lidar/points", "sensor_msgs/msg/PointCloud2", [default_profile(reliable=False, depth=5)])
        writer.add_topic("/ssf/obstacles", "ssf_interfaces/msg/ObstacleArray", [default_profile()])
        writer.add_topic("/cmd_vel", "geometry_msgs/Twist")
        for i in range(COUNT):
            for k, (topic, (_, make)) in enumerate(TOPICS.items()):
                data = messages.serialize(make(i))
                stamp = T0 + i * 100_000_000 + k * 1000
                writer.write(topic, data, stamp)
                sent.append((topic, stamp, data))
    return directory, sent


def test_our_reader_returns_the_exact_bytes_in_order(written):
    directory, sent = written
    with open_bag(directory) as bag:
        got = [(m.topic, m.timestamp_ns, m.data) for m in bag.messages()]
        assert got == sent
        assert bag.info.metadata_version == 9
        assert dict(bag.info.custom_data) == {"purpose": "test"}
        (lidar_qos,) = bag.topics["/lidar/points"].offered_qos
        assert lidar_qos.reliability is QosReliability.BEST_EFFORT and lidar_qos.depth == 5
        assert bag.topics["/cmd_vel"].offered_qos == ()
        assert bag.topics["/ssf/obstacles"].type_hash == messages.type_hash("ssf_interfaces/msg/ObstacleArray")


def test_rosbags_reads_it_and_decodes_equal_values(written):
    directory, sent = written
    store = messages.typestore()
    with RosbagsReader(directory) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {t: v[0] for t, v in TOPICS.items()}
        assert reader.message_count == len(sent)
        got = [(c.topic, stamp, bytes(raw)) for c, stamp, raw in reader.messages()]
        obstacles = [store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/ssf/obstacles"]
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert sorted(got) == sorted(sent)
    assert [o.obstacles[1].velocity.y for o in obstacles] == [0.5] * COUNT
    assert [o.obstacles[0].num_points for o in obstacles] == [100 + i for i in range(COUNT)]
    assert qos["/ssf/obstacles"][0].durability is QosDurability.VOLATILE


def test_mcap_ros2_decoder_reads_it_with_equal_field_values(written):
    directory, _ = written
    (mcap_path,) = directory.glob("*.mcap")
    with mcap_path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
        assert summary.statistics.chunk_count > 1
        assert [m.name for m in reader.iter_metadata()] == ["rosbag2"]
        decoded = {topic: [] for topic in TOPICS}
        for _, channel, _, message in reader.iter_decoded_messages():
            decoded[channel.topic].append(message)
    for i, msg in enumerate(decoded["/ssf/obstacles"]):
        expected = make_obstacles(i)
        assert msg.header.stamp.nanosec == expected.header.stamp.nanosec
        for mine, theirs in zip(expected.obstacles, msg.obstacles):
            assert (theirs.id, theirs.kind, theirs.num_points) == (mine.id, mine.kind, mine.num_points)
            assert theirs.pose.position.x == pytest.approx(mine.pose.position.x)
            assert theirs.velocity.x == pytest.approx(mine.velocity.x)
            assert theirs.yaw_rate == pytest.approx(mine.yaw_rate)
    for i, msg in enumerate(decoded["/lidar/points"]):
        points = np.frombuffer(bytes(msg.data), dtype=np.float32).reshape(10, 3)
        assert np.array_equal(points, np.arange(30, dtype=np.float32).reshape(10, 3) + i)
    assert [m.angular.z for m in decoded["/cmd_vel"]] == pytest.approx([-0.1 * i for i in range(COUNT)])


def test_metadata_yaml_is_version_9_with_every_field(written):
    directory, sent = written
    info = yaml.safe_load((directory / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["ros_distro"] == "jazzy"
    assert info["message_count"] == len(sent)
    assert info["relative_file_paths"] == ["bag_0.mcap"]
    assert info["files"][0]["message_count"] == len(sent)
    assert info["starting_time"]["nanoseconds_since_epoch"] == sent[0][1]
    assert info["duration"]["nanoseconds"] == sent[-1][1] - sent[0][1]
    assert (info["compression_format"], info["compression_mode"]) == ("", "")
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert {name: t["message_count"] for name, t in topics.items()} == {name: COUNT for name in TOPICS}
    lidar = topics["/lidar/points"]["topic_metadata"]
    assert lidar["offered_qos_profiles"][0]["reliability"] == "best_effort"
    assert lidar["type_description_hash"].startswith("RIHS01_")


def test_writer_refuses_an_existing_bag_and_unknown_types(tmp_path):
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "x").write_text("")
    with pytest.raises(BagError, match="already exists"):
        BagWriter(tmp_path / "used")
    with BagWriter(tmp_path / "fresh") as writer:
        with pytest.raises(BagError, match="no_such_pkg/msg/Thing"):
            writer.add_topic("/x", "no_such_pkg/msg/Thing")
        with pytest.raises(BagError, match="not added"):
            writer.write("/never_added", b"\0\1\0\0", 1)
    with open_bag(tmp_path / "fresh") as bag:
        assert bag.info.message_count == 0


def test_idle_chunks_are_finished_by_time(tmp_path):
    now = [0.0]
    writer = BagWriter(tmp_path / "bag", BagWriterConfig(chunk_seconds=0.5), clock=lambda: now[0])
    writer.add_topic("/cmd_vel", "geometry_msgs/msg/Twist")
    writer.write("/cmd_vel", messages.serialize(make_twist(1)), T0)
    (mcap_path,) = (tmp_path / "bag").glob("*.mcap")
    with open_bag(mcap_path) as bag:
        assert bag.info.message_count == 0  # still in the open chunk
    now[0] = 0.6
    writer.flush_if_due()
    with open_bag(mcap_path) as bag:
        assert bag.info.message_count == 1
        assert bag.info.damage  # no summary yet: read by scanning
    writer.close()


def test_out_of_order_stamps_come_back_sorted_from_overlapping_chunks(tmp_path):
    rng = np.random.default_rng(3)
    stamps = [int(T0 + i * 1_000_000 + rng.integers(-40, 40) * 1_000_000) for i in range(300)]
    string = messages.msg_type("std_msgs/msg/String")
    with BagWriter(tmp_path / "bag", BagWriterConfig(chunk_bytes=1024)) as writer:
        writer.add_topic("/jitter", "std_msgs/msg/String")
        for i, stamp in enumerate(stamps):
            writer.write("/jitter", messages.serialize(string(data=str(i))), stamp)
    (path,) = (tmp_path / "bag").glob("*.mcap")
    scanned = tmp_path / "no_summary.mcap"
    scanned.write_bytes(path.read_bytes()[:-200])  # cut into the summary: read by scanning
    for source in (tmp_path / "bag", scanned):
        with open_bag(source) as bag:
            got = [(m.timestamp_ns, int(bag.decode(m).data)) for m in bag.messages()]
        assert [t for t, _ in got] == sorted(stamps)
        assert sorted(got) == sorted((s, i) for i, s in enumerate(stamps))
