"""ssf_odom_node in a running graph: replayed semantic flow in; /odom, /tf, /ssf/path and /ssf/map out; malformed
clouds and gaps skipped on the constant-velocity prediction."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from ssf_common import messages
from ssf_common.conversions import odometry_from_msg, semantic_flow_to_cloud
from ssf_common.geometry.se3 import invert, make_pose, transform_points
from ssf_common.middleware import Node
from ssf_common.pointcloud import cloud_to_array, xyz_to_cloud
from ssf_common.records import Segmentation, SemanticFlow
from ssf_odom_node.core.odometry import OdomInput
from ssf_odom_node.node import OdomNode
from support import wait_until

STEP = 0.5  # m of ego motion per scan, along x
PERIOD_NS = 100_000_000


def world(seed: int, convoy_shift: float) -> tuple[np.ndarray, np.ndarray]:
    """A street (ground, walls, poles) and four trucks shifted along x; moving flags."""
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-40, 40, (3000, 2)), rng.normal(-1.8, 0.01, 3000)]
    walls = np.r_[np.c_[rng.uniform(-40, 40, 1500), np.full(1500, 12.0), rng.uniform(-1.8, 3, 1500)],
                  np.c_[np.full(600, 35.0), rng.uniform(-10, 10, 600), rng.uniform(-1.8, 3, 600)],
                  np.c_[rng.choice([-20.0, -5.0, 10.0], 600) + rng.normal(0, 0.1, 600), rng.normal(-9, 0.1, 600),
                        rng.uniform(-1.8, 2, 600)]]
    trucks = np.c_[rng.uniform(-4, 4, 2000) + rng.choice([-15.0, 0.0, 15.0], 2000) + convoy_shift,
                   rng.choice([-5.0, -3.0], 2000) + rng.uniform(-0.3, 0.3, 2000), rng.uniform(-1.8, 1.7, 2000)]
    static = np.vstack([ground, walls])
    return np.vstack([static, trucks]), np.r_[np.zeros(len(static), bool), np.ones(len(trucks), bool)]


def semantic_flow(index: int) -> SemanticFlow:
    """Scan `index` (sensor frame, the ego at x = STEP * index) with its exact flow and segmentation."""
    points_world, moving = world(index, 1.0 * index)
    pose, next_pose = make_pose(STEP * index), make_pose(STEP * (index + 1))
    points = transform_points(invert(pose), points_world)
    target = points_world + np.where(moving[:, None], [1.0, 0.0, 0.0], 0.0)
    flow = transform_points(invert(next_pose), target) - points
    segmentation = Segmentation.from_probability(moving.astype(np.float32), moving.astype(np.int32))
    return SemanticFlow(index * PERIOD_NS, "lidar", points, flow, segmentation)


def tf_stamp(msg) -> int:
    """The stamp of a /tf message's first transform."""
    return messages.stamp_ns(msg.transforms[0].header.stamp)


@pytest.fixture
def graph():
    node = OdomNode(argv=["--ros-args", "-p", "map_period_s:=0.2", "-p", "report_period_s:=60.0", "-p", "map.confirm:=2",
                          "-p", "mount:=[0.0, 0.0, 1.8, 0.0, 0.0, 0.0]"])
    node.spin_in_thread()
    probe = Node("probe")
    received: dict[str, list] = {"odom": [], "tf": [], "path": [], "map": []}
    ours = lambda stamp: stamp % PERIOD_NS == 0 and stamp <= 30 * PERIOD_NS  # not another test's leftovers

    def on_odom(msg) -> None:
        if msg.child_frame_id == "base_link" and ours(messages.stamp_ns(msg.header.stamp)):
            received["odom"].append(msg)

    def on_tf(msg) -> None:
        if msg.transforms and msg.transforms[0].header.frame_id == "odom":
            received["tf"].append(msg)

    probe.create_subscription("nav_msgs/msg/Odometry", "/odom", on_odom)
    probe.create_subscription("tf2_msgs/msg/TFMessage", "/tf", on_tf)
    probe.create_subscription("nav_msgs/msg/Path", "/ssf/path", received["path"].append)
    probe.create_subscription("sensor_msgs/msg/PointCloud2", "/ssf/map", received["map"].append)
    probe.spin_in_thread()
    publisher = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/ssf/semantic_flow")
    assert wait_until(lambda: publisher.get_subscription_count() > 0)
    yield node, publisher, received
    node.request_shutdown()
    node.on_shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_node_publishes_odometry_tf_path_and_map_from_replayed_scans(graph, capfd):
    node, publisher, received = graph
    for index in range(4):
        publisher.publish(semantic_flow_to_cloud(semantic_flow(index)))
        assert wait_until(lambda: len(received["odom"]) == index + 1)
    odometry = odometry_from_msg(received["odom"][-1])
    assert (odometry.frame_id, odometry.child_frame_id) == ("odom", "base_link")
    # /odom is the newest scan's pose: scan 3's flow reaches scan 4, which its static flow's motion places
    assert odometry.stamp_ns == 4 * PERIOD_NS
    np.testing.assert_allclose(odometry.position, [4 * STEP, 0.0, 0.0], atol=0.03)  # the convoy does not pull it
    assert odometry.twist[0] == pytest.approx(STEP / 0.1, abs=0.3)
    assert np.linalg.eigvalsh(odometry.pose_covariance).min() > 0
    # /tf and /ssf/path are other topics: each arrives in its own time after /odom
    assert wait_until(lambda: received["tf"] and tf_stamp(received["tf"][-1]) == 4 * PERIOD_NS)
    assert wait_until(lambda: received["path"] and len(received["path"][-1].poses) == 4)
    transform = received["tf"][-1].transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_link")
    assert transform.transform.translation.x == pytest.approx(4 * STEP, abs=0.03)
    path = received["path"][-1]  # the refined poses, each at its own scan
    assert len(path.poses) == 4 and messages.stamp_ns(path.poses[-1].header.stamp) == 3 * PERIOD_NS
    assert path.poses[-1].pose.position.x == pytest.approx(3 * STEP, abs=0.03)
    assert wait_until(lambda: len(received["map"]) > 0)
    map_points = cloud_to_array(received["map"][-1])
    assert 0 < len(map_points) <= node.config.map.max_voxels
    lanes = (map_points["y"] < -2.5) & (map_points["y"] > -5.5) & (map_points["z"] > 0.3) & (map_points["x"] < 30)
    assert not lanes.any()  # no trucks in the static map (base_link frame: ground at z = 0)

    # a malformed message is logged and skipped; a missing scan is bridged by the prediction
    bad = xyz_to_cloud(np.zeros((5, 3), np.float32), messages.header(4 * PERIOD_NS, "lidar"))  # no flow/label fields
    publisher.publish(bad)
    time.sleep(0.3)
    assert len(received["odom"]) == 4
    publisher.publish(semantic_flow_to_cloud(semantic_flow(5)))  # scan 4 never arrives
    assert wait_until(lambda: len(received["odom"]) == 5)
    after_gap = odometry_from_msg(received["odom"][-1])
    assert after_gap.stamp_ns == 6 * PERIOD_NS
    np.testing.assert_allclose(after_gap.position, [6 * STEP, 0.0, 0.0], atol=0.05)
    assert "dropped a message on /ssf/semantic_flow" in capfd.readouterr().err


def test_a_restarted_stream_starts_the_odometry_again(graph):
    """Stamps jumping back (a simulator reset, a looping bag) start a new sequence: pose, path and map from zero."""
    node, publisher, received = graph
    for index in range(3):  # a first drive, stamped 2.0 s onwards
        publisher.publish(semantic_flow_to_cloud(replace(semantic_flow(index), stamp_ns=(20 + index) * PERIOD_NS)))
        assert wait_until(lambda: len(received["odom"]) == index + 1)
    assert odometry_from_msg(received["odom"][-1]).position[0] == pytest.approx(2 * STEP, abs=0.03)  # period unsure
    for index in range(2):  # the drive starts again at stamp zero
        publisher.publish(semantic_flow_to_cloud(semantic_flow(index)))
        assert wait_until(lambda: len(received["odom"]) == 4 + index)
    restarted = odometry_from_msg(received["odom"][-1])
    assert restarted.stamp_ns == 2 * PERIOD_NS
    np.testing.assert_allclose(restarted.position, [2 * STEP, 0.0, 0.0], atol=0.03)
    assert wait_until(lambda: len(received["path"][-1].poses) == 2)  # the path follows /odom on its own topic
    assert node.sequence.restarts == 1


@pytest.mark.parametrize("pose_at", ["next_scan", "scan"])
def test_odom_is_the_newest_scans_pose_once_the_period_is_learnt(pose_at):
    """next_scan: once the shortest gap between scans came three times (the first scans answered were two periods
    apart), each /odom is the pose of the scan the flow reaches, one period after the flow's scan; before that, and
    with pose_at scan, the refined pose of the flow's own scan. Stamps never repeat."""
    node = OdomNode(argv=["--ros-args", "-p", "report_period_s:=60.0", "-p", "map.confirm:=2", "-p", f"pose_at:={pose_at}",
                          "-p", "mount:=[0.0, 0.0, 1.8, 0.0, 0.0, 0.0]"])
    sent = []
    node.odom_pub.publish = sent.append
    try:
        for index in (0, 2, 3, 4, 5, 6):
            flow = semantic_flow(index)
            node._step("scan", OdomInput(flow.stamp_ns, flow.points, flow.flow, flow.segmentation.dynamic_prob))
        stamps = [odometry_from_msg(msg).stamp_ns // PERIOD_NS for msg in sent]
        assert stamps == ([0, 2, 3, 4, 6, 7] if pose_at == "next_scan" else [0, 2, 3, 4, 5, 6])
        assert odometry_from_msg(sent[-1]).position[0] == pytest.approx(stamps[-1] * STEP, abs=0.05)
        assert node.period.period_ns == PERIOD_NS
        node.period.learn(PERIOD_NS + 2_000_000)  # a driver's jitter does not unlearn it
        assert node.period.period_ns == PERIOD_NS
    finally:
        node.destroy_node()


def test_commands_sent_between_scans_are_the_motion_prior():
    """The node remembers /cmd_vel with its arrival time and drives them from the last scan to the next: the LiDAR's
    motion (mounted 1.2 m ahead of base_link) over a second at 5 m/s turning 0.2 rad/s; bad commands are dropped."""
    twist = messages.msg_type("geometry_msgs/msg/Twist")
    vector = messages.msg_type("geometry_msgs/msg/Vector3")
    node = OdomNode(argv=["--ros-args", "-p", "mount:=[1.2, 0.0, 1.8, 0.0, 0.0, 0.0]", "-p", "mount_from_tf:=false"])
    try:
        assert node.motion_prior(0) is None  # no scan yet
        node.on_command(twist(linear=vector(x=float("nan"), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)))
        node.on_command(twist(linear=vector(x=5.0, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.2)))
        assert len(node.vehicle.commands) == 1
        start = node.vehicle.commands[0][0]
        node._last_stamp, node.speed = start - 1, 5.0
        assert node.motion_prior(start + 10**9) is None  # no command was in force at the last scan
        node._last_stamp = start
        prior = node.motion_prior(start + 10**9)
        base = node.mount @ prior @ invert(node.mount)  # back to base_link's motion
        assert np.arctan2(base[1, 0], base[0, 0]) == pytest.approx(0.2, abs=1e-6)
        assert np.hypot(*base[:2, 3]) == pytest.approx(2 * 5.0 / 0.2 * np.sin(0.1), abs=0.01)  # the arc's chord
        assert prior[1, 3] != pytest.approx(base[1, 3], abs=0.05)  # the mount's lever arm moves the LiDAR sideways
        node.get_clock().use_sim_time = True  # a restarted simulator: its clock starts again from zero
        node.on_command(twist(linear=vector(x=1.0, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)))
        assert [command[1] for command in node.vehicle.commands] == [1.0]  # the old stream's commands are forgotten
    finally:
        node.destroy_node()


def test_measured_twists_between_scans_are_the_measured_motion():
    """With twist_topic set, the node integrates the vehicle's stamped speed and yaw rate from the last scan to the
    next (the LiDAR mounted 1.2 m ahead of base_link); bad, repeated and restarted measurements are handled."""
    stamped = messages.msg_type("geometry_msgs/msg/TwistStamped")
    twist = messages.msg_type("geometry_msgs/msg/Twist")
    vector = messages.msg_type("geometry_msgs/msg/Vector3")

    def measurement(stamp_ns: int, speed: float, yaw_rate: float):
        return stamped(header=messages.header(stamp_ns, "base_link"),
                       twist=twist(linear=vector(x=speed, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=yaw_rate)))

    node = OdomNode(argv=["--ros-args", "-p", "mount:=[1.2, 0.0, 1.8, 0.0, 0.0, 0.0]", "-p", "mount_from_tf:=false",
                          "-p", "twist_topic:=/vehicle/twist"])
    try:
        for k in range(1, 11):
            node.on_twist(measurement(k * PERIOD_NS, 5.0, 0.2))
        node.on_twist(measurement(10 * PERIOD_NS, 5.0, 0.2))  # the same sample again
        node.on_twist(measurement(11 * PERIOD_NS, float("inf"), 0.0))
        assert len(node.vehicle.twists.samples) == 10
        assert node.measured_prior(10 * PERIOD_NS) is None  # no scan yet
        node._last_stamp = 0
        base = node.mount @ node.measured_prior(10 * PERIOD_NS) @ invert(node.mount)
        assert np.arctan2(base[1, 0], base[0, 0]) == pytest.approx(0.2, abs=1e-9)
        assert np.hypot(*base[:2, 3]) == pytest.approx(2 * 5.0 / 0.2 * np.sin(0.1), abs=0.01)  # the arc's chord
        node.on_twist(measurement(PERIOD_NS, 1.0, 0.0))  # a restarted stream
        assert list(node.vehicle.twists.samples) == [(PERIOD_NS, 1.0, 0.0)]
        node._last_stamp = 100 * PERIOD_NS  # measurements ten seconds before the scans: stopped, or another clock
        assert node.measured_prior(101 * PERIOD_NS) is None and node.said_no_twist
    finally:
        node.destroy_node()
