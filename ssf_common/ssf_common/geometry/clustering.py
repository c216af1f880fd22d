"""Clustering of point sets: connected components of occupied voxels (fast, exact), and DBSCAN / HDBSCAN from
scikit-learn where a density clustering is wanted. Labels are 0..count-1; -1 is noise."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

NEIGHBOUR_OFFSETS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                              if (dx, dy, dz) > (0, 0, 0)], dtype=np.int64)


class Clustering(NamedTuple):
    """A cluster label per point (-1: noise) and the number of clusters."""

    labels: np.ndarray
    count: int


def voxel_components(points: np.ndarray, voxel: float) -> Clustering:
    """Connected components of the occupied voxels (26-connected): points in touching voxels share a label."""
    if points.shape[0] == 0:
        return Clustering(np.full(0, -1), 0)
    keys = np.floor(points[:, :3] / voxel).astype(np.int64)
    keys -= keys.min(axis=0) - 1
    span = keys.max(axis=0) + 2
    codes = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    voxels, inverse = np.unique(codes, return_inverse=True)
    strides = np.array([span[1] * span[2], span[2], 1], dtype=np.int64)
    rows, cols = [], []
    for offset in NEIGHBOUR_OFFSETS @ strides:
        position = np.minimum(np.searchsorted(voxels, voxels + offset), voxels.size - 1)
        found = voxels[position] == voxels + offset
        rows.append(np.flatnonzero(found))
        cols.append(position[found])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(voxels.size, voxels.size))
    count, component = connected_components(graph, directed=False)
    return Clustering(component[inverse.reshape(-1)], int(count))


def dbscan(features: np.ndarray, eps: float, min_samples: int = 5) -> Clustering:
    """DBSCAN (scikit-learn, KD-tree neighbours) on any feature vectors (N, D)."""
    from sklearn.cluster import DBSCAN

    if len(features) == 0:
        return Clustering(np.full(0, -1), 0)
    labels = DBSCAN(eps=eps, min_samples=min_samples, algorithm="kd_tree").fit_predict(features)
    return Clustering(labels.astype(np.int64), int(labels.max() + 1))


def hdbscan(features: np.ndarray, min_cluster_size: int = 10, min_samples: int | None = None) -> Clustering:
    """HDBSCAN (scikit-learn) on any feature vectors (N, D)."""
    from sklearn.cluster import HDBSCAN

    if len(features) < 2:
        return Clustering(np.full(len(features), -1), 0)
    labels = HDBSCAN(min_cluster_size=min_cluster_size, min_samples=min_samples, copy=True).fit_predict(features)
    return Clustering(labels.astype(np.int64), int(labels.max() + 1))


def relabel_by_size(labels: np.ndarray) -> Clustering:
    """Renumber labels 0..count-1 from the largest cluster down (-1 stays -1)."""
    valid = labels >= 0
    if not valid.any():
        return Clustering(np.full(labels.shape, -1), 0)
    unique, inverse, sizes = np.unique(labels[valid], return_inverse=True, return_counts=True)
    rank = np.empty(unique.size, dtype=np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(unique.size)
    out = np.full(labels.shape, -1, dtype=np.int64)
    out[valid] = rank[inverse]
    return Clustering(out, int(unique.size))
