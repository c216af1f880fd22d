"""ssf_seg_node: segments each scan's flow into the static scene and moving objects, for the fusion loop.

/ssf/flow (x y z flow_x flow_y flow_z iteration prior) with its /ssf/ego_motion -> segmenter -> /ssf/mask
(x y z mask instance iteration). The flow's ego motion and the mask it was conditioned on are taken as given."""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from ssf_common import topics
from ssf_common.conversions import mask_to_cloud, scene_flow_from_cloud
from ssf_common.diagnostics import StageStats, advertise, worker_counts
from ssf_common.matching import ExactMatcher, ego_motion_listener
from ssf_common.middleware import QOS_DEFAULT, Node, run
from ssf_common.records import EgoMotion, MotionMask, SceneFlow
from ssf_common.worker import LatestWorker
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter


class SegNode(Node):
    """Translates flow clouds (with their ego motion) into segmenter calls, and segmentations into mask clouds."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_seg_node", argv=argv)
        self.config = self.declare_config(SegConfig)
        device = self.declare_parameter("device", "cpu").value
        report_period = self.declare_parameter("report_period_s", 5.0).value
        self.segmenter = make_segmenter(config=self.config, device=device)
        self.mask_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.MASK, QOS_DEFAULT)
        self.worker = LatestWorker(self._segment, ("flow",), self.get_logger(), "seg")
        self.matcher: ExactMatcher[SceneFlow, EgoMotion] = ExactMatcher(self._matched)
        self._compute_ms: list[float] = []
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=worker_counts(self.stats, self.worker), inputs=(topics.FLOW,))
        self.create_timer(report_period, self._report)
        self.create_timer(0.05, lambda: self.matcher.expire(time.monotonic()))
        self.get_logger().info(f"segmenter '{self.segmenter.name}' on {device}")
        self.create_subscription("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION,
                                 ego_motion_listener(self, self.matcher), QOS_DEFAULT)
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.FLOW, self.on_flow, QOS_DEFAULT)

    def on_flow(self, msg: Any) -> None:
        """Match the flow with its ego motion."""
        flow = self.decoded(scene_flow_from_cloud, msg, topics.FLOW)
        if flow is None:
            return
        self.matcher.add_main((flow.stamp_ns, flow.iteration), flow, time.monotonic())

    def _matched(self, flow: SceneFlow, ego: EgoMotion | None) -> None:
        """Queue the flow with its ego motion for segmentation (the newest wins while busy)."""
        if ego is None:
            self.stats.count("flows_without_ego_motion")  # the segmenter fits one itself
        self.worker.submit("flow", dataclasses.replace(flow, ego=ego))

    def _segment(self, _kind: str, flow: SceneFlow) -> None:
        started = time.perf_counter()
        result = self.segmenter.segment(flow.points, flow.flow, flow.prior,
                                        None if flow.ego is None else flow.ego.transform)
        self._compute_ms.append((time.perf_counter() - started) * 1e3)
        self.stats.record(self._compute_ms[-1], "segmentations")
        seg = result.segmentation
        self.mask_pub.publish(mask_to_cloud(MotionMask(flow.stamp_ns, flow.frame_id, flow.points, seg.dynamic_prob,
                                                       seg.instance, flow.iteration)))

    def _report(self) -> None:
        median = f", median {np.median(self._compute_ms):.1f} ms" if self._compute_ms else ""
        self.get_logger().info(f"segmented {self.worker.processed['flow']} flows{median}; "
                               f"dropped {self.worker.dropped['flow']} that arrived while busy")
        self._compute_ms.clear()

    def on_shutdown(self) -> None:
        """Stop the worker."""
        self.worker.stop()


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_seg_node ssf_seg_node."""
    return run(SegNode, argv)
