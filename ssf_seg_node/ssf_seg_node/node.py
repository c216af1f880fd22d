"""ssf_seg_node: segments each scan's flow into the static scene and moving objects, for the fusion loop.

/ssf/flow (x y z flow_x flow_y flow_z iteration) -> segmenter -> /ssf/mask (x y z mask instance iteration)."""

from __future__ import annotations

import collections
import time
from typing import Any

import numpy as np

from ssf_common import topics
from ssf_common.diagnostics import StageStats, advertise, worker_counts
from ssf_common.conversions import mask_to_cloud, scene_flow_from_cloud
from ssf_common.errors import MessageError
from ssf_common.middleware import QOS_DEFAULT, Node, run
from ssf_common.records import MotionMask, SceneFlow
from ssf_common.worker import LatestWorker
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter

PRIOR_HISTORY = 4  # scans whose last mask is kept as the prior of their next iteration


class SegNode(Node):
    """Translates flow clouds into segmenter calls, and segmentations into mask clouds."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_seg_node", argv=argv)
        self.config = self.declare_config(SegConfig)
        device = self.declare_parameter("device", "cpu").value
        report_period = self.declare_parameter("report_period_s", 5.0).value
        self.segmenter = make_segmenter(config=self.config, device=device)
        self.priors: collections.OrderedDict[int, np.ndarray] = collections.OrderedDict()
        self.mask_pub = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.MASK, QOS_DEFAULT)
        self.worker = LatestWorker(self._segment, ("flow",), self.get_logger(), "seg")
        self._compute_ms: list[float] = []
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=worker_counts(self.stats, self.worker), inputs=(topics.FLOW,))
        self.create_timer(report_period, self._report)
        self.get_logger().info(f"segmenter '{self.segmenter.name}' on {device}")
        self.create_subscription("sensor_msgs/msg/PointCloud2", topics.FLOW, self.on_flow, QOS_DEFAULT)

    def on_flow(self, msg: Any) -> None:
        """Queue the flow for segmentation (the newest wins while busy)."""
        try:
            flow = scene_flow_from_cloud(msg)
        except MessageError as err:
            self.get_logger().warning(f"dropped a message on {topics.FLOW}: {err}")
            return
        self.worker.submit("flow", flow)

    def _segment(self, _kind: str, flow: SceneFlow) -> None:
        prior = self.priors.get(flow.stamp_ns) if flow.iteration > 0 else None
        if prior is not None and len(prior) != len(flow.points):
            prior = None
        started = time.perf_counter()
        result = self.segmenter.segment(flow.points, flow.flow, prior)
        self._compute_ms.append((time.perf_counter() - started) * 1e3)
        self.stats.record(self._compute_ms[-1], "segmentations")
        seg = result.segmentation
        self._remember(flow.stamp_ns, seg.dynamic_prob)
        self.mask_pub.publish(mask_to_cloud(MotionMask(flow.stamp_ns, flow.frame_id, flow.points, seg.dynamic_prob,
                                                       seg.instance, flow.iteration)))

    def _remember(self, stamp_ns: int, prob: np.ndarray) -> None:
        self.priors[stamp_ns] = prob
        self.priors.move_to_end(stamp_ns)
        while len(self.priors) > PRIOR_HISTORY:
            self.priors.popitem(last=False)

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
