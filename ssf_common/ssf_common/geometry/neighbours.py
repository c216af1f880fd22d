"""Nearest neighbours through KD-trees (memory linear in the points: never an N x N matrix)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree


class Neighbours(NamedTuple):
    """k nearest reference points of each query point: distances (M, k) and indices (M, k).

    Missing neighbours (beyond the radius, or fewer than k points) have distance inf and index len(reference)."""

    distance: np.ndarray
    index: np.ndarray


def knn(reference: np.ndarray, query: np.ndarray, k: int, radius: float = np.inf,
        tree: cKDTree | None = None) -> Neighbours:
    """The k nearest reference points of each query point, within `radius`."""
    k = max(1, int(k))
    tree = tree if tree is not None else cKDTree(np.asarray(reference)[:, :3])
    distance, index = tree.query(np.asarray(query)[:, :3], k=k, distance_upper_bound=radius)
    return Neighbours(distance.reshape(len(query), k), index.reshape(len(query), k))


def nearest(reference: np.ndarray, query: np.ndarray, radius: float = np.inf,
            tree: cKDTree | None = None) -> Neighbours:
    """The nearest reference point of each query point: distances (M,) and indices (M,)."""
    found = knn(reference, query, 1, radius, tree)
    return Neighbours(found.distance[:, 0], found.index[:, 0])


def radius_neighbours(reference: np.ndarray, query: np.ndarray, radius: float, max_neighbours: int = 32,
                      tree: cKDTree | None = None) -> Neighbours:
    """Up to `max_neighbours` reference points within `radius` of each query point (nearest first)."""
    return knn(reference, query, max_neighbours, radius, tree)


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
    ab = np.minimum(cKDTree(b[:, :3]).query(a[:, :3])[0], truncate)
    ba = np.minimum(cKDTree(a[:, :3]).query(b[:, :3])[0], truncate)
    return float(ab.mean() + ba.mean())
