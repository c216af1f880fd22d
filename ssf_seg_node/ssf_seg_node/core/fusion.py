"""The mutual-promotion loop of the paper: flow with the mask M^(i) -> segmentation -> M^(i+1), until
Delta_total = alpha ||S^(i) - S^(i-1)|| + beta ||M^(i) - M^(i-1)|| < epsilon or N_iter iterations."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.sweep import PairTimes
from ssf_common.records import MotionMask, SceneFlow, Segmentation, SemanticFlow
from ssf_common.temporal_prior import carry_prior, prior_source
from ssf_seg_node.core.base import Segmenter


class FusionConfig(Section):
    """Convergence of the loop (norms are means over points: m of flow, probability of mask)."""

    alpha: float = Field(1.0, ge=0.0, description="weight of the flow change in Delta_total")
    beta: float = Field(1.0, ge=0.0, description="weight of the mask change in Delta_total")
    epsilon: float = Field(1e-3, gt=0.0, description="the loop has converged when Delta_total falls below this")
    max_iterations: int = Field(1, ge=1, description="N_iter: flow estimates at most. One: the flow starts from the "
                                "temporal prior and the segmentation answers it; further iterations change the answer "
                                "by less than 0.001 in EPE and IoU on whole scans (`ssf eval fusion --iterations 5`) "
                                "for a whole flow estimate each")
    prior_radius: float = Field(1.0, ge=0.0, description="temporal prior M^(0): each point of a scan takes the dynamic "
                                "probability of the previous scan's nearest point moved by its flow, within this distance "
                                "(m); 0: no prior, iteration 0 has no mask")


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
    flow_ms: float  # wall time of the flow estimate
    segmentation_ms: float  # and of the segmentation
    flow_cpu_ms: float = 0.0  # CPU time of the flow estimate
    segmentation_cpu_ms: float = 0.0  # and of the segmentation


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


class Convergence(NamedTuple):
    """How much one iteration changed flow and mask, and whether the loop has converged."""

    delta_flow: float
    delta_mask: float
    delta_total: float
    converged: bool


def convergence(config: FusionConfig, flow: np.ndarray, previous_flow: np.ndarray | None, new_mask: np.ndarray,
                mask: np.ndarray | None) -> Convergence:
    """Delta_total = alpha ||S^(i) - S^(i-1)|| + beta ||M^(i+1) - M^(i)|| and whether it fell below epsilon."""
    delta_flow, delta_mask = flow_change(flow, previous_flow), mask_change(new_mask, mask)
    total = config.alpha * delta_flow + config.beta * delta_mask
    return Convergence(delta_flow, delta_mask, total, total < config.epsilon)


def carry_mask(points: np.ndarray, flow: np.ndarray, probability: np.ndarray, next_points: np.ndarray,
               radius: float) -> np.ndarray:
    """The temporal prior M^(0) of the next scan: each of its points takes the dynamic probability of the nearest
    point of this scan moved by its flow into the next scan's frame (0 where none lies within radius); the two
    halves the graph's fusion and flow nodes run, back to back."""
    return carry_prior(prior_source(0, "", points, flow, probability, radius), next_points)


class FusionLoop:
    """Flow and segmentation promoting each other until they agree."""

    def __init__(self, estimator: FlowEstimatorLike, segmenter: Segmenter, config: FusionConfig) -> None:
        self.estimator = estimator
        self.segmenter = segmenter
        self.config = config

    def run(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None,
            sweeps: PairTimes | None = None) -> FusionResult:
        """Iterate from the preliminary mask M^(0) (None: no mask) until Delta_total < epsilon or N_iter; `sweeps`
        (per-point time of both scans; None: none) goes to the flow estimator, which deskews with it."""
        steps: list[FusionStep] = []
        previous_flow = None
        timed = {} if sweeps is None else {"sweeps": sweeps}
        for iteration in range(self.config.max_iterations):
            # 1. scene flow conditioned on the current mask
            started, cpu = time.perf_counter(), time.process_time()
            estimate = self.estimator.estimate(pc1, pc2, mask, **timed)
            flow_ms, flow_cpu_ms = (time.perf_counter() - started) * 1e3, (time.process_time() - cpu) * 1e3
            # 2. segmentation of points and flow, with the current mask as its prior
            started, cpu = time.perf_counter(), time.process_time()
            result = self.segmenter.segment(pc1, estimate.flow, mask, estimate.ego)
            segmentation_ms, segmentation_cpu_ms = (time.perf_counter() - started) * 1e3, (time.process_time() - cpu) * 1e3
            # 3. how much flow and mask changed
            new_mask = result.segmentation.dynamic_prob
            change = convergence(self.config, estimate.flow, previous_flow, new_mask, mask)
            steps.append(FusionStep(iteration, estimate.flow, result.segmentation, np.asarray(estimate.ego),
                                    change.delta_flow, change.delta_mask, change.delta_total, flow_ms, segmentation_ms,
                                    flow_cpu_ms, segmentation_cpu_ms))
            # 4. stop once they agree
            if change.converged:
                return FusionResult(steps, converged=True)
            previous_flow, mask = estimate.flow, new_mask
        return FusionResult(steps, converged=False)


class LoopStatus(NamedTuple):
    """One iteration of a scan's loop, as /ssf/fusion_state reports it."""

    stamp_ns: int
    iteration: int
    delta_total: float
    delta_flow: float
    delta_mask: float
    converged: bool
    num_points: int
    num_static: int
    num_clusters: int


@dataclass(frozen=True)
class Continue:
    """Not converged yet: send this mask to the flow estimator for the next iteration."""

    hint: MotionMask
    status: LoopStatus


@dataclass(frozen=True)
class Finish:
    """Converged (or stopped on N_iter or a timeout): the scan's semantic flow."""

    result: SemanticFlow
    status: LoopStatus
    reason: str  # "converged" | "max_iterations" | "timeout" | "superseded"


@dataclass
class _Scan:
    stamp_ns: int
    frame_id: str
    points: np.ndarray
    started_s: float
    flows: dict[int, SceneFlow] = field(default_factory=dict)  # S^(i) with the mask M^(i) it was conditioned on
    masks: dict[int, MotionMask] = field(default_factory=dict)  # M^(i+1): the segmentation of S^(i)
    hinted_s: float | None = None  # when the last mask hint went out


class DistributedLoop:
    """The fusion loop when flow and segmentation run in other processes: it takes S^(i) (with the mask M^(i) it was
    conditioned on, and its ego motion) and the segmentation of it as they arrive, keyed by stamp and iteration, and
    decides as `FusionLoop.run` does: continue (a mask hint) or finish. A lost or late message never stalls it: after
    `timeout_s` the best answer so far is published, and an iteration that the measured round trip (hint -> mask) says
    would end after `timeout_s` is not started (the answer goes out at once)."""

    def __init__(self, config: FusionConfig, timeout_s: float = 0.5) -> None:
        self.config = config
        self.timeout_s = timeout_s
        self.scan: _Scan | None = None
        self.finished: dict[str, int] = {"converged": 0, "max_iterations": 0, "timeout": 0, "superseded": 0,
                                         "deadline": 0}
        self.round_trip_s: float | None = None  # mask hint -> the next iteration's mask, smoothed over scans

    def restart(self) -> None:
        """Forget the scan in progress: the stream started again (its stamps jumped back)."""
        self.scan = None

    def on_flow(self, flow: SceneFlow, now_s: float) -> list[Finish]:
        """Remember S^(i); a flow of a newer scan finishes the current one with what it has."""
        done: list[Finish] = []
        if self.scan is None or flow.stamp_ns != self.scan.stamp_ns:
            if self.scan is not None and flow.stamp_ns < self.scan.stamp_ns:
                return done  # a late answer for a scan already given up
            if self.scan is not None:
                done += self._finish_best("superseded")
            self.scan = _Scan(flow.stamp_ns, flow.frame_id, np.asarray(flow.points), now_s)
        if len(flow.points) != len(self.scan.points):
            return done
        self.scan.flows[flow.iteration] = flow
        return done

    def on_mask(self, mask: MotionMask, now_s: float) -> Continue | Finish | None:
        """The segmentation of S^(i) arrived: converged, stopped, or continue with it as the next mask hint."""
        scan = self.scan
        if scan is None or mask.stamp_ns != scan.stamp_ns or mask.iteration not in scan.flows:
            return None
        if len(mask.dynamic_prob) != len(scan.points):
            return None
        i = mask.iteration
        scan.masks[i] = mask
        if i > 0 and scan.hinted_s is not None:
            taken = now_s - scan.hinted_s
            self.round_trip_s = taken if self.round_trip_s is None else 0.8 * self.round_trip_s + 0.2 * taken
        flow, previous = scan.flows[i], scan.flows.get(i - 1)
        change = convergence(self.config, flow.flow, None if previous is None else previous.flow, mask.dynamic_prob,
                             flow.prior)
        status = self._status(i, change.delta_total, change.delta_flow, change.delta_mask, change.converged, mask)
        if change.converged or i + 1 >= self.config.max_iterations:
            return self._finish(i, status, "converged" if change.converged else "max_iterations")
        if self.round_trip_s is not None and now_s - scan.started_s + self.round_trip_s > self.timeout_s:
            return self._finish(i, status, "deadline")  # another iteration would end after the timeout: answer now
        scan.hinted_s = now_s
        return Continue(MotionMask(scan.stamp_ns, scan.frame_id, scan.points, mask.dynamic_prob, mask.instance, i + 1),
                        status)

    def on_timer(self, now_s: float) -> list[Finish]:
        """Give up on a scan that has waited too long, publishing the best answer so far."""
        if self.scan is not None and now_s - self.scan.started_s > self.timeout_s:
            return self._finish_best("timeout")
        return []

    def _status(self, iteration: int, total: float, flow: float, mask: float, converged: bool, seg: MotionMask) -> LoopStatus:
        static = int(np.count_nonzero(seg.dynamic_prob <= 0.5))
        clusters = int(np.unique(seg.instance[seg.instance > 0]).size)
        return LoopStatus(self.scan.stamp_ns, iteration, total, flow, mask, converged, len(seg.dynamic_prob), static, clusters)

    def _finish_best(self, reason: str) -> list[Finish]:
        scan = self.scan
        if scan is None:
            return []
        if not scan.masks:  # no segmentation arrived: nothing trustworthy to publish
            self.scan = None
            self.finished[reason] += 1
            return []
        i = max(scan.masks)
        mask = scan.masks[i]
        status = self._status(i, float("nan"), float("nan"), float("nan"), False, mask)
        return [self._finish(i, status, reason)]

    def _finish(self, iteration: int, status: LoopStatus, reason: str) -> Finish:
        scan = self.scan
        mask, flow = scan.masks[iteration], scan.flows[iteration]
        segmentation = Segmentation.from_probability(mask.dynamic_prob, mask.instance)
        result = SemanticFlow(scan.stamp_ns, scan.frame_id, scan.points, np.asarray(flow.flow, np.float32),
                              segmentation, iterations=iteration + 1, converged=reason == "converged", ego=flow.ego,
                              time=flow.time)
        self.finished[reason] += 1
        self.scan = None
        return Finish(result, status, reason)
