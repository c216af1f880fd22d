"""The `ssf` perception source: the SSF pipeline (flow <-> segmentation loop, then an obstacle per moving instance,
its velocity from the flow) on the last two whole scans, plus the static part of the segmentation clustered into
still boxes (as `dbscan` clusters a whole scan); all in the odometry frame, stamped with the older scan."""

from __future__ import annotations

import numpy as np

from ssf_common.config import build
from ssf_common.records import Obstacles
from ssf_eval.nav.perception import ODOM_FRAME, DbscanConfig, Observation, cluster_boxes, stack
from ssf_eval.pipeline import PerceptionConfig, SsfPerception as Pipeline
from ssf_flow_node.core.estimator import WHOLE_SCAN


def whole_scan_config() -> PerceptionConfig:
    """The pipeline as the graph's nodes run it on whole scans."""
    return build(PerceptionConfig, {"flow": WHOLE_SCAN}, source="ssf perception")


class SsfPerception:
    """Semantic scene flow between the previous scan and this one; its moving instances become obstacles."""

    name = "ssf"
    reads_scan = True

    def __init__(self, config: PerceptionConfig | None = None, clusters: DbscanConfig | None = None,
                 device: str = "cpu") -> None:
        self.pipeline = Pipeline(config or whole_scan_config(), device)
        self.clusters = clusters or DbscanConfig()
        self._previous: tuple[int, np.ndarray, np.ndarray] | None = None  # stamp, points, odom <- lidar
        self.iterations: list[int] = []

    def observe(self, observation: Observation) -> Obstacles:
        """Obstacles of the previous scan (stamped then), from its flow towards this scan."""
        frame = observation.frame
        points = np.ascontiguousarray(frame.scan.points[:, :3], dtype=np.float32)
        previous, self._previous = self._previous, (frame.stamp_ns, points, observation.lidar_pose)
        if previous is None:
            return Obstacles.empty(frame.stamp_ns, ODOM_FRAME)
        stamp_ns, pc1, pose1 = previous
        seen = self.pipeline.perceive(pc1, points, stamp_ns=stamp_ns, frame_id="lidar", follows=True)
        self.iterations.append(seen.fusion.iterations)
        moving = seen.obstacles.transformed(pose1, ODOM_FRAME)
        still = cluster_boxes(pc1[~seen.fusion.segmentation.dynamic], pose1, stamp_ns, self.clusters).boxes
        return stack(moving, still)
