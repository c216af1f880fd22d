"""Pre-processing shared by every estimator: range crop, downsampling to N points, ground split, flow propagation."""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from ssf_common.config import Section
from ssf_common.errors import DataError


class Sampling(str, Enum):
    """How a scan is reduced to N points."""

    RANDOM = "random"
    VOXEL = "voxel"
    FPS = "fps"


class PreprocessConfig(Section):
    """Range crop and downsampling applied to both scans before estimation."""

    points: int = Field(8192, ge=64, description="points kept per scan")
    sampling: Sampling = Sampling.RANDOM
    voxel_size: float = Field(0.1, gt=0.0, description="voxel edge (m) for voxel sampling")
    min_range: float = Field(0.0, ge=0.0, description="points closer to the sensor are dropped (m)")
    max_range: float = Field(60.0, gt=0.0, description="points farther from the sensor are dropped (m)")
    remove_ground: bool = Field(False, description="spend the N points on non-ground structure only")
    ground_cell: float = Field(2.0, gt=0.0, description="grid cell (m) of the ground height estimate")
    ground_height: float = Field(0.3, gt=0.0, description="points this far above the local ground are not ground (m)")
    propagate_k: int = Field(3, ge=1, le=32, description="neighbours for inverse-distance flow propagation")
    propagate_radius: float = Field(1.0, gt=0.0, description="object motion reaches points left out of the sample "
                                    "within this distance (m); farther ones move with the ego motion")
    seed: int = 0


class Sample(NamedTuple):
    """Points chosen from a scan: indices into the scan and their coordinates."""

    indices: np.ndarray  # (M,) int64
    points: np.ndarray  # (M, 3) float32


def check_scan(points: np.ndarray, name: str) -> np.ndarray:
    """Validate a scan (N, C>=3) and return its xyz as contiguous float32."""
    array = np.asarray(points)
    if array.ndim != 2 or array.shape[1] < 3:
        raise DataError(f"{name}: expected an (N, 3+) array of points, got shape {array.shape}")
    if array.shape[0] == 0:
        raise DataError(f"{name}: scan is empty")
    xyz = np.ascontiguousarray(array[:, :3], dtype=np.float32)
    if not np.isfinite(xyz).all():
        raise DataError(f"{name}: {int((~np.isfinite(xyz).all(axis=1)).sum())} points have NaN/Inf coordinates")
    return xyz


def check_mask(mask: np.ndarray | None, count: int) -> np.ndarray | None:
    """Validate a per-point motion mask (dynamic probability in [0, 1]) for a scan of `count` points."""
    if mask is None:
        return None
    values = np.asarray(mask)
    if values.ndim == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.shape != (count,):
        raise DataError(f"mask: expected {count} values (one per point of scan t), got shape {values.shape}")
    values = values.astype(np.float32)
    if not np.isfinite(values).all() or values.min() < 0.0 or values.max() > 1.0:
        raise DataError("mask: values must be dynamic probabilities in [0, 1]")
    return values


def ground_mask(points: np.ndarray, cell: float = 2.0, height: float = 0.3) -> np.ndarray:
    """Flag points within `height` of the local ground."""
    return height_above_ground(points, cell) < height


DENSE_GRID_CELLS = 1 << 22  # beyond this many grid cells (scattered outliers) the sparse path is used


def height_above_ground(points: np.ndarray, cell: float = 2.0) -> np.ndarray:
    """Height of each point above the lowest point of its grid cell (or its 8 neighbours, slope-tolerant)."""
    keys = np.floor(points[:, :2] / cell).astype(np.int64)
    keys -= keys.min(axis=0) - 1  # a border of empty cells around the scan
    rows, cols = (int(n) + 2 for n in keys.max(axis=0))
    if rows * cols > DENSE_GRID_CELLS:
        return sparse_height_above_ground(points, keys, cols, cell)
    cells = keys[:, 0] * cols + keys[:, 1]
    lowest = np.full(rows * cols, np.inf)
    np.minimum.at(lowest, cells, points[:, 2])
    grid = lowest.reshape(rows, cols)
    neighbour_lowest = np.full_like(grid, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                np.minimum(neighbour_lowest[1:-1, 1:-1], grid[1 + dx:rows - 1 + dx, 1 + dy:cols - 1 + dy],
                           out=neighbour_lowest[1:-1, 1:-1])
    floor = np.minimum(grid, neighbour_lowest + 0.15 * cell).ravel()  # a cell without visible ground borrows its neighbours'
    return points[:, 2] - floor[cells]


def sparse_height_above_ground(points: np.ndarray, keys: np.ndarray, cols: int, cell: float) -> np.ndarray:
    """height_above_ground over the occupied cells only, for scans spread over a huge area."""
    cells = keys[:, 0] * cols + keys[:, 1]
    unique, inverse = np.unique(cells, return_inverse=True)
    lowest = np.full(unique.shape[0], np.inf, dtype=np.float64)
    np.minimum.at(lowest, inverse, points[:, 2])
    neighbour_lowest = np.full_like(lowest, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                shifted = np.minimum(np.searchsorted(unique, unique + dx * cols + dy), unique.shape[0] - 1)
                found = unique[shifted] == unique + dx * cols + dy
                neighbour_lowest[found] = np.minimum(neighbour_lowest[found], lowest[shifted[found]])
    floor = np.minimum(lowest, neighbour_lowest + 0.15 * cell)
    return points[:, 2] - floor[inverse]


def crop(points: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """Indices of the points inside the configured range annulus."""
    distance = np.linalg.norm(points[:, :2], axis=1)
    return np.flatnonzero((distance >= config.min_range) & (distance <= config.max_range))


def farthest_point_indices(points: np.ndarray, count: int, start: int = 0) -> np.ndarray:
    """Farthest point sampling (greedy); O(N * count)."""
    chosen = np.empty(count, dtype=np.int64)
    distance = np.full(points.shape[0], np.inf, dtype=np.float32)
    current = start
    for i in range(count):
        chosen[i] = current
        distance = np.minimum(distance, ((points - points[current]) ** 2).sum(axis=1))
        current = int(distance.argmax())
    return chosen


def voxel_indices(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the first) per occupied voxel."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(first)


def downsample(points: np.ndarray, config: PreprocessConfig, rng: np.random.Generator) -> Sample:
    """Crop and reduce a scan to at most `config.points` points, remembering where each came from."""
    candidates = crop(points, config)
    if config.remove_ground and candidates.size:
        candidates = candidates[~ground_mask(points[candidates], config.ground_cell, config.ground_height)]
    if candidates.size == 0:
        raise DataError(f"scan has no points between {config.min_range} m and {config.max_range} m")
    if config.sampling is Sampling.VOXEL:
        candidates = candidates[voxel_indices(points[candidates], config.voxel_size)]
    if candidates.size > config.points:
        if config.sampling is Sampling.FPS:
            pick = farthest_point_indices(points[candidates], config.points, int(rng.integers(candidates.size)))
        else:
            pick = rng.choice(candidates.size, config.points, replace=False)
        candidates = np.sort(candidates[pick])
    return Sample(candidates.astype(np.int64), points[candidates])


def propagate(source: np.ndarray, values: np.ndarray, targets: np.ndarray, k: int = 3,
              radius: float = np.inf) -> np.ndarray:
    """Carry per-point values from source points to target points by inverse-distance kNN (KD-tree); targets
    with no source within `radius` get zeros."""
    k = min(k, source.shape[0])
    distance, index = cKDTree(source).query(targets, k=k, distance_upper_bound=radius)
    distance, index = distance.reshape(len(targets), k), index.reshape(len(targets), k)
    found = np.isfinite(distance)
    weight = np.where(found, 1.0 / np.maximum(distance, 1e-6), 0.0)
    weight /= np.maximum(weight.sum(axis=1, keepdims=True), 1e-12)
    padded = np.concatenate([values, np.zeros((1, values.shape[1]), values.dtype)])  # index == len(source): none
    return np.einsum("nk,nkc->nc", weight, padded[index]).astype(np.float32)


def propagate_motion(points: np.ndarray, sample: Sample, relative: np.ndarray, k: int = 3,
                     radius: float = np.inf) -> np.ndarray:
    """Motion relative to the scene for every point of a scan: exact on sampled points, interpolated on the
    others near sampled points that move, zero elsewhere."""
    motion = np.zeros((points.shape[0], 3), dtype=np.float32)
    motion[sample.indices] = relative
    moving = np.abs(relative).max(axis=1) > 0.0
    if not moving.any() or sample.indices.size == points.shape[0]:
        return motion
    rest = np.ones(points.shape[0], dtype=bool)
    rest[sample.indices] = False
    rest = np.flatnonzero(rest)
    gap, _ = cKDTree(sample.points[moving]).query(points[rest], distance_upper_bound=radius)
    near = rest[np.isfinite(gap)]  # only these can pick up any motion
    if near.size:
        motion[near] = propagate(sample.points, relative, points[near], k, radius)
    return motion
