"""The paper's segmentation table and the fusion loop's per-iteration figure, on labelled pairs."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Collection, Iterable, NamedTuple, Sequence

import numpy as np

from ssf_common.dataset.pairs import ScanPair
from ssf_common.render.figures import save_figure
from ssf_eval.flow.metrics import score_flow
from ssf_eval.pipeline import PerceptionConfig, PerceptionChain
from ssf_eval.seg.metrics import ObstacleErrors, SegCounts, SegScores, obstacle_errors, pool, seg_counts, seg_scores
from ssf_seg_node.core.base import Segmenter
from ssf_seg_node.core.obstacles import extract_obstacles

SSF = "ssf"  # the fusion loop's row


class FlowInput(NamedTuple):
    """The flow every segmenter of the table is given for one pair, and the ego motion that came with it."""

    flow: np.ndarray
    ego: np.ndarray


@dataclass(frozen=True)
class Method:
    """One row of the table: a segmenter on a given flow, or the fusion loop (segmenter None)."""

    label: str
    segmenter: Segmenter | None


class MethodScores(NamedTuple):
    """One row's pooled scores."""

    label: str
    scores: SegScores
    obstacles: dict[str, float]
    ms_median: float
    frames: int
    iterations_mean: float


def evaluate_segmentation(methods: Sequence[Method], pairs: Iterable[ScanPair], flow_of: Callable[[ScanPair], FlowInput],
                          perception: PerceptionChain | None, config: PerceptionConfig,
                          progress: Callable[[int], None] | None = None,
                          sequence_starts: Collection[int] = (0,)) -> list[MethodScores]:
    """Every method on every pair: segmenters on the pair's given flow, the loop (SSF) on the scans themselves (pairs
    are consecutive except where a sequence starts, so the loop carries each segmentation to the next pair as its
    preliminary mask)."""
    counts: dict[str, list[SegCounts]] = {m.label: [] for m in methods}
    errors: dict[str, list[ObstacleErrors]] = {m.label: [] for m in methods}
    times: dict[str, list[float]] = {m.label: [] for m in methods}
    iterations: dict[str, list[int]] = {m.label: [] for m in methods}
    for index, pair in enumerate(pairs):
        given = None
        for method in methods:
            started = time.perf_counter()
            if method.segmenter is None:
                assert perception is not None
                result = perception.perceive(pair.pc1, pair.pc2, follows=index not in sequence_starts,
                                             time1=pair.time1, time2=pair.time2, measured=pair.measured)
                segmentation, obstacles, rounds = result.fusion.segmentation, result.found.moving, result.fusion.iterations
                times[method.label].append((time.perf_counter() - started) * 1e3)
            else:
                given = given or flow_of(pair)
                started = time.perf_counter()
                segmentation = method.segmenter.segment(pair.pc1, given.flow, None, given.ego).segmentation
                times[method.label].append((time.perf_counter() - started) * 1e3)
                obstacles = extract_obstacles(pair.pc1, given.flow, segmentation, given.ego, config.scan_period, 0, "sensor",
                                              config.obstacles)
                rounds = 1
            counts[method.label].append(seg_counts(segmentation, pair))
            errors[method.label].append(obstacle_errors(obstacles, segmentation, pair, config.scan_period))
            iterations[method.label].append(rounds)
        if progress is not None:
            progress(index + 1)
    return [MethodScores(m.label, seg_scores(pool(counts[m.label])), pool(errors[m.label]).summary(),
                         float(np.median(times[m.label])), len(times[m.label]), float(np.mean(iterations[m.label])))
            for m in methods]


def format_seg_table(rows: Sequence[MethodScores]) -> str:
    """Accuracy, balanced accuracy, moving IoU, instance P/R/F1/PQ, obstacle errors, time and box yaw errors per method."""
    header = (f"{'method':<22} {'acc %':>6} {'bal %':>6} {'IoU':>6} {'P':>5} {'R':>5} {'F1':>5} {'PQ':>5} "
              f"{'pos m':>6} {'vel m/s':>7} {'miss %':>6} {'ph/10':>5} {'ms':>7} {'it':>4} {'yaw °':>5} {'>30° %':>6}")
    lines = [header, "-" * len(header)]
    for row in rows:
        s, o = row.scores, row.obstacles
        lines.append(f"{row.label:<22} {100 * s.accuracy:6.2f} {100 * s.balanced_accuracy:6.2f} {s.moving_iou:6.3f} "
                     f"{s.precision:5.2f} {s.recall:5.2f} {s.f1:5.2f} {s.pq:5.2f} {o['position_m_median']:6.2f} "
                     f"{o['velocity_mps_median']:7.2f} {100 * o['missed_ratio']:6.1f} {o['phantoms_per_10_frames']:5.2f} "
                     f"{row.ms_median:7.1f} {row.iterations_mean:4.1f} {o['yaw_deg_median']:5.1f} "
                     f"{100 * o['yaw_over_30deg_ratio']:6.1f}")
    return "\n".join(lines)


class IterationScores(NamedTuple):
    """The loop's state after iteration n, pooled over frames (frames that converged earlier keep their answer)."""

    iteration: int
    epe_all: float
    epe_dynamic: float
    moving_iou: float
    accuracy: float
    converged_share: float  # frames converged by this iteration
    delta_total_median: float


def evaluate_iterations(perception: PerceptionChain, pairs: Iterable[ScanPair],
                        progress: Callable[[int], None] | None = None,
                        sequence_starts: Collection[int] = (0,)) -> tuple[list[IterationScores], list[int]]:
    """Flow EPE and segmentation IoU after every iteration of the loop (with the temporal prior of the consecutive
    pairs), and the iterations each frame took."""
    iterations = perception.config.fusion.max_iterations
    flow_scores: list[list] = [[] for _ in range(iterations)]
    seg: list[list[SegCounts]] = [[] for _ in range(iterations)]
    deltas: list[list[float]] = [[] for _ in range(iterations)]
    taken: list[int] = []
    converged_at: list[int | None] = []
    for index, pair in enumerate(pairs):
        result = perception.perceive(pair.pc1, pair.pc2, follows=index not in sequence_starts, time1=pair.time1,
                                     time2=pair.time2, measured=pair.measured).fusion
        taken.append(result.iterations)
        converged_at.append(result.iterations - 1 if result.converged else None)
        for n in range(iterations):
            step = result.steps[min(n, len(result.steps) - 1)]
            flow_scores[n].append(score_flow(step.flow, pair.flow, pair.dynamic1))
            seg[n].append(seg_counts(step.segmentation, pair))
            if n < len(result.steps):
                deltas[n].append(step.delta_total)
        if progress is not None:
            progress(index + 1)
    from ssf_eval.flow.metrics import pool_scores

    rows = []
    for n in range(iterations):
        flows, scores = pool_scores(flow_scores[n]), seg_scores(pool(seg[n]))
        share = float(np.mean([c is not None and c <= n for c in converged_at])) if converged_at else float("nan")
        finite = [d for d in deltas[n] if np.isfinite(d)]
        rows.append(IterationScores(n, flows.all.epe3d, flows.dynamic.epe3d, scores.moving_iou, scores.accuracy, share,
                                    float(np.median(finite)) if finite else float("nan")))
    return rows, taken


def format_iteration_table(rows: Sequence[IterationScores]) -> str:
    """One line per iteration."""
    header = f"{'iteration':>9} {'EPE all m':>10} {'EPE dyn m':>10} {'IoU':>6} {'acc %':>6} {'converged %':>12} {'delta':>9}"
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(f"{r.iteration:9d} {r.epe_all:10.4f} {r.epe_dynamic:10.4f} {r.moving_iou:6.3f} {100 * r.accuracy:6.2f} "
                     f"{100 * r.converged_share:12.1f} {r.delta_total_median:9.2e}")
    return "\n".join(lines)


def plot_iterations(rows: Sequence[IterationScores], path, title: str = "") -> object:
    """The paper's ablation figure: dynamic EPE and moving IoU against the iteration, and the converged share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    
    n = [r.iteration for r in rows]
    figure, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    axes[0].plot(n, [r.epe_dynamic for r in rows], "o-", color="#d62728", label="dynamic points")
    axes[0].plot(n, [r.epe_all for r in rows], "s--", color="#555555", label="all points")
    axes[0].set(xlabel="iteration", ylabel="EPE3D (m)", title="scene flow error")
    axes[0].legend()
    axes[1].plot(n, [r.moving_iou for r in rows], "o-", color="#1f77b4")
    axes[1].set(xlabel="iteration", ylabel="moving-class IoU", title="segmentation")
    axes[2].bar(n, [100 * r.converged_share for r in rows], color="#2ca02c")
    axes[2].set(xlabel="iteration", ylabel="frames converged (%)", title="convergence", ylim=(0, 100))
    for axis in axes:
        axis.set_xticks(n)
        axis.grid(alpha=0.3)
    if title:
        figure.suptitle(title)
    return save_figure(figure, path, dpi=110)
