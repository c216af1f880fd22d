"""Clustering of point sets: connected components of occupied voxels (fast, exact) or of points within the scan's
measured point spacing, clusters that neighbour each other in the sensor's view, and DBSCAN (scikit-learn's labels
from one KD-tree pair search) / HDBSCAN (scikit-learn) where a density clustering is wanted. Labels are 0..count-1; -1 is noise."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ssf_common.geometry.neighbours import PointIndex
from ssf_common.geometry.reductions import vector_lengths
from ssf_common.geometry.sampling import grid_cells

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
    codes, span = grid_cells(points[:, :3], voxel, border=1)
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


def spacing_components(points: np.ndarray, cell: float, reach: float, min_link: float, max_link: float,
                       sample: int = 2048, seed: int = 0, spacing: float | None = None) -> Clustering:
    """Connected components of points (sensor frame) linked where they lie closer than `reach` times the scan's point
    spacing at their range, kept within [min_link, max_link] (m): objects a short gap apart stay apart where the scan is
    dense (near the sensor), and sparsely sampled ones hold together (far away). The spacing grows with the range at the
    sensor's angular resolution, measured on the points themselves (the median over up to `sample` of them of the
    distance to the fourth nearest point, per metre of range; `spacing`: already measured so); links are made between
    one point per `cell` voxel."""
    if points.shape[0] == 0:
        return Clustering(np.full(0, -1), 0)
    xyz = np.asarray(points[:, :3], np.float64)
    spacing = angular_spacing(xyz, sample, seed) if spacing is None else spacing
    link = np.clip(reach * spacing * vector_lengths(xyz), min_link, max_link)
    _, first, inverse = np.unique(grid_cells(xyz, cell)[0], return_index=True, return_inverse=True)
    cells, reach_of = xyz[first], link[first]
    # each point links the points within its own link length: a pair is linked when it is within the longer of
    # the two (one KD-tree pair search at the longest, then the pairs beyond both lengths dropped)
    pairs = cKDTree(cells).query_pairs(float(reach_of.max()), output_type="ndarray")
    gaps = vector_lengths(cells[pairs[:, 0]] - cells[pairs[:, 1]])
    linked = pairs[gaps <= np.maximum(reach_of[pairs[:, 0]], reach_of[pairs[:, 1]])]
    graph = coo_matrix((np.ones(len(linked), dtype=np.int8), (linked[:, 0], linked[:, 1])),
                       shape=(cells.shape[0], cells.shape[0]))
    count, component = connected_components(graph, directed=False)
    return Clustering(component[inverse.reshape(-1)], int(count))


def angular_spacing(points: np.ndarray, sample: int = 2048, seed: int = 0, neighbours: int = 4) -> float:
    """Typical distance between neighbouring points of a scan per metre of range (rad): the median over up to `sample`
    points of the distance to their `neighbours`-th nearest point divided by their range (0 for under two points)."""
    if points.shape[0] <= neighbours:
        return 0.0
    pick = np.random.default_rng(seed).choice(points.shape[0], min(sample, points.shape[0]), replace=False)
    gaps = PointIndex(points).query(points[pick], k=neighbours + 1)[0][:, -1]
    return float(np.median(gaps / np.maximum(vector_lengths(points[pick]), 1e-6)))


def angular_neighbours(points: np.ndarray, labels: np.ndarray, angle: float, cell: float) -> np.ndarray:
    """(M, 2) pairs a < b of labels (>= 0) with points (sensor frame) within `angle` (rad) of each other as the sensor
    sees them, at any ranges: neighbours in the scan, one point per `cell` voxel looked at."""
    valid = np.flatnonzero(np.asarray(labels) >= 0)
    if valid.size == 0:
        return np.zeros((0, 2), np.int64)
    xyz = np.asarray(points[valid, :3], np.float64)
    _, first = np.unique(grid_cells(xyz, cell)[0], return_index=True)
    directions = xyz[first] / np.maximum(vector_lengths(xyz[first])[:, None], 1e-6)
    near = cKDTree(directions).query_pairs(2.0 * np.sin(angle / 2.0), output_type="ndarray")
    pairs = np.sort(np.asarray(labels)[valid[first]][near], axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def dbscan(features: np.ndarray, eps: float, min_samples: int = 5) -> Clustering:
    """DBSCAN on any feature vectors (N, D), with the labels scikit-learn's gives: core points (at least min_samples
    within eps, themselves included) linked within eps form clusters, numbered in the order of their first core point;
    a border point joins the earliest of the clusters whose core points lie within eps of it; the rest is noise. From
    one KD-tree pair search (scikit-learn builds a list of neighbours per point: 3x slower here)."""
    count = len(features)
    labels = np.full(count, -1, np.int64)
    if count == 0:
        return Clustering(labels, 0)
    pairs = cKDTree(np.asarray(features, np.float64)).query_pairs(eps, output_type="ndarray")
    core = np.bincount(pairs.ravel(), minlength=count) + 1 >= min_samples
    cores = np.flatnonzero(core)
    if cores.size == 0:
        return Clustering(labels, 0)
    linked = pairs[core[pairs[:, 0]] & core[pairs[:, 1]]]
    graph = coo_matrix((np.ones(len(linked), np.int8), (linked[:, 0], linked[:, 1])), shape=(count, count))
    component = connected_components(graph, directed=False)[1]
    roots, first = np.unique(component[cores], return_index=True)  # first: each cluster's first core point
    rank = np.empty(component.max() + 1, np.int64)
    rank[roots[np.argsort(cores[first], kind="stable")]] = np.arange(roots.size)
    labels[cores] = rank[component[cores]]
    edges = pairs[core[pairs[:, 0]] != core[pairs[:, 1]]]  # a core point and a border point
    border_first = ~core[edges[:, 0]]
    border = np.where(border_first, edges[:, 0], edges[:, 1])
    owner = labels[np.where(border_first, edges[:, 1], edges[:, 0])]
    earliest = np.full(count, roots.size, np.int64)
    np.minimum.at(earliest, border, owner)
    claimed = earliest < roots.size
    labels[claimed] = earliest[claimed]
    return Clustering(labels, int(roots.size))


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
