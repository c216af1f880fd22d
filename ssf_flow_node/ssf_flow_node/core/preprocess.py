"""Pre-processing shared by every estimator: range crop, downsampling to N points, ground split, flow propagation."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import DataError
from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.neighbours import PointIndex, may_be_near, propagate
from ssf_common.geometry.reductions import vector_lengths
from ssf_common.geometry.sampling import Sampling, sample_indices


class PreprocessConfig(Section):
    """Range crop and downsampling applied to both scans before estimation."""

    points: int = Field(8192, ge=64, description="points kept per scan (at least, with points_share)")
    points_share: float = Field(0.0, ge=0.0, le=1.0, description="dense scans keep this share of their candidate points "
                                "(cropped, ground removed; those above object_height count, though the budget goes to "
                                "the points below) when that is more than `points`: the budget follows the sensor's "
                                "density instead of one sensor's (0: always `points`)")
    sampling: Sampling = Sampling.RANDOM
    voxel_size: float = Field(0.1, gt=0.0, description="voxel edge (m) for voxel sampling")
    min_range: float = Field(0.0, ge=0.0, description="points closer to the sensor are dropped (m)")
    max_range: float = Field(60.0, gt=0.0, description="points farther from the sensor are dropped (m)")
    remove_ground: bool = Field(False, description="spend the N points on non-ground structure only")
    ego_ground_points: int = Field(2048, ge=0, description="where the ground is removed, this many ground points still "
                                   "join the ego registration (the ground pins height, roll and pitch)")
    object_height: float = Field(0.0, ge=0.0, description="where the ground is removed, points higher above it than this "
                                 "(m) are structure no road user reaches (the tallest trucks and buses stand ~4.2 m): they "
                                 "move with the ego and leave their share of the point budget to the band where things "
                                 "move (a sensor that looks up, e.g. a 45-degree OS1-128, sees mostly facades; 0: keep "
                                 "them)")
    ego_structure_points: int = Field(2048, ge=0, description="of the points above object_height, this many still join "
                                      "the ego registration (far facades pin the heading)")
    range_balance: bool = Field(False, description="sample with a weight growing with the squared range, so that far "
                                "objects keep their few points and near surfaces are thinned (whole scans)")
    ground_cell: float = Field(2.0, gt=0.0, description="grid cell (m) of the ground height estimate")
    ground_height: float = Field(0.3, gt=0.0, description="points this far above the local ground are not ground (m)")
    ground_zones: bool = Field(False, description="where the ground is removed, a cell without a ground return (under "
                               "a car, beyond a sparse sensor's last ground ring) takes the ground fitted along its "
                               "range and azimuth zone where that is lower, so an object's lowest ring is not taken "
                               "for the ground (the scan must be in its sensor's frame; off by default: no held-out "
                               "gain on vlp16, README)")
    propagate_k: int = Field(3, ge=1, le=32, description="neighbours for inverse-distance flow propagation")
    propagate_radius: float = Field(1.0, gt=0.0, description="object motion reaches points left out of the sample "
                                    "within this distance (m); farther ones move with the ego motion")
    seed: int = 0


class Sample(NamedTuple):
    """Points chosen from a scan: indices into the scan and their coordinates (and, where the ground was removed, a
    few ground points for the ego registration)."""

    indices: np.ndarray  # (M,) int64
    points: np.ndarray  # (M, 3) float32
    ground: np.ndarray | None = None  # (G,) int64 indices of ground points (and of structure above object_height)


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


def crop(points: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """Indices of the points inside the configured range annulus."""
    distance = vector_lengths(points[:, :2])
    return np.flatnonzero((distance >= config.min_range) & (distance <= config.max_range))


def downsample(points: np.ndarray, config: PreprocessConfig, rng: np.random.Generator,
               height: np.ndarray | None = None) -> Sample:
    """Crop and reduce a scan to its point budget, remembering where each came from (`height`: each point's height
    above the ground of the whole scan, when already known)."""
    candidates = crop(points, config)
    ground = None
    budget = None
    if config.remove_ground and candidates.size:
        above = (height_above_ground(points[candidates], config.ground_cell, config.ground_zones)
                 if height is None else height[candidates])
        flat = above < config.ground_height
        ground = candidates[flat]
        ground = ground[rng.permutation(ground.size)[: config.ego_ground_points]]
        high = above >= object_top(config)
        if config.object_height > 0 and (~flat & ~high).any():  # structure above every road user: a few points for
            budget = point_budget(np.count_nonzero(~flat), config)  # the ego; its share of the budget goes to the band
            lifted = candidates[high]
            ground = np.concatenate([ground, lifted[rng.permutation(lifted.size)[: config.ego_structure_points]]])
            flat |= high
        candidates = candidates[~flat]
    if candidates.size == 0:
        raise DataError(f"scan has no points between {config.min_range} m and {config.max_range} m")
    budget = point_budget(candidates.size, config) if budget is None else budget
    if config.range_balance and candidates.size > budget:
        candidates = np.sort(candidates[range_balanced(points[candidates], budget, rng)])
    candidates = candidates[sample_indices(points[candidates], budget, rng, config.sampling, config.voxel_size)]
    return Sample(candidates.astype(np.int64), points[candidates], None if ground is None else np.sort(ground))


def object_top(config: PreprocessConfig) -> float:
    """Height above the ground (m) from which points are structure no road user reaches (inf where object_height is 0)."""
    return max(config.object_height, config.ground_height) if config.object_height > 0 else np.inf


def point_budget(candidates: int, config: PreprocessConfig) -> int:
    """Points to keep of a scan with this many candidates: `points`, or `points_share` of them when that is more."""
    return max(config.points, int(config.points_share * candidates))


def range_balanced(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` indices drawn without replacement with weights growing with the squared horizontal range (a LiDAR's
    point density falls with it), by exponential keys (Efraimidis-Spirakis)."""
    weight = np.maximum(np.einsum("ij,ij->i", points[:, :2], points[:, :2]), 1e-6)
    keys = rng.exponential(size=len(points)) / weight
    return np.argpartition(keys, count - 1)[:count]


def propagate_motion(points: np.ndarray, sample: Sample, relative: np.ndarray, k: int = 3,
                     radius: float = np.inf, still: np.ndarray | None = None) -> np.ndarray:
    """Motion relative to the scene for every point of a scan: exact on sampled points, interpolated on the
    others near sampled points that move (unless `still`), zero elsewhere."""
    motion = np.zeros((points.shape[0], 3), dtype=np.float32)
    motion[sample.indices] = relative
    moving = np.abs(relative).max(axis=1) > 0.0
    if not moving.any() or sample.indices.size == points.shape[0]:
        return motion
    rest = np.ones(points.shape[0], dtype=bool) if still is None else ~np.asarray(still, bool)
    rest[sample.indices] = False
    rest = np.flatnonzero(rest)
    rest = rest[may_be_near(sample.points[moving], points[rest], radius)]
    gap, _ = PointIndex(sample.points[moving]).query(points[rest], distance_upper_bound=radius)
    near = rest[np.isfinite(gap)]  # only these can pick up any motion
    if near.size:  # from the sampled points that may lie within the radius of them (the same neighbours, fewer searched)
        around = np.flatnonzero(may_be_near(points[near], sample.points, radius))
        motion[near] = propagate(sample.points[around], relative[around], points[near], k, radius)
    return motion
