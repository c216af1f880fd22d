"""SSF perception assembled from the stages' cores: the flow estimator and the segmenter promoting each other in the
fusion loop, then obstacles. What `ssf seg estimate`, the evaluations and the navigation benchmark run in process."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.records import Obstacles
from ssf_flow_node.core.estimator import FlowConfig, make_estimator
from ssf_seg_node.core.fusion import FusionConfig, FusionLoop, FusionResult, carry_mask
from ssf_seg_node.core.obstacles import ObstacleConfig, extract_obstacles
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter


class PerceptionConfig(Section):
    """The whole perception front end: flow estimator, segmenter, loop, obstacles; one config, dotted names."""

    flow: FlowConfig = FlowConfig()
    seg: SegConfig = SegConfig()
    fusion: FusionConfig = FusionConfig()
    obstacles: ObstacleConfig = ObstacleConfig()
    dt: float = Field(0.1, gt=0.0, description="time between consecutive scans (s)")


@dataclass(frozen=True)
class Perception:
    """What perception made of one scan pair: the loop's result and the obstacles (scan t's sensor frame)."""

    fusion: FusionResult
    obstacles: Obstacles


class SsfPerception:
    """Flow ⇄ segmentation until they agree, then obstacles with velocity."""

    def __init__(self, config: PerceptionConfig, device: str = "cpu") -> None:
        self.config = config
        self.loop = FusionLoop(make_estimator(config=config.flow, device=device),
                               make_segmenter(config=config.seg, device=device), config.fusion)
        self.previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # points, flow, dynamic probability

    def reset(self) -> None:
        """Forget the previous scan (a new sequence starts)."""
        self.previous = None

    def perceive(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None, stamp_ns: int = 0,
                 frame_id: str = "sensor", follows: bool = False) -> Perception:
        """Flow, segmentation and obstacles of scan t (pc1) towards scan t+1 (pc2). follows: pc1 is the scan the
        previous call's pc2 was, so that call's segmentation, carried by its flow, is the preliminary mask M^(0)
        (unless a mask is given)."""
        if mask is None and follows and self.previous is not None:
            mask = carry_mask(*self.previous, pc1, self.config.fusion.prior_radius)
        fusion = self.loop.run(pc1, pc2, mask)
        self.previous = (np.asarray(pc1)[:, :3], fusion.flow, fusion.segmentation.dynamic_prob)
        obstacles = extract_obstacles(pc1, fusion.flow, fusion.segmentation, fusion.ego, self.config.dt, stamp_ns,
                                      frame_id, self.config.obstacles)
        return Perception(fusion, obstacles)
