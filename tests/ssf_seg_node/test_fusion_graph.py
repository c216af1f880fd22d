"""The flow ⇄ segmentation ⇄ fusion nodes converge on replayed scans and publish semantic flow and obstacles."""

from __future__ import annotations

import numpy as np
import pytest

from support import wait_until
from ssf_common import messages
from ssf_common.conversions import obstacles_from_msg, semantic_flow_from_cloud
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.middleware import QOS_SENSOR_DATA, Node
from ssf_common.pointcloud import xyz_to_cloud
from ssf_common.records import MotionMask, SceneFlow
from ssf_flow_node.node import FlowNode
from ssf_common.config import build
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_seg_node.core.fusion import Continue, DistributedLoop, Finish, FusionConfig, FusionLoop
from ssf_seg_node.core.segmenter import make_segmenter
from ssf_seg_node.fusion_node import FusionNode
from ssf_seg_node.node import SegNode


def test_distributed_loop_continues_then_converges_and_times_out():
    loop = DistributedLoop(FusionConfig(max_iterations=4), timeout_s=0.5)
    points = np.zeros((4, 3), np.float32)
    flow = np.ones((4, 3), np.float32)
    prob = np.array([0.0, 0.0, 1.0, 1.0], np.float32)
    instance = np.array([0, 0, 1, 1], np.int32)
    assert loop.on_flow(SceneFlow(5, "lidar", points, flow, 0), 0.0) == []
    first = loop.on_mask(MotionMask(5, "lidar", points, prob, instance, 0), 0.1)
    assert isinstance(first, Continue) and first.hint.iteration == 1 and np.isinf(first.status.delta_flow)
    loop.on_flow(SceneFlow(5, "lidar", points, flow, 1, first.hint.dynamic_prob), 0.2)  # conditioned on the hint
    done = loop.on_mask(MotionMask(5, "lidar", points, prob, instance, 1), 0.3)
    assert isinstance(done, Finish) and done.reason == "converged" and done.status.delta_total == 0.0
    assert done.result.iterations == 2 and done.result.segmentation.num_instances == 1
    # a lost mask: the timer finishes the scan with the best answer it has
    loop.on_flow(SceneFlow(6, "lidar", points, flow, 0), 1.0)
    loop.on_mask(MotionMask(6, "lidar", points, prob, instance, 0), 1.1)
    loop.on_flow(SceneFlow(6, "lidar", points, flow * 2, 1), 1.2)
    assert loop.on_timer(1.3) == []
    [late] = loop.on_timer(1.6)
    assert late.reason == "timeout" and not late.result.converged
    # a newer scan supersedes one still in progress; a late answer for a finished scan is ignored
    loop.on_flow(SceneFlow(7, "lidar", points, flow, 0), 2.0)
    loop.on_mask(MotionMask(7, "lidar", points, prob, instance, 0), 2.1)
    [superseded] = loop.on_flow(SceneFlow(8, "lidar", points, flow, 0), 2.2)
    assert superseded.reason == "superseded" and superseded.result.stamp_ns == 7
    assert loop.on_mask(MotionMask(7, "lidar", points, prob, instance, 1), 2.3) is None
    assert loop.finished == {"converged": 1, "max_iterations": 0, "timeout": 1, "superseded": 1, "deadline": 0}


@pytest.fixture
def graph():
    quiet = ["--ros-args", "-p", "report_period_s:=60.0"]
    nodes = [FlowNode(argv=quiet + ["-p", "preprocess.remove_ground:=false"]), SegNode(argv=quiet),
             FusionNode(argv=quiet + ["-p", "timeout_s:=5.0", "-p", "fusion.max_iterations:=3"])]  # the paper's loop
    for node in nodes:
        node.spin_in_thread()
    probe = Node("probe")
    results, obstacles, states, markers = [], [], [], []
    probe.create_subscription("sensor_msgs/msg/PointCloud2", "/ssf/semantic_flow", results.append)
    probe.create_subscription("ssf_interfaces/msg/ObstacleArray", "/ssf/obstacles", obstacles.append)
    probe.create_subscription("ssf_interfaces/msg/FusionState", "/ssf/fusion_state", states.append)
    probe.create_subscription("visualization_msgs/msg/MarkerArray", "/ssf/markers", markers.append)
    flows = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/ssf/flow")
    probe.spin_in_thread()
    scans = probe.create_publisher("sensor_msgs/msg/PointCloud2", "/lidar/points", QOS_SENSOR_DATA)
    assert wait_until(lambda: scans.get_subscription_count() > 0 and flows.get_subscription_count() >= 2)
    yield scans, flows, results, obstacles, states, markers
    for node in nodes:
        node.request_shutdown()
        node.on_shutdown()
        node.destroy_node()
    probe.destroy_node()


def test_the_node_loop_converges_on_replayed_scans(graph, capfd):
    scans, flows, results, obstacles, states, markers = graph
    flows.publish(xyz_to_cloud(np.zeros((10, 3), np.float32), messages.header(1, "lidar")))  # no flow fields
    pair = synthetic_pair(seed=2, agents=3, points=8192)
    scans.publish(xyz_to_cloud(pair.pc1, messages.header(1_000_000_000, "lidar")))
    assert wait_until(lambda: scans.get_subscription_count() > 0)
    scans.publish(xyz_to_cloud(pair.pc2, messages.header(1_100_000_000, "lidar")))
    assert wait_until(lambda: len(results) == 1 and len(obstacles) == 1, timeout_s=60.0)
    result = semantic_flow_from_cloud(results[0])
    assert result.stamp_ns == 1_000_000_000 and len(result) == len(pair.pc1)
    # what the same loop finds in process, the graph finds too
    in_process = FusionLoop(make_estimator(config=build(FlowConfig, WHOLE_SCAN, {"preprocess": {"remove_ground": False}})),
                            make_segmenter(), FusionConfig(max_iterations=3)).run(pair.pc1, pair.pc2).segmentation
    assert (result.segmentation.dynamic == in_process.dynamic).mean() > 0.99
    assert (result.segmentation.dynamic == pair.dynamic1).mean() > 0.95 and result.segmentation.num_instances >= 1
    found = obstacles_from_msg(obstacles[0])
    moving, still = found.take(np.flatnonzero(found.ids > 0)), found.take(np.flatnonzero(found.ids == 0))
    assert found.frame_id == "lidar" and len(moving) == result.segmentation.num_instances
    assert all(np.linalg.norm(moving.velocities[:, :2], axis=1) > 0.5)  # moving objects, ego motion removed
    assert len(still) > 0 and not still.velocities.any()  # the street's still structure, standing still
    assert wait_until(lambda: states and states[-1].converged)  # /ssf/fusion_state is a topic of its own
    assert [state.iteration for state in states] == list(range(len(states)))
    assert wait_until(lambda: len(markers) == 1)  # the same obstacles as boxes for RViz / Foxglove
    boxes = [m for m in markers[0].markers if m.ns == "obstacles"]
    assert len(boxes) == len(found) and all(m.header.frame_id == "lidar" for m in boxes)
    assert "dropped a message on /ssf/flow" in capfd.readouterr().err
