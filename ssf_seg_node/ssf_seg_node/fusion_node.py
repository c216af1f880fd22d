"""ssf_fusion_node: the flow ⇄ segmentation loop across processes, and the obstacles of each finished scan.

/ssf/flow (with its /ssf/ego_motion) + /ssf/mask -> /ssf/mask_hint (next iteration) or, once converged:
/ssf/semantic_flow, /ssf/obstacles (the moving instances with their velocities, and the still part of the scan as
boxes standing still) and /ssf/prior (what the next scan's temporal prior is made of); /ssf/fusion_state every
iteration."""

from __future__ import annotations

import dataclasses
import time
from typing import Any, ClassVar

from pydantic import Field

from ssf_common import messages, topics
from ssf_common.config import Section
from ssf_common.conversions import (mask_from_cloud, mask_to_cloud, obstacles_to_msg,
                                    prior_to_cloud, scene_flow_from_cloud, semantic_flow_to_cloud)
from ssf_common.diagnostics import StageStats, advertise
from ssf_common.markers import MarkerSet
from ssf_common.matching import ExactMatcher, ego_motion_listener
from ssf_common.middleware import QOS_DEFAULT, Node, run
from ssf_common.records import EgoMotion, SceneFlow
from ssf_common.stamps import StampSequence
from ssf_common.temporal_prior import prior_source
from ssf_seg_node.core.fusion import Continue, DistributedLoop, Finish, FusionConfig, LoopStatus
from ssf_seg_node.core.obstacles import ObstacleConfig, result_obstacles


class FusionNodeConfig(Section):
    """The loop's convergence, its patience, and how obstacles are made."""

    fusion: FusionConfig = FusionConfig()
    obstacles: ObstacleConfig = ObstacleConfig()
    timeout_s: float = Field(0.5, gt=0.0, description="a scan whose loop waits longer is finished with its best answer")
    renamed: ClassVar[dict[str, str]] = {"dt": "scan_period"}
    scan_period: float = Field(0.1, gt=0.0, description="seconds between scans where a flow comes without its ego motion (the "
                      "ego motion's stamps tell otherwise)")


class FusionNode(Node):
    """Translates flow and mask clouds into loop decisions, and decisions into hints, results and obstacles."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_fusion_node", argv=argv)
        self.config = self.declare_config(FusionNodeConfig)
        report_period = self.declare_parameter("report_period_s", 5.0).value
        self.loop = DistributedLoop(self.config.fusion, self.config.timeout_s)
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=self._refresh, inputs=(topics.FLOW, topics.MASK))
        self.sequence = StampSequence()
        self.matcher: ExactMatcher[SceneFlow, EgoMotion] = ExactMatcher(self._matched)
        self.hint_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.MASK_HINT, QOS_DEFAULT)
        self.prior_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.PRIOR, QOS_DEFAULT)
        self.result_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.SEMANTIC_FLOW, QOS_DEFAULT)
        self.obstacle_pub = self.create_publisher("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, QOS_DEFAULT)
        self.state_pub = self.create_publisher("ssf_interfaces/msg/FusionState", topics.FUSION_STATE, QOS_DEFAULT)
        self.markers, self.marker_pub = MarkerSet(), self.create_publisher(
            "visualization_msgs/msg/MarkerArray", topics.SSF_MARKERS, QOS_DEFAULT)
        self.create_timer(0.05, self.on_timer)
        self.create_timer(report_period, self._report)
        self.create_subscription("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION,
                                 ego_motion_listener(self, self.matcher), QOS_DEFAULT)
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.FLOW, self.on_flow, QOS_DEFAULT)
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.MASK, self.on_mask, QOS_DEFAULT)

    def on_flow(self, msg: Any) -> None:
        """Match S^(i) of the scan in progress with its ego motion."""
        flow = self.decoded(scene_flow_from_cloud, msg, topics.FLOW)
        if flow is None:
            return
        if self.sequence.restarted(flow.stamp_ns):
            self.get_logger().info("flow stamps jumped back: the stream restarted, a new sequence begins")
            self.loop.restart()
            self.matcher.clear()
        self.matcher.add_main((flow.stamp_ns, flow.iteration), flow, time.monotonic())

    def _matched(self, flow: SceneFlow, ego: EgoMotion | None) -> None:
        """Remember S^(i) with its ego motion."""
        for finish in self.loop.on_flow(dataclasses.replace(flow, ego=ego), time.monotonic()):
            self._publish_result(finish)

    def on_mask(self, msg: Any) -> None:
        """Decide on the segmentation of S^(i): another iteration, or the scan's answer."""
        mask = self.decoded(mask_from_cloud, msg, topics.MASK)
        if mask is None:
            return
        started = time.perf_counter()
        decision = self.loop.on_mask(mask, time.monotonic())
        if isinstance(decision, Continue):
            self._publish_state(decision.status)
            self.hint_pub.publish(mask_to_cloud(decision.hint))
            self.stats.record((time.perf_counter() - started) * 1e3, "iterations")
        elif isinstance(decision, Finish):
            self._publish_result(decision)
            self.stats.record((time.perf_counter() - started) * 1e3, "iterations")

    def on_timer(self) -> None:
        """Match or give up on what waited too long; finish a scan that has waited too long."""
        now = time.monotonic()
        self.matcher.expire(now)
        for finish in self.loop.on_timer(now):
            self._publish_result(finish)

    def _publish_result(self, finish: Finish) -> None:
        result = finish.result
        self._publish_state(finish.status)
        if result.ego is None:  # a flow whose ego motion never came (not from our flow node): the core fits one
            self.stats.count("results_without_ego_motion")
        obstacles = result_obstacles(result, self.config.obstacles, self.config.scan_period).all()
        self.obstacle_pub.publish(obstacles_to_msg(obstacles))  # first: the planner plans the scan on them
        self.result_pub.publish(semantic_flow_to_cloud(result))  # the odometry's pose serves the next plan
        radius = self.config.fusion.prior_radius  # last: the flow node needs it only when the next scan comes
        self.prior_pub.publish(prior_to_cloud(prior_source(result.stamp_ns, result.frame_id, result.points,
                                                           result.flow, result.segmentation.dynamic_prob, radius)))
        if self.marker_pub.get_subscription_count():  # markers are for people watching: none are built for nobody
            self.marker_pub.publish(self.markers.obstacles(obstacles))

    def _publish_state(self, status: LoopStatus) -> None:
        self.state_pub.publish(messages.msg_type("ssf_interfaces/msg/FusionState")(
            header=messages.header(status.stamp_ns, ""), iteration=status.iteration,
            delta_total=float(status.delta_total), delta_flow=float(status.delta_flow),
            delta_mask=float(status.delta_mask), converged=bool(status.converged), num_points=status.num_points,
            num_static=status.num_static, num_clusters=status.num_clusters))

    def _refresh(self) -> None:
        for reason, count in self.loop.finished.items():
            self.stats.set(f"finished_{reason}", count)

    def _report(self) -> None:
        counts = ", ".join(f"{reason} {count}" for reason, count in self.loop.finished.items())
        self.get_logger().info(f"scans finished: {counts}")


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_seg_node ssf_fusion_node."""
    return run(FusionNode, argv)
