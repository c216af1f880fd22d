"""Nearest neighbours through KD-trees (memory linear in the points: never an N x N matrix)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import small_gicp

from ssf_common.geometry.reductions import column_bounds


class PointIndex:
    """A KD-tree over 3-D points, queried as scipy's cKDTree is (distance inf and index n where no point lies closer
    than the bound), built and searched by small_gicp's compiled tree: about twice as fast as cKDTree at both."""

    def __init__(self, points: np.ndarray) -> None:
        self.data = np.ascontiguousarray(np.asarray(points)[:, :3], dtype=np.float64)
        self.n = len(self.data)
        self._tree = small_gicp.KdTree(self.data) if self.n else None  # small_gicp cannot hold an empty cloud

    def query(self, points: np.ndarray, k: int = 1,
              distance_upper_bound: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the k nearest points (nearest first) closer than distance_upper_bound; shapes (M,)
        for k = 1, else (M, k)."""
        points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        reach = min(int(k), self.n)
        distance = np.full((len(points), int(k)), np.inf)
        index = np.full((len(points), int(k)), self.n, dtype=np.int64)
        if reach > 0 and len(points):
            found, squared = self._tree.batch_knn_search(points, reach)
            found = np.asarray(found).astype(np.int64).reshape(len(points), reach)  # a missing one: 2^64 - 1 wraps to -1
            gap = np.sqrt(np.asarray(squared).reshape(len(points), reach))
            within = (found >= 0) & (gap < distance_upper_bound)
            distance[:, :reach] = np.where(within, gap, np.inf)
            index[:, :reach] = np.where(within, found, self.n)
        return (distance[:, 0], index[:, 0]) if k == 1 else (distance, index)


class Neighbours(NamedTuple):
    """k nearest reference points of each query point: distances (M, k) and indices (M, k).

    Missing neighbours (beyond the radius, or fewer than k points) have distance inf and index len(reference)."""

    distance: np.ndarray
    index: np.ndarray


def knn(reference: np.ndarray, query: np.ndarray, k: int, radius: float = np.inf,
        tree: PointIndex | None = None) -> Neighbours:
    """The k nearest reference points of each query point, within `radius`."""
    k = max(1, int(k))
    tree = tree if tree is not None else PointIndex(reference)
    distance, index = tree.query(np.asarray(query)[:, :3], k=k, distance_upper_bound=radius)
    return Neighbours(distance.reshape(len(query), k), index.reshape(len(query), k))


def nearest(reference: np.ndarray, query: np.ndarray, radius: float = np.inf,
            tree: PointIndex | None = None) -> Neighbours:
    """The nearest reference point of each query point: distances (M,) and indices (M,)."""
    found = knn(reference, query, 1, radius, tree)
    return Neighbours(found.distance[:, 0], found.index[:, 0])


def radius_neighbours(reference: np.ndarray, query: np.ndarray, radius: float, max_neighbours: int = 32,
                      tree: PointIndex | None = None) -> Neighbours:
    """Up to `max_neighbours` reference points within `radius` of each query point (nearest first)."""
    return knn(reference, query, max_neighbours, radius, tree)


MAX_GRID_CELLS = 1 << 24  # a prefilter grid larger than this (16 MB) is not worth building


def may_be_near(reference: np.ndarray, query: np.ndarray, reach: float) -> np.ndarray:
    """Which query points may have a reference point within `reach`: every one that does, and some that do not (a
    horizontal grid of cell `reach` around the reference points). A KD-tree query costs the same per point near or
    far, so filtering the many far points first makes a query of a whole scan against a few objects cheap."""
    query, reference = np.asarray(query), np.asarray(reference)
    if len(reference) == 0 or len(query) == 0:
        return np.zeros(len(query), bool)
    if not np.isfinite(reach) or reach <= 0:
        return np.ones(len(query), bool)
    low, high = column_bounds(reference[:, :2])
    low = low - reach
    shape = np.floor((high + reach - low) / reach).astype(np.int64) + 1
    if shape[0] * shape[1] > MAX_GRID_CELLS:
        return np.ones(len(query), bool)
    occupied = np.zeros(shape + 2, bool)  # a border of empty cells: the neighbours of every cell exist
    cell = np.floor((reference[:, :2] - low) / reach).astype(np.int64) + 1
    occupied[cell[:, 0], cell[:, 1]] = True
    grown = occupied.copy()
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            grown[1:-1, 1:-1] |= occupied[1 + dx: shape[0] + 1 + dx, 1 + dy: shape[1] + 1 + dy]
    # cells outside the grid fall on its empty border
    column = np.clip(np.floor((query[:, 0] - low[0]) / reach).astype(np.int64) + 1, 0, shape[0] + 1)
    row = np.clip(np.floor((query[:, 1] - low[1]) / reach).astype(np.int64) + 1, 0, shape[1] + 1)
    return grown.ravel()[column * (shape[1] + 2) + row]


def propagate(source: np.ndarray, values: np.ndarray, targets: np.ndarray, k: int = 3,
              radius: float = np.inf) -> np.ndarray:
    """Carry per-point values from source points to target points by inverse-distance kNN (KD-tree); targets
    with no source within `radius` get zeros."""
    k = min(k, source.shape[0])
    distance, index = knn(source, targets, k, radius)
    found = np.isfinite(distance)
    weight = np.where(found, 1.0 / np.maximum(distance, 1e-6), 0.0)
    weight /= np.maximum(weight.sum(axis=1, keepdims=True), 1e-12)
    padded = np.concatenate([values, np.zeros((1, values.shape[1]), values.dtype)])  # index == len(source): none
    return np.einsum("nk,nkc->nc", weight, padded[index]).astype(np.float32)


def chamfer_distance(a: np.ndarray, b: np.ndarray, truncate: float = np.inf) -> float:
    """Symmetric Chamfer distance: mean nearest distance a -> b plus b -> a (each capped at `truncate`)."""
    ab = np.minimum(PointIndex(b).query(a[:, :3])[0], truncate)
    ba = np.minimum(PointIndex(a).query(b[:, :3])[0], truncate)
    return float(ab.mean() + ba.mean())
