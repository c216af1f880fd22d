"""The learning-free segmenter: motion relative to the static scene, clusters of what moves, a rigid test per cluster.

The classical answer to motion segmentation: compensate the ego motion, keep the off-ground points whose residual
motion is fast enough, cluster them, call a cluster a moving object when it is big enough and moves rigidly, and join
the pieces of one object: neighbours in the sensor's view that move alike and together fit one object."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError
from ssf_common.geometry.boxes import min_area_rectangle
from ssf_common.geometry.clustering import angular_neighbours, angular_spacing, spacing_components
from ssf_common.geometry.fitting import batched_kabsch, weighted_kabsch
from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.labels import label_counts, label_extents, label_means
from ssf_common.geometry.se3 import own_motion, transform_points
from ssf_seg_node.core.base import SegInput, SegmentationResult, result_from_slots


class GeometricConfig(Section):
    """Thresholds of the learning-free segmenter (speeds in m/s, so they hold at any scan rate)."""

    min_speed: float = Field(0.6, gt=0.0, description="residual speed (m/s) above which a point may move")
    prior_speed: float = Field(0.3, gt=0.0, description="the same threshold for points the previous mask called dynamic")
    softness: float = Field(0.3, gt=0.0, description="width of the probability ramp around the threshold, as a share of it")
    cluster_reach: float = Field(2.5, gt=0.0, description="moving points closer than this many times the local point "
                                 "spacing (measured on the scan) belong to one object, so that two neighbours a short gap "
                                 "apart (cars in adjacent lanes, people walking side by side) stay two")
    cluster_cell: float = Field(0.2, gt=0.0, description="voxel (m) on which the point spacing is measured and linked")
    min_link: float = Field(1.0, gt=0.0, description="shortest link (m) connecting moving points into objects (the "
                            "scale of a vehicle's or a walker's own gaps, where the scan is dense)")
    max_link: float = Field(2.0, gt=0.0, description="longest link (m) connecting moving points into objects, where the "
                            "scan is sparse (far away)")
    min_points: int = Field(3, ge=1, description="smaller moving clusters are noise and stay static")
    max_extent: float = Field(15.0, gt=0.0, description="larger moving clusters (xy extent, m) are ego-motion error, static")
    rigidity: float = Field(0.25, gt=0.0, description="largest RMS deviation (m) of a cluster's flow from one rigid motion")
    object_footprint: tuple[float, float] = Field(
        (5.5, 2.5), description="footprint (length, width; m) of the largest object one motion carries (a large car or "
        "van, mirrors included): moving clusters that are neighbours in the sensor's view, move alike and together "
        "fit it are pieces of one object")
    fragment_speed: float = Field(1.5, gt=0.0, description="largest difference (m/s) of the mean velocities of two pieces "
                                  "of one object: the flow's error on a piece of a few points (90 % of the pieces of one "
                                  "object agree within 1.3 m/s on the tuning seeds; two walkers crossing differ by ~3 m/s)")
    ground_cell: float = Field(2.0, gt=0.0, description="grid cell (m) of the ground height estimate")
    ground_height: float = Field(0.0, ge=0.0, description="points this close above the local ground are ground and stay "
                                 "static (0: the flow alone decides, as on scans whose ground was removed)")
    ego_iterations: int = Field(4, ge=1, description="reweighted fits of the ego motion when none is given")
    ego_scale: float = Field(0.1, gt=0.0, description="residual (m) at which an ego-fit point loses half its weight")
    ego_points: int = Field(4096, ge=16, description="random points the ego fit uses (it needs few)")


class GeometricSegmenter:
    """Ego-compensated residual flow, clustering of the moving points, and a rigid test per cluster."""

    name = "geometric"

    def __init__(self, config: GeometricConfig, dt: float = 0.1) -> None:
        self.config = config
        self.dt = dt

    def segment(self, points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None = None,
                ego: np.ndarray | None = None) -> SegmentationResult:
        """Static scene and moving objects of scan t from its flow (and the previous mask as a prior)."""
        points, flow = np.asarray(points, np.float32)[:, :3], np.asarray(flow, np.float32)
        # 1. the ego motion: given, or fitted robustly to the flow of every point
        ego = fit_ego_motion(points, flow, previous, self.config) if ego is None else np.asarray(ego, np.float64)
        # 2. each point's motion relative to the static scene, as a velocity and a speed
        velocity = own_motion(ego, points, flow) / np.float32(self.dt)
        speed = np.sqrt(np.einsum("ij,ij->i", velocity, velocity))
        # 3. candidates: off-ground points faster than the threshold (a lower one where the prior says dynamic)
        threshold = np.full(len(points), self.config.min_speed)
        if previous is not None:
            threshold[np.asarray(previous) > 0.5] = self.config.prior_speed
        moving = speed > threshold
        if self.config.ground_height > 0:
            moving &= height_above_ground(points, self.config.ground_cell) >= self.config.ground_height
        candidates = np.flatnonzero(moving)
        near, near_flow = points[candidates].astype(np.float64), flow[candidates].astype(np.float64)
        # 4. clusters of the candidates (linked within a few point spacings); the big-enough, rigidly moving ones are objects
        spacing = angular_spacing(near)  # the scan's angular resolution, measured on the candidates
        labels, count = spacing_components(near, self.config.cluster_cell, self.config.cluster_reach,
                                           self.config.min_link, self.config.max_link, spacing=spacing)
        moving = self.moving_clusters(near, near_flow, labels, count)
        # 5. fragments: neighbouring moving clusters that move as one and fit one object are one object
        object_of = self.merge_fragments(near, velocity[candidates].astype(np.float64), labels, count, moving, spacing)
        objects = np.unique(object_of[moving])
        # 6. slots: the static scene, then one per moving object, with a probability from how fast each cluster moves
        cluster_speed = label_means(speed[candidates], labels, count)
        cluster_threshold = label_means(threshold[candidates], labels, count)
        ramp = self.config.softness * cluster_threshold
        probability = 1.0 / (1.0 + np.exp(-(cluster_speed - cluster_threshold) / np.maximum(ramp, 1e-6)))
        slots = np.zeros((len(points), 1 + objects.size), np.float32)
        slots[:, 0] = 1.0
        slot_of_cluster = np.full(count, -1)
        slot_of_cluster[moving] = 1 + np.searchsorted(objects, object_of[moving])
        on_moving = moving[labels]
        rows, slot = candidates[on_moving], slot_of_cluster[labels[on_moving]]
        slots[rows, slot] = probability[labels[on_moving]]
        slots[rows, 0] = 1.0 - slots[rows, slot]
        static_slots = np.zeros(slots.shape[1], bool)
        static_slots[0] = True
        return result_from_slots(slots, static_slots, self.config.min_points)

    def moving_clusters(self, points: np.ndarray, flow: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
        """(count,) bool: clusters with enough points, not too large, whose flow one rigid motion explains."""
        if count == 0:
            return np.zeros(0, bool)
        motions = batched_kabsch(points, points + flow, labels, count)
        moved = np.einsum("nij,nj->ni", motions[labels, :3, :3], points) + motions[labels, :3, 3]
        rms = np.sqrt(label_means(np.sum((moved - points - flow) ** 2, axis=1), labels, count))
        return ((label_counts(labels, count) >= self.config.min_points)
                & (label_extents(points, labels, count) <= self.config.max_extent)
                & (rms <= self.config.rigidity))

    def merge_fragments(self, points: np.ndarray, velocity: np.ndarray, labels: np.ndarray, count: int,
                        moving: np.ndarray, spacing: float | None = None) -> np.ndarray:
        """(count,) the object of each cluster (the index of one of its clusters): moving clusters whose points lie
        within `cluster_reach` point spacings of each other in the sensor's view (in angle, at any ranges), whose mean
        velocities differ by at most `fragment_speed` and whose union fits `object_footprint` are one object, nearest
        pairs first. A surface seen at a grazing angle (a car's flank) is sampled a beam's spacing over the sine of
        the incidence apart, wider than a link, and comes apart along the line of sight. `spacing`: the points'
        angular spacing, when already measured."""
        object_of = np.arange(count)
        if np.count_nonzero(moving) < 2:
            return object_of
        angle = self.config.cluster_reach * (angular_spacing(points) if spacing is None else spacing)
        pairs = angular_neighbours(points, np.where(moving[labels], labels, -1), angle, self.config.cluster_cell)
        centres = label_means(points, labels, count)
        pairs = pairs[np.argsort(np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1), kind="stable")]
        length, width = self.config.object_footprint
        for first, second in pairs:
            one, other = object_of[first], object_of[second]
            if one == other:
                continue
            mine, theirs = object_of[labels] == one, object_of[labels] == other
            if np.linalg.norm(velocity[mine].mean(axis=0) - velocity[theirs].mean(axis=0)) > self.config.fragment_speed:
                continue
            _, sides, _ = min_area_rectangle(points[mine | theirs, :2])
            if sides[0] <= length and sides[1] <= width:
                object_of[object_of == other] = one
        return object_of


def fit_ego_motion(points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None, config: GeometricConfig) -> np.ndarray:
    """The rigid motion most of the scene's flow follows: reweighted Kabsch (Cauchy weights) on a random subset,
    prior dynamics left out."""
    pick = np.random.default_rng(0).choice(len(points), min(len(points), config.ego_points), replace=False)
    points, flow = np.asarray(points, np.float64)[pick], np.asarray(flow, np.float64)[pick]
    prior = np.ones(len(points)) if previous is None else (np.asarray(previous)[pick] <= 0.5).astype(np.float64)
    weights, ego = prior, np.eye(4)
    for _ in range(config.ego_iterations):
        ego = weighted_kabsch(points, points + flow, weights)
        residual = np.linalg.norm(transform_points(ego, points) - points - flow, axis=1)
        weights = prior / (1.0 + (residual / config.ego_scale) ** 2)
    return ego


def build_geometric(config, device: str = "cpu") -> GeometricSegmenter:
    """Factory entry: the geometric segmenter (it reads points and flow together)."""
    if config.input is not SegInput.BOTH:
        raise ConfigError(f"segmenter 'geometric' needs points and flow (input both), not '{config.input.value}'")
    return GeometricSegmenter(config.geometric, config.selection.scan_period)
