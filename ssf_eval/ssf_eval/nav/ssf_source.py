"""The `ssf` perception source: the flow <-> segmentation loop on the last two whole scans, and an obstacle per
moving instance (box, velocity from the flow with the ego motion removed), moved into the odometry frame."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section, build
from ssf_common.records import Obstacles
from ssf_eval.nav.perception import ODOM_FRAME, Observation
from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig, make_estimator
from ssf_seg_node.core.fusion import FusionConfig, FusionLoop
from ssf_seg_node.core.obstacles import ObstacleConfig, extract_obstacles
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter


class SsfConfig(Section):
    """The cores the fusion node runs, with the node's defaults (whole scans)."""

    flow: FlowConfig = Field(default_factory=lambda: build(FlowConfig, WHOLE_SCAN))
    segmentation: SegConfig = SegConfig()
    fusion: FusionConfig = FusionConfig()
    obstacles: ObstacleConfig = ObstacleConfig()
    device: str = "cpu"


class SsfPerception:
    """Semantic scene flow between the previous scan and this one; its moving instances become obstacles."""

    name = "ssf"
    reads_scan = True

    def __init__(self, config: SsfConfig | None = None) -> None:
        self.config = config or SsfConfig()
        estimator = make_estimator(config=self.config.flow, device=self.config.device)
        segmenter = make_segmenter(config=self.config.segmentation, device=self.config.device)
        self.loop = FusionLoop(estimator, segmenter, self.config.fusion)
        self._previous: tuple[int, np.ndarray, np.ndarray, np.ndarray | None] | None = None  # stamp, points, pose, mask
        self.iterations: list[int] = []

    def observe(self, observation: Observation) -> Obstacles:
        """Obstacles of the previous scan (stamped then), from its flow towards this scan."""
        frame = observation.frame
        points = np.ascontiguousarray(frame.scan.points[:, :3], dtype=np.float32)
        previous, self._previous = self._previous, (frame.stamp_ns, points, observation.lidar_pose, None)
        if previous is None:
            return Obstacles.empty(frame.stamp_ns, ODOM_FRAME)
        stamp_ns, pc1, pose1, _ = previous
        result = self.loop.run(pc1, points)
        self.iterations.append(result.iterations)
        dt = (frame.stamp_ns - stamp_ns) * 1e-9
        seen = extract_obstacles(pc1, result.flow, result.segmentation, result.ego, dt, stamp_ns, "lidar",
                                 self.config.obstacles)
        return seen.transformed(pose1, ODOM_FRAME)
