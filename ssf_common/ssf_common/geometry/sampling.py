"""Reducing a point set to N points: one vocabulary (random / voxel / farthest-point) and the index samplers."""

from __future__ import annotations

from enum import Enum

import numpy as np
from scipy.spatial import cKDTree


class Sampling(str, Enum):
    """How a scan is reduced to N points."""

    RANDOM = "random"
    VOXEL = "voxel"  # one point per occupied voxel, then random down to N
    FPS = "fps"  # farthest-point sampling


def farthest_point_indices(points: np.ndarray, count: int, start: int = 0) -> np.ndarray:
    """Indices (sorted) of `count` points chosen greedily farthest from those already chosen, from `start`.

    Open3D's C++ sampler picks the points; a KD-tree maps them back to indices."""
    import open3d as o3d

    if count >= len(points):
        return np.arange(len(points), dtype=np.int64)
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    try:
        chosen = np.asarray(cloud.farthest_point_down_sample(int(count), start_index=int(start)).points)
    except TypeError:  # an Open3D without start_index
        return np.sort(greedy_farthest_indices(xyz, count, start))
    _, index = cKDTree(xyz).query(chosen, k=1)
    index = np.unique(index.astype(np.int64))
    if index.size == count:
        return index
    return np.sort(greedy_farthest_indices(xyz, count, start))  # duplicate points: pick by index, not by position


def greedy_farthest_indices(points: np.ndarray, count: int, start: int = 0) -> np.ndarray:
    """Farthest point sampling in numpy, indices in the order chosen; O(N * count)."""
    chosen = np.empty(count, dtype=np.int64)
    distance = np.full(points.shape[0], np.inf)
    current = start
    for i in range(count):
        chosen[i] = current
        distance = np.minimum(distance, ((points - points[current]) ** 2).sum(axis=1))
        distance[chosen[: i + 1]] = -1.0
        current = int(distance.argmax())
    return chosen


def voxel_indices(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the first) per occupied voxel (any number of coordinates), indices sorted."""
    points = np.asarray(points)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    columns = [np.floor(points[:, axis] / voxel).astype(np.int64) for axis in range(points.shape[1])]  # 2x faster
    columns = [column - column.min() for column in columns]
    spans = [int(column.max()) + 1 for column in columns]
    if float(np.prod(np.array(spans, dtype=np.float64))) < 2.0 ** 62:  # one int64 code per voxel: a 1-D unique
        codes = np.zeros(len(points), dtype=np.int64)
        for column, span in zip(columns, spans):
            codes = codes * span + column
        _, first = np.unique(codes, return_index=True)
    else:
        _, first = np.unique(np.stack(columns, axis=1), axis=0, return_index=True)
    return np.sort(first)


def sample_indices(points: np.ndarray, count: int, rng: np.random.Generator, sampling: Sampling = Sampling.RANDOM,
                   voxel: float = 0.1, pad: bool = False) -> np.ndarray:
    """Indices of at most `count` points (sorted), or exactly `count` with `pad` (repeats when there are too few)."""
    sampling = Sampling(sampling)
    candidates = np.arange(len(points))
    if sampling is Sampling.VOXEL:
        candidates = voxel_indices(points, voxel)
    if candidates.size > count:
        if sampling is Sampling.FPS:
            pick = farthest_point_indices(points[candidates], count, int(rng.integers(candidates.size)))
        else:
            pick = rng.choice(candidates.size, count, replace=False)
        candidates = np.sort(candidates[pick])
    if pad and 0 < candidates.size < count:
        extra = rng.choice(candidates, count - candidates.size, replace=True)
        candidates = np.concatenate([rng.permutation(candidates), extra])
    return candidates.astype(np.int64)
