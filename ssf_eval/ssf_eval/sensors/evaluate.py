"""Perception per LiDAR model and scenario: the flow and segmentation figures of the issue's targets, one cell per
sensor x scenario, pooled over seeds and pairs."""

from __future__ import annotations

import time
from typing import Callable, Iterable, NamedTuple

import numpy as np

from ssf_common.dataset.pairs import ScanPair
from ssf_eval.flow.evaluate import MaskSource, mask_for
from ssf_eval.flow.metrics import FlowScores, pool_scores, score_flow
from ssf_eval.pipeline import PerceptionConfig, PerceptionChain
from ssf_eval.seg.metrics import SegCounts, SegScores, pool, seg_counts, seg_scores
from ssf_flow_node.core.estimator import make_estimator
from ssf_seg_node.core.segmenter import make_segmenter


class Targets(NamedTuple):
    """Issue 12's targets on every sensor model and stress scenario."""

    dynamic_epe: float = 0.15  # m, dynamic-point EPE at most
    ego_ratio: float = 0.4  # dynamic-point EPE at most this share of ego motion alone's
    moving_iou: float = 0.80  # moving-class IoU at least


class CellScores(NamedTuple):
    """One sensor on one scenario: flow of `rigid` and `ego` (given the masks), the fusion loop's flow and
    segmentation (as in the graph: the previous pair's segmentation carried over as its preliminary mask), and the
    default segmenter on the maskless `rigid` flow."""

    sensor: str
    scenario: str
    seeds: tuple[int, ...]
    pairs: int
    points: float  # median points per scan of pc1
    rigid: FlowScores
    ego: FlowScores
    loop_flow: FlowScores
    segmenter: SegScores
    loop_seg: SegScores
    rigid_ms: float  # median per pair
    loop_ms: float
    loop_iterations: float  # mean

    @property
    def rigid_ratio(self) -> float:
        """rigid's dynamic EPE as a share of ego motion alone's."""
        return _share(self.rigid.dynamic.epe3d, self.ego.dynamic.epe3d)

    @property
    def loop_ratio(self) -> float:
        """The loop's dynamic EPE as a share of ego motion alone's."""
        return _share(self.loop_flow.dynamic.epe3d, self.ego.dynamic.epe3d)

    def met(self, targets: Targets = Targets()) -> dict[str, bool]:
        """Which targets the graph's output (the fusion loop's flow and segmentation) meets."""
        return {"dynamic_epe": bool(self.loop_flow.dynamic.epe3d <= targets.dynamic_epe),
                "ego_ratio": bool(self.loop_ratio <= targets.ego_ratio),
                "moving_iou": bool(self.loop_seg.moving_iou >= targets.moving_iou)}


def _share(value: float, of: float) -> float:
    return float(value / of) if of > 0 and np.isfinite(of) else float("nan")


class Parts(NamedTuple):
    """Per-pair results that pool into a cell."""

    rigid: list[FlowScores]
    ego: list[FlowScores]
    loop_flow: list[FlowScores]
    segmenter: list[SegCounts]
    loop_seg: list[SegCounts]
    points: list[int]
    rigid_ms: list[float]
    loop_ms: list[float]
    iterations: list[int]


class SensorEvaluator:
    """The node defaults of every stage, run on each pair: `rigid` and `ego` with the given masks, the default
    segmenter on the maskless `rigid` flow, and the whole loop."""

    def __init__(self, config: PerceptionConfig, masks: MaskSource, device: str = "cpu") -> None:
        self.config = config
        self.masks = masks
        self.rigid = make_estimator("rigid", config.flow, device)
        self.ego = make_estimator("ego", config.flow, device)
        self.segmenter = make_segmenter(config=config.seg, device=device)
        self.perception = PerceptionChain(config, device)

    def run(self, pairs: Iterable[ScanPair], seed: int, progress: Callable[[int], None] | None = None) -> Parts:
        """Every stage on every pair of one sequence of consecutive pairs (masks drawn from the seed, as `ssf eval
        flow` draws them; the loop carries each pair's segmentation to the next as its preliminary mask, as the graph
        does)."""
        rng = np.random.default_rng(seed)
        parts = Parts([], [], [], [], [], [], [], [], [])
        self.perception.reset()
        for index, pair in enumerate(pairs):
            mask = mask_for(pair, self.masks, rng)
            started = time.perf_counter()
            rigid = self.rigid.estimate(pair.pc1, pair.pc2, mask)
            parts.rigid_ms.append((time.perf_counter() - started) * 1e3)
            parts.rigid.append(score_flow(rigid.flow, pair.flow, pair.dynamic1))
            ego = self.ego.estimate(pair.pc1, pair.pc2, mask)
            parts.ego.append(score_flow(ego.flow, pair.flow, pair.dynamic1))
            unmasked = rigid if mask is None else self.rigid.estimate(pair.pc1, pair.pc2)
            segmentation = self.segmenter.segment(pair.pc1, unmasked.flow, None, unmasked.ego).segmentation
            parts.segmenter.append(seg_counts(segmentation, pair))
            started = time.perf_counter()
            loop = self.perception.perceive(pair.pc1, pair.pc2, follows=index > 0, time1=pair.time1,
                                            time2=pair.time2, measured=pair.measured).fusion
            parts.loop_ms.append((time.perf_counter() - started) * 1e3)
            parts.loop_flow.append(score_flow(loop.flow, pair.flow, pair.dynamic1))
            parts.loop_seg.append(seg_counts(loop.segmentation, pair))
            parts.iterations.append(loop.iterations)
            parts.points.append(len(pair.pc1))
            if progress is not None:
                progress(index + 1)
        return parts


def cell_scores(sensor: str, scenario: str, seeds: Iterable[int], parts: Iterable[Parts]) -> CellScores:
    """Pool the per-pair results of every seed into one cell (flow point-weighted, segmentation by counts)."""
    parts = list(parts)

    def joined(name: str) -> list:
        return [item for part in parts for item in getattr(part, name)]

    return CellScores(sensor, scenario, tuple(seeds), len(joined("points")), float(np.median(joined("points"))),
                      pool_scores(joined("rigid")), pool_scores(joined("ego")), pool_scores(joined("loop_flow")),
                      seg_scores(pool(joined("segmenter"))), seg_scores(pool(joined("loop_seg"))),
                      float(np.median(joined("rigid_ms"))), float(np.median(joined("loop_ms"))),
                      float(np.mean(joined("iterations"))))


def cell_record(cell: CellScores, targets: Targets = Targets()) -> dict[str, object]:
    """One cell as plain data for the result file."""
    return {"sensor": cell.sensor, "scenario": cell.scenario, "seeds": list(cell.seeds), "pairs": cell.pairs,
            "points_median": cell.points, "dynamic_points": cell.rigid.dynamic.count,
            "rigid": {split: getattr(cell.rigid, split)._asdict() for split in ("all", "static", "dynamic")},
            "ego": {split: getattr(cell.ego, split)._asdict() for split in ("all", "static", "dynamic")},
            "loop_flow": {split: getattr(cell.loop_flow, split)._asdict() for split in ("all", "static", "dynamic")},
            "segmenter": cell.segmenter._asdict(), "loop_seg": cell.loop_seg._asdict(),
            "rigid_dynamic_over_ego": cell.rigid_ratio, "loop_dynamic_over_ego": cell.loop_ratio,
            "rigid_ms_median": cell.rigid_ms, "loop_ms_median": cell.loop_ms,
            "loop_iterations_mean": cell.loop_iterations, "targets_met": cell.met(targets)}


def format_cells(cells: Iterable[CellScores], targets: Targets = Targets()) -> str:
    """The per-sensor x per-scenario table: dynamic EPE (m) of rigid, the loop and ego motion alone, the loop's share
    of ego's, moving-class IoU of the segmenter and of the loop, and which targets the loop meets."""
    header = (f"{'sensor':<10} {'scenario':<16} {'pairs':>5} {'pts/scan':>8} {'dyn pts':>8} {'rigid dyn':>9} "
              f"{'loop dyn':>8} {'ego dyn':>8} {'loop/ego':>8} {'IoU seg':>7} {'IoU loop':>8}  targets (EPE ratio IoU)")
    lines = [header, "-" * len(header)]
    for cell in cells:
        met = cell.met(targets)
        marks = " ".join("yes" if met[name] else "no " for name in ("dynamic_epe", "ego_ratio", "moving_iou"))
        lines.append(f"{cell.sensor:<10} {cell.scenario:<16} {cell.pairs:5d} {cell.points:8.0f} "
                     f"{cell.rigid.dynamic.count:8d} {cell.rigid.dynamic.epe3d:9.3f} {cell.loop_flow.dynamic.epe3d:8.3f} "
                     f"{cell.ego.dynamic.epe3d:8.3f} {cell.loop_ratio:8.2f} {cell.segmenter.moving_iou:7.3f} "
                     f"{cell.loop_seg.moving_iou:8.3f}  {marks}")
    return "\n".join(lines)
