"""ssf_flow_node in a running graph: flow for replayed scans, mask hints answered, malformed clouds dropped."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest

from ssf_common import messages
from support import wait_until
from ssf_common.middleware import QOS_SENSOR_DATA, Node
from ssf_common.pointcloud import cloud_to_array, xyz_to_cloud
from ssf_flow_node.node import FlowNode

SHIFT = np.array([0.6, -0.2, 0.0], dtype=np.float32)


def scene(seed: int = 0) -> np.ndarray:
    """A static scene: ground, two walls and scattered poles, ~6000 points."""
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.7, 0.02, 3000)]
    wall_a = np.c_[rng.uniform(-30, 30, 1200), np.full(1200, 8.0), rng.uniform(-1.7, 3, 1200)]
    wall_b = np.c_[np.full(1200, 25.0), rng.uniform(-8, 8, 1200), rng.uniform(-1.7, 3, 1200)]
    poles = np.c_[rng.choice([-12.0, -4.0, 5.0, 14.0], 600) + rng.normal(0, 0.1, 600), rng.normal(-5, 0.1, 600), rng.uniform(-1.7, 2, 600)]
    return np.vstack([ground, wall_a, wall_b, poles]).astype(np.float32)


def malformed_clouds() -> dict[str, object]:
    """One cloud per kind of malformation a subscriber must survive."""
    good = xyz_to_cloud(scene()[:100], messages.header(1, "lidar"))
    PointCloud2 = messages.msg_type("sensor_msgs/msg/PointCloud2")
    PointField = messages.msg_type("sensor_msgs/msg/PointField")

    def variant(**changes):
        fields = dict(
            header=messages.header(1, "lidar"), height=good.height, width=good.width, fields=good.fields,
            is_bigendian=False, point_step=good.point_step, row_step=good.row_step, data=good.data, is_dense=True,
        )
        fields.update(changes)
        return PointCloud2(**fields)

    nan = np.full((50, 3), np.nan, dtype=np.float32)
    return {
        "short data": variant(data=good.data[:-5]),
        "unknown datatype": variant(fields=[PointField(name=n, offset=4 * i, datatype=42, count=1) for i, n in enumerate("xyz")]),
        "no xyz": variant(fields=[PointField(name="intensity", offset=0, datatype=7, count=1)]),
        "all NaN": xyz_to_cloud(nan, messages.header(1, "lidar")),
        "empty": variant(width=0, row_step=0, data=np.zeros(0, np.uint8)),
    }


@contextlib.contextmanager
def flow_graph(*parameters: str):
    """A flow node (with `parameters`, NAME:=VALUE) and a probe that publishes scans and mask hints and keeps the flow."""
    flow_node = FlowNode(argv=["--ros-args", "-p", "report_period_s:=60.0",
                               *(item for parameter in parameters for item in ("-p", parameter))])
    flow_node.spin_in_thread()
    probe = Node("probe")
    received: list = []
    probe.create_subscription("sensor_msgs/msg/PointCloud2", "/ssf/flow", received.append)
    probe.spin_in_thread()
    scans = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/lidar/points", QOS_SENSOR_DATA)
    hints = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/ssf/mask_hint")
    try:
        assert wait_until(lambda: scans.get_subscription_count() > 0 and hints.get_subscription_count() > 0)
        yield flow_node, probe, scans, hints, received
    finally:
        flow_node.request_shutdown()
        flow_node.on_shutdown()
        flow_node.destroy_node()
        probe.destroy_node()


@pytest.fixture
def graph():
    with flow_graph() as (flow_node, _probe, scans, hints, received):
        yield flow_node, scans, hints, received


def test_flow_for_replayed_scans_and_malformed_clouds_dropped(graph, capfd):
    flow_node, scans, _hints, received = graph
    assert flow_node.config.preprocess.remove_ground and flow_node.config.preprocess.range_balance  # whole scans, any range
    for cloud in malformed_clouds().values():
        scans.publish(cloud)
        time.sleep(0.05)
    points = scene()
    scans.publish(xyz_to_cloud(points, messages.header(1_000_000_000, "lidar")))
    time.sleep(0.1)
    scans.publish(xyz_to_cloud(points - SHIFT, messages.header(1_100_000_000, "lidar")))
    assert wait_until(lambda: len(received) == 1)
    flow = cloud_to_array(received[0])
    assert messages.stamp_ns(received[0].header.stamp) == 1_000_000_000
    assert len(flow) == len(points) and int(flow["iteration"][0]) == 0
    estimate = np.stack([flow["flow_x"], flow["flow_y"], flow["flow_z"]], axis=1)
    assert np.median(np.linalg.norm(estimate + SHIFT, axis=1)) < 0.05  # the scene moved by -SHIFT
    log = capfd.readouterr().err
    for problem in ("data", "datatype", "x/y/z", "NaN", "empty"):
        assert problem in log, f"no log line about '{problem}'"
    assert log.count("dropped a message on /lidar/points") == 5


def test_mask_hint_is_answered_with_its_iteration(graph):
    _flow_node, scans, hints, received = graph
    points = scene(1)
    scans.publish(xyz_to_cloud(points, messages.header(2_000_000_000, "lidar")))
    time.sleep(0.1)
    scans.publish(xyz_to_cloud(points - SHIFT, messages.header(2_100_000_000, "lidar")))
    assert wait_until(lambda: len(received) == 1)
    hint = xyz_to_cloud(
        points, messages.header(2_000_000_000, "lidar"),
        mask=np.zeros(len(points), np.float32), iteration=np.full(len(points), 3, np.uint32),
    )
    hints.publish(hint)
    assert wait_until(lambda: len(received) == 2)
    answer = cloud_to_array(received[1])
    assert messages.stamp_ns(received[1].header.stamp) == 2_000_000_000
    assert int(answer["iteration"][0]) == 3
    bad_hint = xyz_to_cloud(points[:10], messages.header(2_000_000_000, "lidar"), mask=np.zeros(10, np.float32), iteration=np.zeros(10, np.uint32))
    hints.publish(bad_hint)  # wrong point count: dropped with one line, nothing published
    time.sleep(0.5)
    assert len(received) == 2


def test_no_flow_across_a_lost_scan(graph):
    flow_node, scans, _hints, received = graph
    points = scene()
    for index in (10, 11, 13, 14):  # scan 12 was lost on the way
        scans.publish(xyz_to_cloud(points - index * SHIFT, messages.header(index * 100_000_000, "lidar")))
        time.sleep(0.3)
    assert wait_until(lambda: len(received) == 2)
    time.sleep(0.5)
    assert [messages.stamp_ns(msg.header.stamp) for msg in received] == [1_000_000_000, 1_300_000_000]
    assert flow_node.stats.counts["pairs_skipped_after_a_lost_scan"] == 1


def test_a_rolling_shutter_pair_through_the_flow_node(graph):
    from support import SWEEP_PERIOD as PERIOD, SWEEP_SPEED as SPEED, swept_pair

    _flow_node, scans, _hints, received = graph
    (pc1, time1), (pc2, time2) = swept_pair(0)
    scans.publish(xyz_to_cloud(pc1, messages.header(1_000_000_000, "lidar"), time=time1))
    time.sleep(0.1)
    scans.publish(xyz_to_cloud(pc2, messages.header(1_100_000_000, "lidar"), time=time2))
    assert wait_until(lambda: len(received) >= 1, timeout_s=60.0)
    cloud = cloud_to_array(received[0])
    np.testing.assert_array_equal(cloud["time"], time1)  # the per-point time passed on
    flow = np.stack([cloud[name] for name in ("flow_x", "flow_y", "flow_z")], axis=1)
    # at constant velocity every raw point of the static street moves by the ego motion between the stamps
    assert np.median(np.linalg.norm(flow - [-SPEED * PERIOD, 0.0, 0.0], axis=1)) < 0.02


@pytest.mark.parametrize("measured", [True, False])
def test_sweeps_deskewed_by_the_vehicles_measured_motion(measured):
    """With twist_topic set, scan t+1's sweep is deskewed by the vehicle's measured motion over it: the first pair of a
    stream is then estimated once (at no measured motion it is deskewed as it is, then again with its own motion), and
    a sweep that no measurement covers is counted."""
    from sim_bridge.ros_messages import vehicle_twist
    from sim_bridge.simulator import MeasuredMotion
    from support import SWEEP_PERIOD as PERIOD, SWEEP_SPEED as SPEED, swept_pair

    with flow_graph("twist_topic:=/vehicle/twist", "mount:=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]") as (
            flow_node, probe, scans, _hints, received):
        twists = probe.create_publisher("geometry_msgs/msg/TwistStamped", "/vehicle/twist")
        assert wait_until(lambda: twists.get_subscription_count() > 0)
        (pc1, time1), (pc2, time2) = swept_pair(0)
        scans.publish(xyz_to_cloud(pc1, messages.header(1_000_000_000, "lidar"), time=time1))
        if measured:  # the vehicle's bus: speed along x, no turn, over the step ending at scan t+1's stamp
            twists.publish(vehicle_twist(MeasuredMotion(SPEED, 0.0), 1_100_000_000))  # as the simulator sends it
            assert wait_until(lambda: len(flow_node.twists.samples) == 1)
        time.sleep(0.1)
        scans.publish(xyz_to_cloud(pc2, messages.header(1_100_000_000, "lidar"), time=time2))
        assert wait_until(lambda: len(received) >= 1, timeout_s=60.0)
        cloud = cloud_to_array(received[0])
        flow = np.stack([cloud[name] for name in ("flow_x", "flow_y", "flow_z")], axis=1)
        assert np.median(np.linalg.norm(flow - [-SPEED * PERIOD, 0.0, 0.0], axis=1)) < 0.02
        assert flow_node.estimator.estimated_again == (0 if measured else 1)
        assert flow_node.stats.counts["sweeps_without_measured_motion"] == (0 if measured else 1)
