"""Step 2, clustering: connected components of both scans' non-ground points, scan t+1's searchable surfaces and noise
floors, and fixed per-cluster point picks."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.clustering import voxel_components
from ssf_common.geometry.labels import label_quantiles
from ssf_common.geometry.neighbours import PointIndex
from ssf_flow_node.core.rigid.config import RigidConfig


class Clusters(NamedTuple):
    """Cluster label per non-ground point of scan t (-1: none), component label per point of scan t+1, the number of
    clusters, and each cluster's component in scan t+1 (clusters of scan t may split one joint component)."""

    labels1: np.ndarray
    labels2: np.ndarray
    count: int
    parent: np.ndarray


class Surfaces(NamedTuple):
    """Points of scan t+1 to register against: their normals (None: point-to-point), a KD-tree, and per point how far
    its nearest neighbour lies off its surface (its roughness)."""

    points: np.ndarray
    normals: np.ndarray | None
    tree: PointIndex
    roughness: np.ndarray


def surfaces_of(points: np.ndarray, normals: np.ndarray | None) -> Surfaces:
    """Searchable surfaces of scan t+1's points."""
    tree = PointIndex(points)
    gap, index = tree.query(points, k=2) if len(points) > 1 else (np.zeros((len(points), 2)), np.zeros((len(points), 2), int))
    rough = gap[:, 1] if normals is None else np.abs(np.einsum("ij,ij->i", points[index[:, 1]] - points, normals))
    return Surfaces(points, normals, tree, rough)


def joint_clusters(points1: np.ndarray, points2: np.ndarray, voxel: float, groups1: np.ndarray | None = None) -> Clusters:
    """Connected components of the occupied voxels of both (ego-compensated) scans together; points of scan t in
    different groups (the mask's dynamic and static points) get clusters of their own within a component."""
    labels, _ = voxel_components(np.concatenate([points1, points2]), voxel)
    labels1, labels2 = labels[: points1.shape[0]], labels[points1.shape[0]:]
    groups = np.zeros(points1.shape[0], np.int64) if groups1 is None else np.asarray(groups1, np.int64)
    codes, inverse = np.unique(labels1 * 2 + groups, return_inverse=True)
    return Clusters(inverse.reshape(-1).astype(np.int64), labels2.astype(np.int64), int(codes.size), codes // 2)


def component_count(clusters: Clusters) -> int:
    """Number of joint components the clusters' scan t+1 labels refer to."""
    return int(max(clusters.labels2.max(initial=-1), clusters.parent.max(initial=-1)) + 1)


def priorities(count: int, stream: int = 0) -> np.ndarray:
    """A fixed random number per point (the same for the same number of points: one pair's samples)."""
    return np.random.default_rng([count, stream]).random(count)


def ranked_per_label(labels: np.ndarray, active: np.ndarray, per_label: int, priority: np.ndarray) -> np.ndarray:
    """Up to `per_label` point indices of each active label, those of lowest priority value: a cluster picks the same
    points whatever the other clusters are, so the loop's estimates move only where the clusters change."""
    candidates = np.flatnonzero((labels >= 0) & active[np.maximum(labels, 0)])
    ordered = candidates[np.lexsort((priority[candidates], labels[candidates]))]
    sorted_labels = labels[ordered]
    rank = np.arange(ordered.size) - np.searchsorted(sorted_labels, sorted_labels, side="left")
    return ordered[rank < per_label]


def noise_floors(surfaces: Surfaces, clusters: Clusters, noise: float, config: RigidConfig) -> np.ndarray:
    """Per component, the miss (m) below which standing still explains it: the scene's median miss, the component's
    own roughness (the median distance of scan t+1's points from their neighbours' surfaces) and half a step at
    min_speed."""
    rough = label_quantiles(surfaces.roughness, clusters.labels2, component_count(clusters), 0.5)
    return np.maximum(config.surface_noise * np.maximum(rough, noise), 0.5 * config.min_speed * config.scan_period)
