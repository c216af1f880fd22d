"""Deskew: a sweep's geometry straightened, results unchanged to the bit without per-point time, and per-point time
through the chain and the flow node."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ssf_common import messages
from ssf_common.config import build
from ssf_common.errors import DataError
from ssf_common.geometry.se3 import make_pose
from ssf_common.geometry.sweep import deskew, pair_times, reskew
from ssf_common.middleware import QOS_SENSOR_DATA, Node
from ssf_common.pointcloud import cloud_to_array, xyz_to_cloud
from support import wait_until

PERIOD, SPEED = 0.1, 10.0  # s, m/s: the sensor drives 1 m while it turns


def azimuth_times(xyz: np.ndarray) -> np.ndarray:
    """Firing times (s, <= 0, stamp at the sweep's end) of points by azimuth: clockwise from behind."""
    share = np.mod(np.pi - np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * np.pi) / (2 * np.pi)  # 0 behind, growing clockwise
    return ((share - 1.0) * PERIOD).astype(np.float32)


def swept(world: np.ndarray, stamp_x: float) -> tuple[np.ndarray, np.ndarray]:
    """A sweep of static world points by a sensor driving along x at SPEED, at stamp_x at its stamp: each point in the
    sensor frame of its firing time, and that time."""
    times = azimuth_times(world - [stamp_x, 0, 0])
    for _ in range(3):  # the azimuth a point is seen at depends on where the sensor is then
        times = azimuth_times(world - np.c_[stamp_x + SPEED * times, np.zeros((len(world), 2))])
    return (world - np.c_[stamp_x + SPEED * times, np.zeros((len(world), 2))]).astype(np.float32), times


def test_a_static_wall_is_bent_by_the_sweep_and_straight_after_deskew():
    wall = np.c_[np.full(400, 15.0), np.linspace(-10, 10, 400), np.zeros(400)]
    raw, times = swept(wall, 0.0)
    motion = make_pose(-SPEED * PERIOD)  # static points come 1 m nearer each period
    straight = deskew(raw, times, motion, PERIOD)
    assert np.ptp(raw[:, 0]) > 0.15 and raw[:, 0].min() > 15.3  # bent, and half a metre off: taken 0.4-0.6 m back
    assert np.abs(straight[:, 0] - 15.0).max() < 1e-3  # straight, where it is at the stamp
    np.testing.assert_allclose(reskew(straight, times, motion, PERIOD), raw, atol=1e-4)
    with pytest.raises(DataError, match="per-point times"):
        deskew(raw, times[:10], motion, PERIOD)


class Answers:
    """An estimator that keeps every answer of the one it wraps."""

    def __init__(self, estimator) -> None:
        self.estimator = estimator
        self.name = estimator.name
        self.answers: list = []

    def estimate(self, *args):
        """The wrapped estimator's answer, kept."""
        self.answers.append(self.estimator.estimate(*args))
        return self.answers[-1]


def test_no_time_or_all_zero_leaves_flow_masks_and_odometry_bit_identical():
    from ssf_eval.pipeline import PerceptionChain, PerceptionConfig
    from ssf_eval.sources import simulator_pairs
    from sim_bridge.dataset.export import PROTOCOLS
    from ssf_flow_node.core.estimator import WHOLE_SCAN
    from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry

    pairs = simulator_pairs("urban_200", 5, 2, PROTOCOLS["whole"], 1.0).pairs
    assert pairs[0].time1 is None  # instant sweeps carry no time
    zeros = [(np.zeros(len(pair.pc1), np.float32), np.zeros(len(pair.pc2), np.float32)) for pair in pairs]
    runs = {}
    for deskew_on, timed_scans in ((False, False), (True, False), (True, True)):  # off, no time: as it always ran
        chain = PerceptionChain(build(PerceptionConfig, {"flow": {**WHOLE_SCAN, "deskew": deskew_on}}))
        spy = chain.loop.estimator.estimator = Answers(chain.loop.estimator.estimator)
        answers = spy.answers
        seen = [chain.perceive(pair.pc1, pair.pc2, follows=index > 0, stamp_ns=index * 10 ** 8,
                               time1=zeros[index][0] if timed_scans else None, time2=zeros[index][1] if timed_scans else None)
                for index, pair in enumerate(pairs)]
        assert [step.fusion.final.flow is answer.flow for step, answer in zip(seen, answers)] == [True, True]  # as given
        runs[deskew_on, timed_scans] = seen
    reference = runs[False, False]
    for seen in runs.values():
        for got, want in zip(seen, reference):
            assert np.array_equal(got.fusion.flow, want.fusion.flow)
            assert np.array_equal(got.fusion.segmentation.dynamic_prob, want.fusion.segmentation.dynamic_prob)
            # Open3D's ICP sums on several threads: the last bits of an ego motion vary from run to run, as before
            np.testing.assert_allclose(got.fusion.ego, want.fusion.ego, rtol=0, atol=1e-9)
    poses = {}
    for deskew_on, timed_scans in ((False, False), (True, False), (True, True)):
        odometry = make_odometry(config=OdomConfig(deskew=deskew_on))
        poses[deskew_on, timed_scans] = [odometry.step(OdomInput(
            index * 10 ** 8, pair.pc1, seen.fusion.flow, seen.fusion.segmentation.dynamic_prob, ego=seen.fusion.ego,
            time=zeros[index][0] if timed_scans else None)).pose for index, (pair, seen) in enumerate(zip(pairs, reference))]
    for got in poses.values():
        assert all(np.array_equal(a, b) for a, b in zip(got, poses[False, False]))


def test_deskew_is_off_without_time_and_changes_the_flow_with_it():
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator

    rng = np.random.default_rng(3)
    world = np.vstack([np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.7, 0.02, 3000)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, 8.0), rng.uniform(-1.7, 3, 1500)],
                       np.c_[np.full(1500, 25.0), rng.uniform(-8, 8, 1500), rng.uniform(-1.7, 3, 1500)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, -9.0), rng.uniform(-1.7, 3, 1500)]])
    (pc1, time1), (pc2, time2) = swept(world, 0.0), swept(world, SPEED * PERIOD)
    config = build(FlowConfig, WHOLE_SCAN)
    plain = make_estimator("rigid", build(FlowConfig, WHOLE_SCAN, {"deskew": False}))
    deskewing = make_estimator("rigid", config)
    without = deskewing.estimate(pc1, pc2)
    assert np.array_equal(without.flow, plain.estimate(pc1, pc2).flow)  # no time: the estimator as given
    sweeps = pair_times(time1, time2, PERIOD)
    with_time = make_estimator("rigid", config).estimate(pc1, pc2, None, sweeps)
    assert not np.array_equal(with_time.flow, without.flow)
    truth = np.array([-SPEED * PERIOD, 0.0, 0.0], np.float32)  # constant velocity: every raw point's flow
    assert np.median(np.linalg.norm(with_time.flow - truth, axis=1)) < 0.02
    assert abs(with_time.ego[0, 3] + SPEED * PERIOD) < 0.02


@pytest.fixture
def graph():
    from ssf_flow_node.node import FlowNode

    flow_node = FlowNode(argv=["--ros-args", "-p", "report_period_s:=60.0"])
    flow_node.spin_in_thread()
    probe = Node("probe")
    received: list = []
    probe.create_subscription("sensor_msgs/msg/PointCloud2", "/ssf/flow", received.append)
    probe.spin_in_thread()
    scans = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/lidar/points", QOS_SENSOR_DATA)
    assert wait_until(lambda: scans.get_subscription_count() > 0)
    yield scans, received
    flow_node.request_shutdown()
    flow_node.on_shutdown()
    flow_node.destroy_node()
    probe.destroy_node()


def test_a_rolling_shutter_pair_through_the_flow_node(graph):
    scans, received = graph
    rng = np.random.default_rng(0)
    world = np.vstack([np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.7, 0.02, 3000)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, 8.0), rng.uniform(-1.7, 3, 1500)],
                       np.c_[np.full(1500, 25.0), rng.uniform(-8, 8, 1500), rng.uniform(-1.7, 3, 1500)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, -9.0), rng.uniform(-1.7, 3, 1500)]])
    (pc1, time1), (pc2, time2) = swept(world, 0.0), swept(world, SPEED * PERIOD)
    scans.publish(xyz_to_cloud(pc1, messages.header(1_000_000_000, "lidar"), time=time1))
    time.sleep(0.1)
    scans.publish(xyz_to_cloud(pc2, messages.header(1_100_000_000, "lidar"), time=time2))
    assert wait_until(lambda: len(received) >= 1, timeout_s=60.0)
    cloud = cloud_to_array(received[0])
    np.testing.assert_array_equal(cloud["time"], time1)  # the per-point time passed through
    flow = np.stack([cloud[name] for name in ("flow_x", "flow_y", "flow_z")], axis=1)
    assert np.median(np.linalg.norm(flow - [-SPEED * PERIOD, 0.0, 0.0], axis=1)) < 0.02
