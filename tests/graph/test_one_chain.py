"""One perception chain, two drivers: scans replayed through the node graph one at a time come out as the same
masks, obstacles and poses as the same scans through the chain in process (`ssf_eval.pipeline`, the loop fixed at one
iteration), and no stage after the flow fits the ego motion again."""

from __future__ import annotations

import numpy as np
import pytest

from support import wait_until
from ssf_common import messages, pose_msgs, topics
from ssf_common.conversions import obstacles_from_msg, semantic_flow_from_cloud
from ssf_common.geometry.se3 import invert
from ssf_common.middleware import Node
from ssf_common.pointcloud import decode_cloud, xyz_to_cloud
from sim_bridge.dataset.export import simulate, warmup_frames
from sim_bridge.scenario import load_scenario
from ssf_eval.nav.ssf_source import whole_scan_config
from ssf_eval.pipeline import PerceptionChain
from ssf_flow_node.node import FlowNode
from ssf_odom_node.core.odometry import OdomInput, make_odometry
from ssf_odom_node.node import OdomNode
from ssf_seg_node.fusion_node import FusionNode
from ssf_seg_node.node import SegNode

SCANS = 6  # scans simulated after the warm-up (the simulator adds the one that ends the last pair)


def simulated_scans(rolling: bool = False) -> tuple[list, np.ndarray]:
    """Consecutive whole scans of a street with traffic (as the simulator publishes them: each point's time where the
    sweep takes its period), and base_link -> lidar."""
    scenario = load_scenario("urban_200", {"lidar.rolling_shutter": rolling})
    frames = list(simulate(scenario, 5, SCANS, warmup_frames(scenario, 2.0)))
    clouds = [xyz_to_cloud(frame.scan.points, messages.header(frame.stamp_ns, "lidar"),
                           **({"time": frame.scan.time} if rolling else {})) for frame in frames]
    return clouds, invert(frames[0].base_pose) @ frames[0].pose


@pytest.fixture
def graph():
    quiet = ["--ros-args", "-p", "report_period_s:=60.0"]
    one = ["-p", "fusion.max_iterations:=1"]
    nodes = [FlowNode(argv=quiet), SegNode(argv=quiet), FusionNode(argv=quiet + one + ["-p", "timeout_s:=60.0"]),
             OdomNode(argv=quiet + ["-p", "command_topic:=\"\"", "-p", "pose_at:=scan"])]
    for node in nodes:
        node.spin_in_thread()
    probe = Node("probe")
    got: dict[str, list] = {topics.SEMANTIC_FLOW: [], topics.OBSTACLES: [], topics.PATH: [], topics.PRIOR: [],
                            topics.DIAGNOSTICS: []}
    for topic, kind in ((topics.SEMANTIC_FLOW, "sensor_msgs/msg/PointCloud2"), (topics.PRIOR, "sensor_msgs/msg/PointCloud2"),
                        (topics.OBSTACLES, "ssf_interfaces/msg/ObstacleArray"), (topics.PATH, "nav_msgs/msg/Path"),
                        (topics.DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray")):
        probe.create_subscription(kind, topic, got[topic].append)
    scans = probe.create_publisher("sensor_msgs/msg/PointCloud2", topics.LIDAR_POINTS)
    tf = probe.create_publisher("tf2_msgs/msg/TFMessage", topics.TF)
    probe.spin_in_thread()
    assert wait_until(lambda: scans.get_subscription_count() >= 1 and tf.get_subscription_count() >= 1)
    yield scans, tf, got, nodes
    for node in nodes:
        node.request_shutdown()
        node.on_shutdown()
        node.destroy_node()
    probe.destroy_node()


@pytest.mark.parametrize("rolling", [False, True], ids=["instant", "rolling-shutter"])
def test_the_graph_and_the_chain_in_process_agree_on_replayed_scans(graph, rolling):
    scans, tf, got, nodes = graph
    recorded, mount = simulated_scans(rolling)
    pairs = len(recorded) - 1
    tf.publish(messages.msg_type("tf2_msgs/msg/TFMessage")(transforms=[pose_msgs.transform_stamped_msg(
        mount, messages.stamp_ns(recorded[0].header.stamp), "base_link", recorded[0].header.frame_id)]))
    for index, scan in enumerate(recorded):  # one at a time: each pair is answered before the next scan comes
        scans.publish(scan)
        if index:
            assert wait_until(lambda: len(got[topics.PRIOR]) == index and len(got[topics.PATH]) == index
                              and len(got[topics.OBSTACLES]) == index, timeout_s=120.0), {k: len(v) for k, v in got.items()}
    # the same scans through the chain in process, and the odometry core
    chain, odometry = PerceptionChain(whole_scan_config(loop_iterations=1)), make_odometry()
    stamps = [messages.stamp_ns(scan.header.stamp) for scan in recorded]
    points = [decode_cloud(scan).xyz for scan in recorded]
    times = [decode_cloud(scan).time for scan in recorded]
    frame = recorded[0].header.frame_id
    priors = 0
    for index in range(pairs):
        seen = chain.perceive(points[index], points[index + 1], stamp_ns=stamps[index], frame_id=frame,
                              follows=index > 0, next_stamp_ns=stamps[index + 1], time1=times[index],
                              time2=times[index + 1])
        step = odometry.step(OdomInput(stamps[index], points[index], seen.fusion.flow,
                                       seen.fusion.segmentation.dynamic_prob, ego=seen.fusion.ego, time=times[index]))
        graph_result = semantic_flow_from_cloud(got[topics.SEMANTIC_FLOW][index])
        assert graph_result.stamp_ns == stamps[index]
        np.testing.assert_allclose(graph_result.segmentation.dynamic_prob, seen.fusion.segmentation.dynamic_prob,
                                   atol=1e-5)
        np.testing.assert_allclose(graph_result.flow, seen.fusion.flow, atol=1e-4)
        if index:  # from the second pair on, both started from the prior the pair before left
            assert seen.prior is not None
            priors += int(seen.prior.any())
        found, expected = obstacles_from_msg(got[topics.OBSTACLES][index]), seen.obstacles
        assert len(found) == len(expected)
        for name in ("centres", "sizes", "velocities"):
            np.testing.assert_allclose(getattr(found, name), getattr(expected, name), atol=1e-3)
        pose = got[topics.PATH][index].poses[-1].pose
        np.testing.assert_allclose(pose_msgs.matrix_from_pose(pose), mount @ step.pose @ invert(mount), atol=1e-4)
    assert priors > 0  # movers were seen, and carried to the next scan
    # nobody after the flow fitted the ego motion again: every stage had the flow's
    assert wait_until(lambda: reported(got[topics.DIAGNOSTICS]).get("ssf_odom_node", {}).get("steps") == str(pairs),
                      timeout_s=10.0)
    for name, values in reported(got[topics.DIAGNOSTICS]).items():
        assert not any(key.endswith("without_ego_motion") for key in values), (name, values)
        if name == "ssf_flow_node":
            assert "pairs_without_their_prior" not in values


def reported(diagnostics: list) -> dict[str, dict[str, str]]:
    """The newest key-values each perception node reported on /diagnostics."""
    newest: dict[str, dict[str, str]] = {}
    for array in diagnostics:
        for status in array.status:
            if status.name in ("ssf_flow_node", "ssf_seg_node", "ssf_fusion_node", "ssf_odom_node"):
                newest[status.name] = {item.key: item.value for item in status.values}
    return newest


def test_the_ego_motion_is_estimated_once_per_pair(monkeypatch):
    """In process too: segmentation, obstacles and odometry take the flow's ego motion; fitting one again fails here."""
    import ssf_odom_node.core.odometry as odometry_core
    import ssf_seg_node.core.geometric as geometric

    def refit(*_args, **_kwargs):
        raise AssertionError("a stage after the flow fitted the ego motion again")

    monkeypatch.setattr(geometric, "fit_ego_motion", refit)
    monkeypatch.setattr(odometry_core, "flow_transform", refit)
    recorded, _ = simulated_scans()
    points = [decode_cloud(scan).xyz for scan in recorded[:3]]
    chain, odometry = PerceptionChain(whole_scan_config(loop_iterations=1)), make_odometry()
    for index in range(2):
        seen = chain.perceive(points[index], points[index + 1], follows=index > 0)
        odometry.step(OdomInput(index, points[index], seen.fusion.flow, seen.fusion.segmentation.dynamic_prob,
                                ego=seen.fusion.ego))
    assert odometry.next_motion is not None and np.allclose(odometry.next_motion, seen.fusion.ego)
