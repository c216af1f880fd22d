"""The paper's scene flow table on labelled pairs: every estimator on the same pairs, with the same masks."""

from __future__ import annotations

import time
from enum import Enum
from typing import Iterable, NamedTuple, Sequence

import numpy as np

from ssf_common.dataset.masks import noisy_mask
from ssf_common.dataset.pairs import ScanPair
from ssf_eval.flow.metrics import FlowScores, pool_scores, score_flow
from ssf_flow_node.core.base import FlowEstimator, FlowResult


class MaskSource(str, Enum):
    """Where the motion mask given to the estimators comes from."""

    NONE = "none"
    NOISY = "noisy"  # ground truth with 10 % of moving objects dropped and 3 % of points flipped
    TRUTH = "gt"


class EstimatorScores(NamedTuple):
    """Pooled scores of one estimator over all evaluated pairs, and its median time per pair."""

    name: str
    scores: FlowScores
    ms_median: float
    frames: int


def mask_for(pair: ScanPair, source: MaskSource, rng: np.random.Generator) -> np.ndarray | None:
    """The mask that every estimator gets for this pair."""
    if source is MaskSource.NONE:
        return None
    if source is MaskSource.TRUTH:
        return pair.dynamic1.astype(np.float32)
    return noisy_mask(pair, rng)


class FlowEvaluation(NamedTuple):
    """Scores of every estimator, and what each estimated on the last pair (for the picture)."""

    results: list[EstimatorScores]
    last_pair: ScanPair | None
    last_flows: dict[str, FlowResult]


def evaluate_flow(estimators: Sequence[FlowEstimator], pairs: Iterable[ScanPair], source: MaskSource,
                  seed: int = 0, progress=None) -> FlowEvaluation:
    """Run every estimator on every pair; scores pooled over points, split into all/static/dynamic."""
    rng = np.random.default_rng(seed)
    frames: list[list[FlowScores]] = [[] for _ in estimators]
    times: list[list[float]] = [[] for _ in estimators]
    last_pair, last_flows = None, {}
    for index, pair in enumerate(pairs):
        mask = mask_for(pair, source, rng)
        last_pair, last_flows = pair, {}
        for slot, estimator in enumerate(estimators):
            started = time.perf_counter()
            result = estimator.estimate(pair.pc1, pair.pc2, mask)
            times[slot].append((time.perf_counter() - started) * 1e3)
            frames[slot].append(score_flow(result.flow, pair.flow, pair.dynamic1))
            last_flows[estimator.name] = result
        if progress is not None:
            progress(index + 1)
    results = [EstimatorScores(estimator.name, pool_scores(scores), float(np.median(spent)) if spent else float("nan"),
                               len(scores)) for estimator, scores, spent in zip(estimators, frames, times)]
    return FlowEvaluation(results, last_pair, last_flows)


def format_flow_table(results: Sequence[EstimatorScores]) -> str:
    """A text table: EPE3D (m), AS %, AR %, Outliers % for all / static / dynamic points."""
    header = f"{'estimator':<14} {'split':<8} {'EPE3D m':>8} {'AS %':>7} {'AR %':>7} {'Out %':>7} {'points':>9} {'ms':>7}"
    lines = [header, "-" * len(header)]
    for result in results:
        for split in ("all", "static", "dynamic"):
            m = getattr(result.scores, split)
            ms = f"{result.ms_median:7.1f}" if split == "all" else ""
            lines.append(f"{result.name if split == 'all' else '':<14} {split:<8} {m.epe3d:8.4f} {100 * m.acc_strict:7.2f} "
                         f"{100 * m.acc_relax:7.2f} {100 * m.outliers:7.2f} {m.count:9d} {ms:>7}")
    return "\n".join(lines)
