"""SSF perception in process: the graph's per-scan chain, run by one driver in the order the nodes run it.

For scan t and the scan t+1 after it: the temporal prior M^(0) that scan t-1 left (`/ssf/prior`), carried onto scan t
(the flow node); scene flow with its ego motion (the flow node); segmentation with that ego motion as given (the
segmentation node); the loop's decision (the fusion node, `fusion.max_iterations`); the scan's obstacles, moving and
still (the fusion node); and what scan t leaves for scan t+1's prior (the fusion node). `ssf seg estimate`, the
evaluations and the navigation benchmark run this; the nodes run the same core functions across processes."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.sweep import pair_times
from ssf_common.records import EgoMotion, Obstacles, PriorSource
from ssf_common.temporal_prior import carry_prior, prior_source
from ssf_flow_node.core.estimator import FlowConfig, make_estimator
from ssf_seg_node.core.fusion import FusionConfig, FusionLoop, FusionResult
from ssf_seg_node.core.obstacles import ObstacleConfig, SceneObstacles, scan_obstacles
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter


class PerceptionConfig(Section):
    """The whole perception front end: flow estimator, segmenter, loop, obstacles; one config, dotted names."""

    flow: FlowConfig = FlowConfig()
    seg: SegConfig = SegConfig()
    fusion: FusionConfig = FusionConfig()
    obstacles: ObstacleConfig = ObstacleConfig()
    renamed: ClassVar[dict[str, str]] = {"dt": "scan_period"}
    scan_period: float = Field(0.1, gt=0.0, description="time between consecutive scans (s) where the scans carry no "
                               "stamps")
    measured_motion: bool = Field(True, description="the vehicle's measured motion (wheel speed, gyro) where the "
                                  "source has it (the simulator's odometer; in the graph the flow node's twist_topic): "
                                  "it deskews each sweep and guides and vets the flow's ego motion")


class ChainTimes(NamedTuple):
    """CPU time (ms) of each step of one scan's pass, by the node that runs it."""

    prior_ms: float  # flow node: carrying the previous scan's segmentation onto this one
    flow_ms: float  # flow node: the estimates (every iteration)
    segmentation_ms: float  # segmentation node (every iteration)
    fusion_ms: float  # fusion node: obstacles, and what the next scan's prior is made of


@dataclass(frozen=True)
class ScanPerception:
    """What perception made of one scan pair: the loop's result, its ego motion and the obstacles (scan t's frame)."""

    fusion: FusionResult
    ego: EgoMotion
    found: SceneObstacles
    prior: np.ndarray | None  # M^(0): the mask the loop started from
    cpu: ChainTimes = ChainTimes(0.0, 0.0, 0.0, 0.0)

    @property
    def obstacles(self) -> Obstacles:
        """Every obstacle, moving and still, as /ssf/obstacles carries them."""
        return self.found.all()


class PerceptionChain:
    """Flow ⇄ segmentation until they agree, then obstacles with velocity; scan after scan."""

    def __init__(self, config: PerceptionConfig, device: str = "cpu") -> None:
        self.config = config
        self.loop = FusionLoop(make_estimator(config=config.flow, device=device),
                               make_segmenter(config=config.seg, device=device), config.fusion)
        self.source: PriorSource | None = None  # what the last scan left for the next one's prior

    def reset(self) -> None:
        """Forget the previous scan (a new sequence starts)."""
        self.source = None

    def perceive(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None, stamp_ns: int = 0,
                 frame_id: str = "sensor", follows: bool = False, next_stamp_ns: int | None = None,
                 time1: np.ndarray | None = None, time2: np.ndarray | None = None,
                 measured: np.ndarray | None = None) -> ScanPerception:
        """Semantic scene flow and obstacles of scan t (pc1) towards scan t+1 (pc2). follows: pc1 is the scan the
        previous call's pc2 was, so that call's segmentation, carried by its flow, is the preliminary mask M^(0)
        (unless a mask is given). Velocities use the stamps' interval when next_stamp_ns is given, else config.scan_period.
        time1, time2: each point's time (s relative to its scan's stamp), where the sweeps took their period to turn:
        the flow deskews with them (flow.deskew), as the flow node does; measured: the sensor's motion over scan t+1's
        sweep as the vehicle measured it (`ScanPair.measured`), which deskews it and guides the ego motion (measured_motion)."""
        radius = self.config.fusion.prior_radius
        started = time.process_time()
        dt = self.config.scan_period if next_stamp_ns is None else (next_stamp_ns - stamp_ns) * 1e-9
        # 1. the temporal prior: the previous scan's segmentation carried onto this one
        if mask is None and follows and self.source is not None:
            mask = carry_prior(self.source, pc1)
        carried = time.process_time()
        # 2. flow with its ego motion ⇄ segmentation, until they agree
        measured = measured if self.config.measured_motion else None
        fusion = self.loop.run(pc1, pc2, mask, pair_times(time1, time2, dt, measured))
        looped = time.process_time()
        ego = EgoMotion(stamp_ns, stamp_ns + int(round(dt * 1e9)), frame_id, fusion.ego, fusion.iterations - 1)
        # 3. the obstacles: moving instances with their velocities, the still part as boxes
        found = scan_obstacles(pc1, fusion.flow, fusion.segmentation, fusion.ego, ego.dt, stamp_ns, frame_id,
                               self.config.obstacles)
        # 4. what this scan leaves for the next one's prior
        self.source = prior_source(stamp_ns, frame_id, pc1, fusion.flow, fusion.segmentation.dynamic_prob, radius)
        flow_ms = sum(step.flow_cpu_ms for step in fusion.steps)
        cpu = ChainTimes((carried - started) * 1e3, flow_ms, (looped - carried) * 1e3 - flow_ms,
                         (time.process_time() - looped) * 1e3)
        return ScanPerception(fusion, ego, found, mask, cpu)
