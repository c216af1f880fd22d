"""Per-label reductions over points (labels are 0..count-1), vectorised with bincount."""

from __future__ import annotations

import numpy as np


def label_counts(labels: np.ndarray, count: int) -> np.ndarray:
    """Points per label (int64, length count)."""
    return np.bincount(labels, minlength=count)[:count]


def label_sums(values: np.ndarray, labels: np.ndarray, count: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Per label, the (weighted) sum of values (N,) or (N, C) -> (count,) or (count, C)."""
    values = np.asarray(values, dtype=np.float64)
    scale = None if weights is None else np.asarray(weights, dtype=np.float64)
    if values.ndim == 1:
        return np.bincount(labels, values if scale is None else values * scale, count)
    return np.stack([np.bincount(labels, values[:, i] if scale is None else values[:, i] * scale, count)
                     for i in range(values.shape[1])], axis=1)


def label_sums_of_rows(values: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Per label, the sums of K rows of values (K, N) -> (count, K) in one pass: the points grouped by a stable sort
    (cheap when the labels already come grouped) and each row summed with reduceat along its contiguous memory,
    where K bincounts would read the labels K times."""
    values = np.asarray(values, dtype=np.float64)
    sums = np.zeros((count, values.shape[0]))
    if len(labels) == 0:
        return sums
    order = np.argsort(labels, kind="stable")
    grouped = labels[order]
    starts = np.flatnonzero(np.concatenate([[True], grouped[1:] != grouped[:-1]]))
    sums[grouped[starts]] = np.add.reduceat(values[:, order], starts, axis=1).T
    return sums


def label_means(values: np.ndarray, labels: np.ndarray, count: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Per label, the (weighted) mean of values; zero for empty labels."""
    total = label_counts(labels, count).astype(np.float64) if weights is None else np.bincount(labels, weights, count)
    sums = label_sums(values, labels, count, weights)
    safe = np.where(total > 0, total, 1.0)
    return sums / (safe if sums.ndim == 1 else safe[:, None])


def label_quantiles(values: np.ndarray, labels: np.ndarray, count: int, quantile: float = 0.5) -> np.ndarray:
    """Per label, its value of rank floor(quantile x size) (the upper middle one for the median; zero for empty labels)."""
    sizes = label_counts(labels, count)
    if len(values) == 0:
        return np.zeros(count)
    order = np.lexsort((values, labels))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    rank = np.minimum((sizes * quantile).astype(np.int64), np.maximum(sizes - 1, 0))
    return np.where(sizes > 0, np.asarray(values)[order][np.minimum(starts + rank, len(values) - 1)], 0.0)


def label_spans(values: np.ndarray, labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Per label, the lowest and the highest of values (inf and -inf for empty labels)."""
    values = np.asarray(values, dtype=np.float64)  # one column as float64: ufunc.at is 30x slower on 2-D or cast values
    low, high = np.full(count, np.inf), np.full(count, -np.inf)
    np.minimum.at(low, labels, values)
    np.maximum.at(high, labels, values)
    return low, high


def label_extents(points: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Per label, the larger side (m) of its horizontal axis-aligned bounding box; zero for empty labels."""
    sides = np.zeros(count)
    for axis in (0, 1):
        low, high = label_spans(points[:, axis], labels, count)
        sides = np.maximum(sides, np.where(np.isfinite(low), high - low, 0.0))
    return sides


def label_main_axes(xy: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Per label, the unit horizontal direction along which its points spread most (the principal axis of their 2-D
    covariance; x for empty labels)."""
    centred = xy - label_means(xy, labels, count)[labels]
    xx, xy_, yy = (label_means(a * b, labels, count) for a, b in
                   ((centred[:, 0], centred[:, 0]), (centred[:, 0], centred[:, 1]), (centred[:, 1], centred[:, 1])))
    angle = 0.5 * np.arctan2(2.0 * xy_, xx - yy)
    return np.column_stack([np.cos(angle), np.sin(angle)])


def ragged_arange(lengths: np.ndarray) -> np.ndarray:
    """Concatenation of arange(n) for each n in lengths."""
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.arange(total) - offsets


def pick_per_label(labels: np.ndarray, active: np.ndarray, per_label: int, rng: np.random.Generator) -> np.ndarray:
    """Up to `per_label` random point indices from each active label (labels < 0 are never picked)."""
    candidates = np.flatnonzero((labels >= 0) & active[np.maximum(labels, 0)])
    shuffled = candidates[rng.permutation(candidates.size)]
    order = np.argsort(labels[shuffled], kind="stable")
    ordered = shuffled[order]
    sorted_labels = labels[ordered]
    rank = np.arange(ordered.size) - np.searchsorted(sorted_labels, sorted_labels, side="left")
    return ordered[rank < per_label]
