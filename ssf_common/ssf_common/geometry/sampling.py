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


def grid_cells(points: np.ndarray, cell: float, border: int = 0) -> tuple[np.ndarray, tuple[int, ...]]:
    """The grid cell of each point (N, D) as one int64 code, row-major, the cells counted from the lowest occupied one
    with `border` empty cells around them, and the grid's shape. One contiguous row per axis: reductions along a row
    are many times faster than along axis 0 of an (N, D) array."""
    keys = [np.floor(row / cell).astype(np.int64) for row in np.ascontiguousarray(np.asarray(points).T)]
    keys = [key - (int(key.min()) - border) for key in keys]
    shape = tuple(int(key.max()) + 1 + border for key in keys)
    codes = keys[0]
    for key, size in zip(keys[1:], shape[1:]):
        codes = codes * size + key
    return codes, shape


def voxel_keys(points: np.ndarray, voxel: float, bits: int = 21, clip: bool = False) -> np.ndarray:
    """One int64 code per point (N, D) naming its voxel: each axis offset by half its 2**bits range and packed `bits`
    apart (clipped into that range when `clip`), the same code wherever the points are, from any scan."""
    keys = np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64) + (1 << (bits - 1))
    if clip:
        keys = np.clip(keys, 0, (1 << bits) - 1)
    codes = keys[:, 0]
    for axis in range(1, keys.shape[1]):
        codes = (codes << bits) | keys[:, axis]
    return codes


def voxel_indices(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the first) per occupied voxel (any number of coordinates), indices sorted."""
    points = np.asarray(points)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    rows = np.floor(np.ascontiguousarray(points.T) / voxel)  # one contiguous row per axis: reductions along a row
    lows = [float(row.min()) for row in rows]  # are 40x faster than along axis 0 of an (N, 3) array
    spans = [float(row.max()) - low + 1.0 for row, low in zip(rows, lows)]
    volume = float(np.prod(spans))
    if volume >= 2.0 ** 62:
        _, first = np.unique(np.stack([(row - low).astype(np.int64) for row, low in zip(rows, lows)], axis=1), axis=0,
                             return_index=True)
        return np.sort(first)
    dtype = np.int32 if volume < 2.0 ** 31 else np.int64  # one code per voxel, 32 bits where they fit: a faster sort
    codes = np.zeros(len(points), dtype=dtype)
    for row, low, span in zip(rows, lows, spans):
        codes = codes * dtype(span) + (row - low).astype(dtype)
    order = np.argsort(codes, kind="stable")  # stable: each voxel's run starts with its first point
    ordered = codes[order]
    starts = np.empty(len(ordered), dtype=bool)
    starts[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=starts[1:])
    return np.sort(order[starts])


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
