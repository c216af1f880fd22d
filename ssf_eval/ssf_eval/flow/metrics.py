"""Scene flow metrics: EPE3D, AS, AR, Outliers (FlowNet3D definitions, as the paper uses them) for all, static and dynamic points."""

from __future__ import annotations

from typing import Iterable, NamedTuple

import numpy as np


class FlowMetrics(NamedTuple):
    """Scene flow errors over a set of points (NaN when the set is empty)."""

    epe3d: float
    acc_strict: float
    acc_relax: float
    outliers: float
    count: int


class FlowScores(NamedTuple):
    """Metrics on all points and split into static and dynamic points."""

    all: FlowMetrics
    static: FlowMetrics
    dynamic: FlowMetrics


EMPTY = FlowMetrics(float("nan"), float("nan"), float("nan"), float("nan"), 0)


def flow_metrics(predicted: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None) -> FlowMetrics:
    """EPE3D = mean e; AS = mean[e<0.05 or r<0.05]; AR = mean[e<0.1 or r<0.1]; Outliers = mean[e>0.3 or r>0.1]."""
    predicted = np.asarray(predicted, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if predicted.shape != truth.shape or predicted.ndim != 2 or predicted.shape[1] != 3:
        raise ValueError(f"flow shapes differ or are not (N, 3): {predicted.shape} vs {truth.shape}")
    if valid is not None:
        predicted, truth = predicted[valid], truth[valid]
    if truth.shape[0] == 0:
        return EMPTY
    error = np.linalg.norm(predicted - truth, axis=1)
    relative = error / (np.linalg.norm(truth, axis=1) + 1e-4)
    return FlowMetrics(
        epe3d=float(error.mean()),
        acc_strict=float(((error < 0.05) | (relative < 0.05)).mean()),
        acc_relax=float(((error < 0.1) | (relative < 0.1)).mean()),
        outliers=float(((error > 0.3) | (relative > 0.1)).mean()),
        count=int(truth.shape[0]),
    )


def score_flow(predicted: np.ndarray, truth: np.ndarray, dynamic: np.ndarray) -> FlowScores:
    """Metrics on all points, on static points and on points of moving objects."""
    dynamic = np.asarray(dynamic, dtype=bool)
    return FlowScores(
        all=flow_metrics(predicted, truth),
        static=flow_metrics(predicted, truth, ~dynamic),
        dynamic=flow_metrics(predicted, truth, dynamic),
    )


def pool_metrics(parts: Iterable[FlowMetrics]) -> FlowMetrics:
    """Combine per-frame metrics as if computed over the union of their points."""
    parts = [part for part in parts if part.count > 0]
    total = sum(part.count for part in parts)
    if total == 0:
        return EMPTY
    return FlowMetrics(
        *(float(sum(part[i] * part.count for part in parts) / total) for i in range(4)),
        count=total,
    )


def pool_scores(frames: Iterable[FlowScores]) -> FlowScores:
    """Combine per-frame scores point-weighted, split by split."""
    frames = list(frames)
    return FlowScores(*(pool_metrics(frame[i] for frame in frames) for i in range(3)))
