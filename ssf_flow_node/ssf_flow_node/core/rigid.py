"""Learning-free real-time scene flow (ICP-Flow-like): ego motion, clusters, per-cluster rigid motion."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from ssf_common.config import Section
from ssf_common.geometry.clustering import voxel_components
from ssf_common.geometry.fitting import planar_kabsch, planar_plane_step
from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.labels import label_extents, label_means, pick_per_label, ragged_arange
from ssf_common.geometry.se3 import transform_points, yaw_translate
from ssf_flow_node.core.base import FlowResult, finish, prepare
from ssf_flow_node.core.preprocess import PreprocessConfig
from ssf_flow_node.core.registration import RegistrationConfig, ScanMatcher

class RigidConfig(Section):
    """Clustering and per-cluster registration of the learning-free estimator."""

    cluster_voxel: float = Field(0.5, gt=0.0, description="voxel edge (m) of the connected-component clustering")
    min_cluster_points: int = Field(10, ge=3, description="points needed in each scan to register a cluster")
    min_masked_points: int = Field(3, ge=2, description="points needed in each scan for a cluster the mask calls dynamic")
    max_step: float = Field(3.0, gt=0.0, description="largest object displacement per frame (m)")
    histogram_bin: float = Field(0.3, gt=0.0, description="bin (m) of the translation histogram")
    histogram_points: int = Field(32, ge=4, description="points per scan and cluster in the translation histogram")
    histogram_peaks: int = Field(4, ge=1, description="histogram peaks tried as initial translations")
    point_weight: float = Field(0.3, ge=0.0, description="weight of point-to-point next to point-to-plane residuals")
    plane: bool = Field(True, description="register objects point-to-plane (normals of scan t+1) instead of point-to-point")
    max_yaw: float = Field(0.1, ge=0.0, description="largest object rotation per frame (rad)")
    max_extent: float = Field(12.0, gt=0.0, description="larger clusters (xy extent, m) are static structure unless the mask says otherwise")
    icp_points: int = Field(128, ge=3, description="points per cluster in its ICP (random, for speed on big clusters)")
    icp_iterations: int = Field(5, ge=1, description="iterations of the batched per-cluster ICP")
    icp_gates: tuple[float, float] = Field((1.0, 0.3), description="correspondence gate (m), first and last iteration")
    residual_cap: float = Field(1.0, gt=0.0, description="nearest-neighbour residuals are truncated here (m)")
    min_gain: float = Field(0.5, ge=0.0, le=1.0, description="share of the static hypothesis' residual a motion must "
                            "remove (where the mask does not call the cluster dynamic)")
    inlier_gate: float = Field(0.3, gt=0.0, description="a point is explained by scan t+1 within this distance (m)")
    min_explained_gain: float = Field(0.25, ge=0.0, le=1.0, description="or: share of a cluster's points a motion must "
                                      "newly explain")
    min_motion: float = Field(0.05, ge=0.0, description="cluster motions below this (m) are static")
    attach_height: float = Field(0.08, ge=0.0, description="points below ground_height but above this may belong to objects (m)")
    attach_distance: float = Field(0.6, ge=0.0, description="such low points this close to a moving cluster move with it (m)")
    mask_threshold: float = Field(0.5, ge=0.0, le=1.0, description="dynamic probability above which a point is dynamic")


class Clusters(NamedTuple):
    """Cluster label per non-ground point of each scan (-1: none) and the number of clusters."""

    labels1: np.ndarray
    labels2: np.ndarray
    count: int


class ClusterMotions(NamedTuple):
    """Per cluster: rotation about z, translation (in scan t+1's frame, after ego compensation), moving flag."""

    yaw: np.ndarray
    translation: np.ndarray
    moving: np.ndarray


class RigidFlowEstimator:
    """Ego motion by robust ICP, then rigid motions of clusters of the non-ground points."""

    name = "rigid"

    def __init__(self, preprocess: PreprocessConfig, registration: RegistrationConfig, config: RigidConfig) -> None:
        self.preprocess = preprocess
        self.registration = registration
        self.config = config

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; dynamic points of the mask are kept out of the ego registration."""
        pair = prepare(pc1, pc2, mask, self.preprocess)
        points1, points2 = pair.sample1.points, pair.sample2.points
        dynamic = None if pair.mask is None else pair.mask > self.config.mask_threshold
        # 1. ego motion from the points the mask does not call dynamic (robust kernel for the ones it misses)
        matcher = ScanMatcher(points2, self.registration)
        ego = matcher.align(points1 if dynamic is None else points1[~dynamic])
        compensated = transform_points(ego, points1)
        # 2. drop the ground, cluster the rest of both scans together
        height1 = height_above_ground(points1, self.preprocess.ground_cell)
        above1 = height1 >= self.preprocess.ground_height
        above2 = height_above_ground(points2, self.preprocess.ground_cell) >= self.preprocess.ground_height
        clusters = joint_clusters(compensated[above1], points2[above2], self.config.cluster_voxel)
        # 3. rigid motion of each cluster, histogram-initialised ICP, kept only where it explains the data
        normals2 = matcher.normals()[above2] if self.config.plane else None
        motions = cluster_motions(compensated[above1], points2[above2], clusters, self.config,
                                  None if dynamic is None else pair.mask[above1], normals2)
        # 4. every point moves with its cluster (ground-flagged points touching a moving cluster too), or with the scene
        labels = np.full(points1.shape[0], -1)
        labels[above1] = clusters.labels1
        low = ~above1 & (height1 > self.config.attach_height)
        labels[low] = attach_to_moving(compensated[low], compensated[above1], clusters.labels1, motions.moving,
                                       self.config.attach_distance)
        moved = apply_motions(compensated, labels, motions)
        return finish(pair, moved - points1, ego, self.preprocess)


def joint_clusters(points1: np.ndarray, points2: np.ndarray, voxel: float) -> Clusters:
    """Connected components of the occupied voxels of both (ego-compensated) scans together."""
    labels, count = voxel_components(np.concatenate([points1, points2]), voxel)
    return Clusters(labels[: points1.shape[0]], labels[points1.shape[0]:], count)


def initial_translations(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, active: np.ndarray,
                         config: RigidConfig, tree: cKDTree, rng: np.random.Generator) -> np.ndarray:
    """Per cluster, the best of: no motion, the centroid shift, the peaks of the displacement histogram."""
    count = clusters.count
    picks1 = pick_per_label(clusters.labels1, active, config.histogram_points, rng)
    picks2 = pick_per_label(clusters.labels2, active, config.histogram_points, rng)
    candidates = [np.zeros((count, 3)), centroid_shift(points1, points2, clusters, count)]
    if picks1.size and picks2.size:
        candidates += histogram_peaks(points1, points2, clusters, picks1, picks2, config)
    labels = clusters.labels1[picks1]
    shifts = np.stack(candidates)  # (candidates, clusters, 3)
    moved = (points1[picks1][None] + shifts[:, labels]).reshape(-1, 3)
    tries = np.repeat(np.arange(len(candidates)), labels.size) * count + np.tile(labels, len(candidates))
    scores = fit_quality(moved, tries, tree, clusters.labels2, config, len(candidates) * count,
                         np.tile(labels, len(candidates))).residual
    best = scores.reshape(len(candidates), count).argmin(axis=0)
    return shifts[best, np.arange(count)]


def centroid_shift(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, count: int) -> np.ndarray:
    """Per cluster, the horizontal shift between its centroids in the two scans."""
    shift = np.zeros((count, 3))
    shift[:, :2] = label_means(points2[:, :2], clusters.labels2, count) - label_means(points1[:, :2], clusters.labels1, count)
    return shift


def histogram_peaks(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, picks1: np.ndarray,
                    picks2: np.ndarray, config: RigidConfig) -> list[np.ndarray]:
    """Per cluster, the `peaks` most frequent horizontal displacements between its points in the two scans."""
    count = clusters.count
    picks2 = picks2[np.argsort(clusters.labels2[picks2], kind="stable")]
    labels2 = clusters.labels2[picks2]
    starts = np.searchsorted(labels2, clusters.labels1[picks1], side="left")
    lengths = np.searchsorted(labels2, clusters.labels1[picks1], side="right") - starts
    first = np.repeat(picks1, lengths)
    second = picks2[np.repeat(starts, lengths) + ragged_arange(lengths)]
    displacement = points2[second, :2] - points1[first, :2]
    near = np.linalg.norm(displacement, axis=1) <= config.max_step
    first, displacement = first[near], displacement[near]
    half = int(np.ceil(config.max_step / config.histogram_bin)) + 1
    width = 2 * half + 1
    cells = np.round(displacement / config.histogram_bin).astype(np.int64) + half
    codes = clusters.labels1[first] * width * width + cells[:, 0] * width + cells[:, 1]
    unique, votes = np.unique(codes, return_counts=True)
    cluster_of = unique // (width * width)
    order = np.lexsort((-votes, cluster_of))
    rank = np.arange(order.size) - np.searchsorted(cluster_of[order], cluster_of[order], side="left")
    peaks = []
    for level in range(config.histogram_peaks):
        chosen = order[rank == level]
        shift = np.zeros((count, 3))
        cell = unique[chosen] % (width * width)
        shift[cluster_of[chosen], 0] = (cell // width - half) * config.histogram_bin
        shift[cluster_of[chosen], 1] = (cell % width - half) * config.histogram_bin
        peaks.append(shift)
    return peaks


class Fit(NamedTuple):
    """How well scan t+1 explains each cluster under one motion hypothesis."""

    residual: np.ndarray  # mean distance to the same cluster in scan t+1, each capped at residual_cap (m)
    unexplained: np.ndarray  # share of points farther than inlier_gate from it


def fit_quality(moved: np.ndarray, labels: np.ndarray, tree: cKDTree, labels2: np.ndarray, config: RigidConfig,
                count: int, clusters: np.ndarray | None = None) -> Fit:
    """Per label, residual and unexplained share of its moved points against the same cluster in scan t+1
    (`clusters`: each point's cluster, where the labels are not clusters)."""
    clusters = labels if clusters is None else clusters
    gap, index = tree.query(moved, distance_upper_bound=config.residual_cap)
    hit = np.isfinite(gap)
    hit[hit] = labels2[index[hit]] == clusters[hit]
    residual = np.where(hit, gap, config.residual_cap)
    sizes = np.maximum(np.bincount(labels, minlength=count), 1)
    return Fit(np.bincount(labels, residual, count) / sizes,
               np.bincount(labels, residual > config.inlier_gate, count) / sizes)


def cluster_motions(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, config: RigidConfig,
                    mask: np.ndarray | None, normals2: np.ndarray | None = None) -> ClusterMotions:
    """Histogram-initialised batched ICP per cluster; a motion is kept where it explains the points better."""
    count = clusters.count
    yaw, translation = np.zeros(count), np.zeros((count, 3))
    if count == 0 or points1.shape[0] == 0 or points2.shape[0] == 0:
        return ClusterMotions(yaw, translation, np.zeros(count, dtype=bool))
    sizes1 = np.bincount(clusters.labels1, minlength=count)
    sizes2 = np.bincount(clusters.labels2, minlength=count)
    active = (np.minimum(sizes1, sizes2) >= config.min_cluster_points) & (label_extents(points1, clusters.labels1, count) <= config.max_extent)
    belief = None
    if mask is not None:
        belief = np.bincount(clusters.labels1, mask, count) / np.maximum(sizes1, 1)
        active |= (belief > config.mask_threshold) & (np.minimum(sizes1, sizes2) >= config.min_masked_points)
    tree = cKDTree(points2)
    rng = np.random.default_rng(0)
    translation = initial_translations(points1, points2, clusters, active, config, tree, rng)
    believed = np.zeros(count, dtype=bool) if belief is None else belief > config.mask_threshold
    active &= believed | (translation != 0.0).any(axis=1)  # where standing still explains a cluster best, it does
    members = pick_per_label(clusters.labels1, active, config.icp_points, rng)
    source, labels = points1[members], clusters.labels1[members]
    gates = np.geomspace(config.icp_gates[0], config.icp_gates[1], config.icp_iterations)
    for gate in gates:
        moved = yaw_translate(source, yaw[labels], translation[labels])
        gap, index = tree.query(moved, distance_upper_bound=gate)
        good = np.isfinite(gap)
        good[good] = clusters.labels2[index[good]] == labels[good]
        fitted = np.bincount(labels[good], minlength=count) >= 3
        if normals2 is None:
            new_yaw, new_translation = planar_kabsch(source[good], points2[index[good]], labels[good], count, config.max_yaw)
        else:
            new_yaw, new_translation = planar_plane_step(moved[good], points2[index[good]], normals2[index[good]],
                                                         labels[good], yaw, translation, count, config.point_weight,
                                                         config.max_yaw)
        yaw[fitted], translation[fitted] = new_yaw[fitted], new_translation[fitted]
    moved = yaw_translate(source, yaw[labels], translation[labels])
    fit_moving = fit_quality(moved, labels, tree, clusters.labels2, config, count)
    fit_static = fit_quality(source, labels, tree, clusters.labels2, config, count)
    shift = np.stack([np.bincount(labels, (moved - source)[:, i], count) for i in range(3)], axis=1)
    displacement = np.linalg.norm(shift, axis=1) / np.maximum(np.bincount(labels, minlength=count), 1)
    explains = (fit_moving.residual < (1.0 - config.min_gain) * fit_static.residual) | (
        fit_static.unexplained - fit_moving.unexplained >= config.min_explained_gain)
    moving = active & (displacement > config.min_motion) & explains
    moving |= active & (displacement > config.min_motion) & believed
    yaw[~moving], translation[~moving] = 0.0, 0.0
    return ClusterMotions(yaw, translation, moving)


def attach_to_moving(points: np.ndarray, clustered: np.ndarray, labels: np.ndarray, moving: np.ndarray,
                     distance: float) -> np.ndarray:
    """Label of the moving cluster within `distance` of each point (-1 where none)."""
    attached = np.full(points.shape[0], -1)
    on_moving = (labels >= 0) & moving[np.maximum(labels, 0)]
    if not on_moving.any() or points.shape[0] == 0:
        return attached
    gap, index = cKDTree(clustered[on_moving]).query(points, distance_upper_bound=distance)
    near = np.isfinite(gap)
    attached[near] = labels[on_moving][index[near]]
    return attached


def apply_motions(points: np.ndarray, labels: np.ndarray, motions: ClusterMotions) -> np.ndarray:
    """Move each clustered point with its cluster's motion."""
    moved = points.copy()
    on = labels >= 0
    moved[on] = yaw_translate(points[on], motions.yaw[labels[on]], motions.translation[labels[on]])
    return moved.astype(np.float32)
