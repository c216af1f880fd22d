"""The mutual-promotion loop of the paper: flow with the mask M^(i) -> segmentation -> M^(i+1), until
Delta_total = alpha ||S^(i) - S^(i-1)|| + beta ||M^(i) - M^(i-1)|| < epsilon or N_iter iterations."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.records import Segmentation
from ssf_seg_node.core.base import Segmenter


class FusionConfig(Section):
    """Convergence of the loop (norms are means over points: m of flow, probability of mask)."""

    alpha: float = Field(1.0, ge=0.0, description="weight of the flow change in Delta_total")
    beta: float = Field(1.0, ge=0.0, description="weight of the mask change in Delta_total")
    epsilon: float = Field(1e-3, gt=0.0, description="the loop has converged when Delta_total falls below this")
    max_iterations: int = Field(5, ge=1, description="N_iter: flow estimates at most (iteration 0 has no mask)")


class FlowEstimate(Protocol):
    """What a flow estimator returns (ssf_flow_node's FlowResult)."""

    flow: np.ndarray
    ego: np.ndarray


class FlowEstimatorLike(Protocol):
    """Any scene flow estimator: estimate(pc1, pc2, mask) -> flow for every point of pc1, and the ego motion."""

    name: str

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> Any: ...


@dataclass(frozen=True)
class FusionStep:
    """One iteration: the flow it estimated, the segmentation of that flow, and how much both changed."""

    iteration: int
    flow: np.ndarray
    segmentation: Segmentation
    ego: np.ndarray
    delta_flow: float  # mean |S^(i) - S^(i-1)| over points (m); inf on iteration 0
    delta_mask: float  # mean |M^(i+1) - M^(i)| over points
    delta_total: float
    flow_ms: float
    segmentation_ms: float


@dataclass(frozen=True)
class FusionResult:
    """The loop's answer for one scan pair: the last flow and segmentation, and every iteration on the way."""

    steps: list[FusionStep] = field(default_factory=list)
    converged: bool = False

    @property
    def final(self) -> FusionStep:
        """The last iteration."""
        return self.steps[-1]

    @property
    def flow(self) -> np.ndarray:
        """(N, 3) flow of every point of scan t."""
        return self.final.flow

    @property
    def segmentation(self) -> Segmentation:
        """The segmentation of every point of scan t."""
        return self.final.segmentation

    @property
    def ego(self) -> np.ndarray:
        """The ego motion (scan-t coordinates of static points -> scan t+1)."""
        return self.final.ego

    @property
    def iterations(self) -> int:
        """Flow estimates made."""
        return len(self.steps)


def mask_change(new: np.ndarray, old: np.ndarray | None) -> float:
    """Mean absolute change of the dynamic probability (a missing old mask counts as all static)."""
    return float(np.mean(np.abs(new - (0.0 if old is None else old)))) if len(new) else 0.0


def flow_change(new: np.ndarray, old: np.ndarray | None) -> float:
    """Mean end-point distance between two flows (inf without a previous flow)."""
    if old is None:
        return float("inf")
    return float(np.linalg.norm(new - old, axis=1).mean()) if len(new) else 0.0


class FusionLoop:
    """Flow and segmentation promoting each other until they agree."""

    def __init__(self, estimator: FlowEstimatorLike, segmenter: Segmenter, config: FusionConfig) -> None:
        self.estimator = estimator
        self.segmenter = segmenter
        self.config = config

    def run(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FusionResult:
        """Iterate from the preliminary mask M^(0) (None: no mask) until Delta_total < epsilon or N_iter."""
        steps: list[FusionStep] = []
        previous_flow = None
        for iteration in range(self.config.max_iterations):
            # 1. scene flow conditioned on the current mask
            started = time.perf_counter()
            estimate = self.estimator.estimate(pc1, pc2, mask)
            flow_ms = (time.perf_counter() - started) * 1e3
            # 2. segmentation of points and flow, with the current mask as its prior
            started = time.perf_counter()
            result = self.segmenter.segment(pc1, estimate.flow, mask, estimate.ego)
            segmentation_ms = (time.perf_counter() - started) * 1e3
            # 3. how much flow and mask changed
            new_mask = result.segmentation.dynamic_prob
            delta_flow, delta_mask = flow_change(estimate.flow, previous_flow), mask_change(new_mask, mask)
            delta_total = self.config.alpha * delta_flow + self.config.beta * delta_mask
            steps.append(FusionStep(iteration, estimate.flow, result.segmentation, np.asarray(estimate.ego),
                                    delta_flow, delta_mask, delta_total, flow_ms, segmentation_ms))
            # 4. stop once they agree
            if delta_total < self.config.epsilon:
                return FusionResult(steps, converged=True)
            previous_flow, mask = estimate.flow, new_mask
        return FusionResult(steps, converged=False)
