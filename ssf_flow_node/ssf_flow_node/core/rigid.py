"""Learning-free real-time scene flow (ICP-Flow-like): ego motion, clusters, per-cluster rigid motion."""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from ssf_common.config import Section
from ssf_common.geometry.clustering import voxel_components
from ssf_common.geometry.fitting import planar_kabsch, planar_plane_step
from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.labels import (label_counts, label_extents, label_main_axes, label_means, label_quantiles,
                                         label_spans, ragged_arange)
from ssf_common.geometry.neighbours import may_be_near
from ssf_common.geometry.se3 import transform_points, yaw_translate
from ssf_flow_node.core.base import FlowResult, PreparedPair, ScanCache, finish, fingerprint, prepare
from ssf_flow_node.core.preprocess import PreprocessConfig, Sample, check_mask, object_top
from ssf_flow_node.core.registration import RegistrationConfig, ScanMatcher, motion_gap


FLAT_HEIGHT = 0.3  # m: a cluster flatter than this counts as this tall when its sampling spacing is estimated
PAIR_HISTORY = 3  # pairs whose work is kept: the loop's next iteration on a pair may come after the next pair


class RigidConfig(Section):
    """Clustering and per-cluster registration of the learning-free estimator (speeds in m/s, turns in rad/s)."""

    dt: float = Field(0.1, gt=0.0, description="time between the two scans (s)")
    cluster_voxel: float = Field(0.5, gt=0.0, description="voxel edge (m) of the connected-component clustering")
    split_voxel: float = Field(0.25, ge=0.0, description="a cluster that stays still although parts of it changed is "
                               "clustered again with this voxel (m), so a walker beside a parked car gets its own motion "
                               "(0: never)")
    split_by_mask: bool = Field(False, description="the mask's dynamic points form clusters apart from the rest of "
                                "their component (off: a carried mask misses the parts of an object it has newly shown, "
                                "which then stayed behind)")
    min_cluster_points: int = Field(15, ge=3, description="points needed in each scan to register a cluster")
    min_masked_points: int = Field(3, ge=2, description="points needed in each scan for a cluster the mask calls dynamic")
    max_speed: float = Field(30.0, gt=0.0, description="fastest object (m/s)")
    histogram_bin: float = Field(0.3, gt=0.0, description="bin (m) of the translation histogram")
    histogram_points: int = Field(32, ge=4, description="points per scan and cluster in the translation histogram")
    histogram_peaks: int = Field(4, ge=1, description="histogram peaks tried as initial translations")
    point_weight: float = Field(0.3, ge=0.0, description="weight of point-to-point next to point-to-plane residuals")
    plane: bool = Field(True, description="register objects point-to-plane (normals of scan t+1) instead of point-to-point")
    max_yaw_rate: float = Field(1.0, ge=0.0, description="fastest object turn (rad/s)")
    max_extent: float = Field(12.0, gt=0.0, description="larger clusters (xy extent, m) are static structure unless the mask says otherwise")
    icp_points: int = Field(128, ge=3, description="points per cluster in its ICP (random, for speed on big clusters)")
    icp_iterations: int = Field(5, ge=1, description="iterations of the batched per-cluster ICP")
    screen_still: bool = Field(True, description="clusters that standing still explains within their noise floor are "
                               "not fitted (no fitted motion could be proven for them); their ends and carried motions "
                               "are still tried")
    icp_gates: tuple[float, float] = Field((1.0, 0.3), description="correspondence gate (m), first and last iteration")
    residual_cap: float = Field(1.0, gt=0.0, description="nearest-neighbour residuals are truncated here (m)")
    min_gain: float = Field(0.3, ge=0.0, le=1.0, description="share of the static hypothesis' distance to the surfaces "
                            "of scan t+1 a motion must remove (where the mask does not call the cluster dynamic)")
    min_point_gain: float = Field(0.5, ge=0.0, le=1.0, description="or: share of its distance to the points")
    support_gain: float = Field(0.1, ge=0.0, le=1.0, description="a motion proven by the surfaces must also bring the "
                                "points this share closer (sliding along a wall does not)")
    mask_gain: float = Field(0.1, ge=0.0, le=1.0, description="the same share where the mask calls the cluster dynamic")
    surface_noise: float = Field(2.0, ge=0.0, description="a cluster standing still must miss the surfaces of scan t+1 by "
                                 "more than this many times the scene's median miss, and its surfaces' own roughness, "
                                 "before its motion counts")
    inlier_gate: float = Field(0.3, gt=0.0, description="a point is explained by scan t+1 within this distance (m)")
    resample_spacing: float = Field(0.3, ge=0.0, description="standing still counts the sensor's resampling of a "
                                    "surface it slides along only where scan t+1 samples it along the slide at least "
                                    "this coarsely (m): far walls at grazing angles; the finer-sampled flank of a car "
                                    "moving with the ego (or overtaking it) would pass for still")
    min_explained_gain: float = Field(0.25, ge=0.0, le=1.0, description="or: share of a cluster's points a motion must "
                                      "newly explain")
    max_unexplained: float = Field(0.2, ge=0.0, le=1.0, description="a motion must explain all but this share of a "
                                   "cluster's points")
    min_speed: float = Field(0.5, ge=0.0, description="clusters slower than this (m/s) are static")
    ground_clearance: float = Field(0.08, ge=0.0, description="where the ground is split off, points this close above "
                                    "it (m) are ground and keep the scene's motion; higher ones near a mover share it")
    footprint: float = Field(0.1, ge=0.0, description="points within ground_clearance of the ground still move with a "
                             "moving object where one of its sampled points lies within this horizontal distance (m): "
                             "its wheels and lowest parts, inside its footprint (0: never)")
    attach_distance: float = Field(0.6, ge=0.0, description="points left out of the clusters (low ones) this close to a "
                                   "moving cluster move with it where its motion explains them better (m)")
    mask_threshold: float = Field(0.5, ge=0.0, le=1.0, description="dynamic probability above which a point is dynamic")
    ego_refit: float = Field(0.02, ge=0.0, le=1.0, description="the ego motion is aligned without the mask's dynamic "
                             "points too only where it calls more than this share of them dynamic (the robust kernel "
                             "copes with the rest)")
    ego_tolerance: float = Field(0.1, ge=0.0, description="the ego motions aligned with and without the mask's dynamic "
                                 "points agree within this (m, over a 1 m radius); where they do not, the second must "
                                 "lie this much nearer the previous pair's to be taken")
    ego_max_accel: float = Field(8.0, gt=0.0, description="hardest change of the ego's speed (m/s², braking at about 0.8 "
                                 "g): where only the alignment without the mask's dynamic points is a change from the "
                                 "previous pair's motion a vehicle can make in dt, it is taken (traffic moving with the ego "
                                 "pulls the other towards standing still)")
    ego_vouch: bool = Field(True, description="where the mask calls enough points dynamic, the alignment without them is "
                            "taken at once when it is a change of the previous pair's motion a vehicle can make "
                            "(ego_max_accel, ego_mask_share): the alignment on every point is made only to judge one "
                            "that is not")
    ego_mask_share: float = Field(0.5, ge=0.0, le=1.0, description="the alignment without the mask's dynamic points "
                                  "is taken for being the only plausible change only while the mask calls at most this "
                                  "share of the points dynamic (a mask that hides the static structure drags an alignment "
                                  "on oncoming traffic along step by step, each step plausible)")
    end_whole: bool = Field(True, description="where the ground is split, the ends of a flank are found among all the "
                            "points of the whole scans within a sampling spacing of its sampled ones, not among the "
                            "sampled ones alone (a near flank thinned by the range-balanced sample)")
    end_spacings: float = Field(2.0, ge=0.0, description="a cluster alone in its component whose two ends moved alike "
                                "along its main horizontal axis, by at least this many times its sampling spacing, moves "
                                "by that shift where it explains scan t+1 no worse than standing still: a flank sliding "
                                "along itself, which the fits cannot tell from still (0: never)")
    end_agreement: float = Field(0.25, ge=0.0, le=1.0, description="the two ends' shifts agree within this share of "
                                 "their mean")
    end_points: int = Field(50, ge=2, description="points a cluster needs in scan t before its ends count")
    end_slack: float = Field(0.25, ge=0.0, description="the ends' shift may fit the sample this share worse than "
                             "standing still: a flank sliding along itself fits either way only within the noise of its "
                             "sampling")
    end_occlusion: float = Field(0.5, gt=0.0, description="an end with points of scan t+1 this much nearer the sensor "
                                 "beside it (within three sampling spacings) is the edge of what hides the cluster, not "
                                 "the cluster's end (m)")
    carry_pairs: int = Field(10, ge=0, description="in a stream of scans, an object seen moving keeps its motion for at "
                             "most this many pairs running in which the pair alone cannot tell it from standing still (a "
                             "flank sliding along itself), while that motion explains scan t+1 no worse (0: never)")
    carry_radius: float = Field(0.5, gt=0.0, description="a point of scan t takes the motion of the previous pair's "
                                "moving point that landed nearest it, within this distance (m)")
    carry_share: float = Field(0.5, gt=0.0, le=1.0, description="share of a cluster's points that must take a motion "
                               "from the previous pair for the cluster to keep it")
    carry_proven: int = Field(2, ge=1, description="pairs that must have shown the object moving on their own evidence "
                              "before its motion is carried (one pair's phantom is not carried on)")
    carry_tolerance: float = Field(0.2, ge=0.0, description="the cluster's own fitted motion replaces the carried one "
                                   "where the two agree within this (m per pair)")


class Clusters(NamedTuple):
    """Cluster label per non-ground point of scan t (-1: none), component label per point of scan t+1, the number of
    clusters, and each cluster's component in scan t+1 (clusters of scan t may split one joint component)."""

    labels1: np.ndarray
    labels2: np.ndarray
    count: int
    parent: np.ndarray


class Bands(NamedTuple):
    """The whole scans' points between the ground and object_height (scan t ego-compensated), where the sample is too
    coarse to say where a flank ends."""

    points1: np.ndarray
    points2: np.ndarray


class ClusterMotions(NamedTuple):
    """Per cluster: rotation about z, translation (in scan t+1's frame, after ego compensation), moving flag; and, over
    the pairs of a stream, how many pairs its motion has been carried without the pair's own evidence (-1: still, 0:
    this pair proved it) and how many pairs proved it on their own evidence (0: still)."""

    yaw: np.ndarray
    translation: np.ndarray
    moving: np.ndarray
    carried: np.ndarray
    proven: np.ndarray


class Carried(NamedTuple):
    """Per point of scan t, what the previous pair of a stream left there: the own motion (after the ego's) of the
    moving point that landed nearest, how many pairs that motion had been carried (-1: no moving point near) and
    how many pairs had proved it."""

    motion: np.ndarray
    streak: np.ndarray
    proven: np.ndarray

    def take(self, rows: np.ndarray) -> Carried:
        """The same for a subset of the points."""
        return Carried(self.motion[rows], self.streak[rows], self.proven[rows])


class CarriedMotions(NamedTuple):
    """Per cluster: the mean carried motion, whether enough of its points carry one, whether it may be carried on (not
    for too long, proven often enough), for how many pairs it has been carried and how many pairs proved it."""

    translation: np.ndarray
    present: np.ndarray
    usable: np.ndarray
    streak: np.ndarray
    proven: np.ndarray


@dataclass
class PairState:
    """What one scan pair keeps across the calls of the fusion loop: samples, target normals, ground split, the ego
    fit's source points (the sample, then ground points) in a fixed random order, and the ego motion aligned on them all."""

    key: bytes
    pair: PreparedPair
    matcher: ScanMatcher
    source: np.ndarray
    order: np.ndarray
    above1: np.ndarray
    above2: np.ndarray
    surfaces: Surfaces  # scan t+1 above the ground
    all_surfaces: Surfaces  # all of scan t+1
    ground1: np.ndarray | None  # points of the whole scan t on the ground (where it was split off)
    low: Plan | None  # those points seen from above
    bands: Bands | None  # the whole scans' non-ground points below object_height (scan t as sensed)
    prior: np.ndarray | None = None  # the previous pair's ego motion (a stream's constant velocity)
    base_ego: np.ndarray | None = None  # the ego motion aligned on every point
    ego: np.ndarray | None = None  # the ego motion of the last estimate with a mask (else the one on every point)
    motion: np.ndarray | None = None  # each sampled point's own motion in the last estimate (after the ego)
    moved: np.ndarray | None = None  # the sampled points that motion moves
    result: FlowResult | None = None  # the last estimate
    next_key: bytes = b""  # scan t+1's fingerprint: the next pair of a stream starts with it
    carried: Carried | None = None  # what the previous pair of the stream left on the sampled points
    landed: np.ndarray | None = None  # the sampled points moved by the last estimate (scan t+1's frame)
    streak: np.ndarray | None = None  # per sampled point, its cluster's ClusterMotions.carried in the last estimate
    proven: np.ndarray | None = None  # per sampled point, its cluster's ClusterMotions.proven in the last estimate


class RigidFlowEstimator:
    """Ego motion by robust ICP, then rigid motions of clusters of the non-ground points."""

    name = "rigid"

    def __init__(self, preprocess: PreprocessConfig, registration: RegistrationConfig, config: RigidConfig) -> None:
        self.preprocess = preprocess
        self.registration = registration
        self.config = config
        self.state: PairState | None = None  # the pair asked about last
        self.states: collections.OrderedDict[bytes, PairState] = collections.OrderedDict()  # the last few pairs
        self.scans = ScanCache(preprocess)

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; the ego motion is also aligned without the mask's dynamic points, and clusters the
        mask calls dynamic need fewer points and less evidence to move."""
        state = self.pair_state(pc1, pc2)
        pair = state.pair
        masked = None if mask is None else check_mask(mask, pair.pc1.shape[0])[pair.sample1.indices]
        points1, points2 = pair.sample1.points, pair.sample2.points
        dynamic = None if masked is None else masked > self.config.mask_threshold
        if dynamic is not None and state.result is not None and np.array_equal(dynamic, state.moved):
            return state.result  # the mask calls dynamic just what the last estimate moved: nothing new to use
        above1, above2 = state.above1, state.above2
        # 1. ego motion from every point and from the mask's static ones; where they differ, constant velocity judges
        ego = self.ego_motion(state, dynamic)
        compensated = transform_points(ego, points1)
        carried = None if state.carried is None else state.carried._replace(motion=state.carried.motion @ ego[:3, :3].T)
        # 2. cluster the non-ground points of both scans together (optionally the mask's dynamic points apart)
        clusters = joint_clusters(compensated[above1], points2[above2], self.config.cluster_voxel,
                                  None if dynamic is None or not self.config.split_by_mask else dynamic[above1])
        # 3. rigid motion of each cluster (histogram-initialised ICP, kept only where it explains the data); clusters
        #    that stay still although parts of them changed are clustered finer and tried again; a cluster the previous
        #    pair saw moving keeps that motion where this pair cannot tell it from standing still
        belief = None if masked is None else masked[above1]
        previous = None if state.motion is None else state.motion[above1]
        bands = None if state.bands is None else state.bands._replace(points1=transform_points(ego, state.bands.points1))
        clusters, motions = split_motions(compensated[above1], state.surfaces, clusters, self.config, belief, previous,
                                          points1[above1], None if carried is None else carried.take(above1), bands)
        # 4. every point moves with its cluster (low points next to a moving cluster where its motion explains them
        #    better), or with the scene
        labels = np.full(points1.shape[0], -1)
        labels[above1] = clusters.labels1
        low = np.flatnonzero(~above1)
        labels[low] = attach_to_moving(compensated[low], compensated[above1], clusters.labels1, motions,
                                       state.all_surfaces, self.config)
        moved = apply_motions(compensated, labels, motions)
        state.motion = moved - compensated
        state.moved = np.abs(state.motion).max(axis=1) > 0.0
        state.landed = moved
        state.streak = np.where(labels >= 0, motions.carried[np.maximum(labels, 0)], -1)
        state.proven = np.where(labels >= 0, motions.proven[np.maximum(labels, 0)], 0)
        still = None
        if state.ground1 is not None:  # the lowest points stay with the ground, except in a mover's footprint
            still = state.ground1.copy()
            still[state.low.under(points1[state.moved], self.config.footprint)] = False
        state.result = finish(pair, moved - points1, ego, self.preprocess, still)
        return state.result

    def pair_state(self, pc1: np.ndarray, pc2: np.ndarray) -> PairState:
        """The cached work on this pair of scans (the fusion loop asks for the same pair again), or a fresh one."""
        key = fingerprint(pc1, pc2)
        if key in self.states:  # the loop asks again, perhaps after the stream's next pair (a node's mask hint)
            self.states.move_to_end(key)
            self.state = self.states[key]
            return self.state
        first = fingerprint(pc1)
        previous = next((state for state in reversed(self.states.values()) if state.next_key == first), None)
        latest = previous or self.state
        prior = None if latest is None else latest.ego
        pair = prepare(pc1, pc2, None, self.preprocess, self.scans)
        points1, points2 = pair.sample1.points, pair.sample2.points
        source, target = with_ground(pair.pc1, pair.sample1), with_ground(pair.pc2, pair.sample2)
        matcher = ScanMatcher(target, self.registration)
        order = np.random.default_rng(self.registration.seed).permutation(source.shape[0])
        above1, above2 = np.ones(points1.shape[0], bool), np.ones(points2.shape[0], bool)
        if not self.preprocess.remove_ground:  # where the ground was split off, the lowest points are objects' bottoms
            low2 = height_above_ground(points2, self.preprocess.ground_cell) < self.preprocess.ground_height
            if shows_ground(matcher, low2):
                above1 = height_above_ground(points1, self.preprocess.ground_cell) >= self.preprocess.ground_height
                above2 = ~low2
        normals = matcher.normals()[: points2.shape[0]] if self.config.plane else None
        every = surfaces_of(points2, normals)
        above = every if above2.all() else surfaces_of(points2[above2], None if normals is None else normals[above2])
        ground1, low, bands = None, None, None
        if self.preprocess.remove_ground:  # whole scans: points on the ground take an object's motion only under it
            ground1 = pair.height1 < self.config.ground_clearance
            low = Plan(pair.pc1, np.flatnonzero(ground1))
            if self.config.end_whole:
                bands = Bands(band_points(pair.pc1, pair.height1, self.preprocess),
                              band_points(pair.pc2, pair.height2, self.preprocess))
        self.state = PairState(key, pair, matcher, source, order, above1, above2, above, every, ground1, low, bands,
                               prior, next_key=fingerprint(pc2))
        if previous is not None and self.config.carry_pairs > 0:  # the stream's previous pair: its motions go on
            self.state.carried = carry_motions(previous, points1, self.config.carry_radius)
        self.states[key] = self.state
        while len(self.states) > PAIR_HISTORY:
            self.states.popitem(last=False)
        return self.state

    def ego_motion(self, state: PairState, dynamic: np.ndarray | None) -> np.ndarray:
        """Ego motion aligned on every point (the robust kernel drops a few movers) and, where the mask calls more than
        `ego_refit` of the points dynamic, aligned without them. The second is taken at once where it is a change of
        the previous pair's motion a vehicle can make (constant velocity vouches for it, `ego_vouch`). Otherwise both
        are aligned: where they agree within `ego_tolerance`, the second (no movers); where they differ, the first,
        unless the second lies nearer the previous pair's ego motion by more than the tolerance, or only the second is
        a change a vehicle can make. A mask that hides static structure and keeps oncoming cars drags the second away
        step by step; traffic moving with the ego pulls the first towards standing still, a jump no vehicle makes
        between two scans."""
        if dynamic is None:  # a question without a mask leaves the stream's motion (the next pair's prior) as it was
            state.ego = self.every_point(state) if state.ego is None else state.ego
            return self.every_point(state)
        share = float(np.mean(dynamic)) if dynamic.size else 0.0
        if np.count_nonzero(dynamic) <= self.config.ego_refit * state.source.shape[0]:
            state.ego = self.every_point(state)
            return state.ego
        keep = np.ones(state.source.shape[0], bool)
        keep[: dynamic.size] = ~dynamic
        masked = state.matcher.align(state.source[state.order[keep[state.order]]], ordered=True, prior=state.prior)
        if self.config.ego_vouch and state.prior is not None and self.plausible(masked, state.prior, share):
            state.ego = masked
            return state.ego
        base = self.every_point(state)
        vouched = motion_gap(masked, base) <= self.config.ego_tolerance or (
            state.prior is not None and self.nearer_prior(masked, base, state.prior, share))
        state.ego = masked if vouched else base
        return state.ego

    def every_point(self, state: PairState) -> np.ndarray:
        """The ego motion aligned on every point of the pair (once per pair)."""
        if state.base_ego is None:
            state.base_ego = state.matcher.align(state.source[state.order], ordered=True, prior=state.prior)
        return state.base_ego

    def plausible(self, motion: np.ndarray, prior: np.ndarray, dynamic_share: float) -> bool:
        """Whether a motion is a change of the previous pair's that a vehicle can make in dt (ego_max_accel), aligned
        while the mask leaves most of the points to it (ego_mask_share)."""
        return (motion_gap(motion, prior) <= self.config.ego_max_accel * self.config.dt ** 2
                and dynamic_share <= self.config.ego_mask_share)

    def nearer_prior(self, masked: np.ndarray, base: np.ndarray, prior: np.ndarray, dynamic_share: float = 0.0) -> bool:
        """Whether the alignment without the mask's dynamic points lies nearer the previous pair's motion than the one
        with every point by more than ego_tolerance, or is alone in being a change a vehicle can make in dt while the
        mask leaves most of the points to it (`dynamic_share`: the share it calls dynamic)."""
        alone_plausible = self.plausible(masked, prior, dynamic_share) and not self.plausible(base, prior, 0.0)
        return motion_gap(masked, prior) + self.config.ego_tolerance < motion_gap(base, prior) or alone_plausible


class Plan:
    """Points of a scan seen from above: which of them lie within a horizontal distance of other points."""

    def __init__(self, points: np.ndarray, index: np.ndarray) -> None:
        self.points, self.index = points, index

    def under(self, above: np.ndarray, reach: float) -> np.ndarray:
        """Indices of the points with one of `above` within `reach` (m) horizontally: in its footprint."""
        if reach <= 0 or len(above) == 0 or len(self.index) == 0:
            return np.zeros(0, np.int64)
        candidates = self.index[may_be_near(above[:, :2], self.points[self.index, :2], reach)]
        gap, _ = cKDTree(above[:, :2]).query(self.points[candidates, :2], distance_upper_bound=np.nextafter(reach, np.inf))
        return candidates[np.isfinite(gap)]


def carry_motions(previous: PairState, points: np.ndarray, radius: float) -> Carried | None:
    """What the previous pair of a stream left on the points of its scan t+1 (this pair's scan t): each point takes the
    own motion and streak of the previous estimate's moving point that landed nearest it, within `radius` (m)."""
    if previous.landed is None or previous.streak is None or previous.proven is None or previous.motion is None:
        return None
    motion, streak, proven = np.zeros((len(points), 3)), np.full(len(points), -1), np.zeros(len(points), np.int64)
    moving = np.flatnonzero(previous.streak >= 0)
    if moving.size and len(points):
        gap, index = cKDTree(previous.landed[moving]).query(points, distance_upper_bound=radius)
        hit = np.isfinite(gap)
        source = moving[index[hit]]
        motion[hit], streak[hit], proven[hit] = previous.motion[source], previous.streak[source], previous.proven[source]
    return Carried(motion, streak, proven)


def shows_ground(matcher: ScanMatcher, low: np.ndarray) -> bool:
    """Whether the lowest points of the sampled scan t+1 lie mostly on level surfaces (a ground), rather than being the
    bottoms of walls and objects of a scan whose ground was cut away."""
    level = np.abs(matcher.normals()[: low.size, 2]) > 0.9
    return bool(low.any() and level[low].mean() > 0.5)


def with_ground(points: np.ndarray, sample: Sample) -> np.ndarray:
    """The sampled points of a scan followed by its ground points kept for the ego registration."""
    return sample.points if sample.ground is None else np.concatenate([sample.points, points[sample.ground]])


class Surfaces(NamedTuple):
    """Points of scan t+1 to register against: their normals (None: point-to-point), a KD-tree, and per point how far
    its nearest neighbour lies off its surface (its roughness)."""

    points: np.ndarray
    normals: np.ndarray | None
    tree: cKDTree
    roughness: np.ndarray


def surfaces_of(points: np.ndarray, normals: np.ndarray | None) -> Surfaces:
    """Searchable surfaces of scan t+1's points."""
    tree = cKDTree(points)
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


def component_count(clusters: Clusters) -> int:
    """Number of joint components the clusters' scan t+1 labels refer to."""
    return int(max(clusters.labels2.max(initial=-1), clusters.parent.max(initial=-1)) + 1)


def initial_translations(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, active: np.ndarray,
                         config: RigidConfig, tree: cKDTree, previous: np.ndarray | None = None,
                         carried: np.ndarray | None = None) -> np.ndarray:
    """Per cluster, the best of: no motion, the centroid shift, the peaks of the displacement histogram, the mean
    motion its points had in the previous estimate on this pair, and the motion carried from the previous pair."""
    count = clusters.count
    picks1 = ranked_per_label(clusters.labels1, active, config.histogram_points, priorities(len(points1)))
    present = np.zeros(component_count(clusters), bool)
    present[clusters.parent[active]] = True
    picks2 = ranked_per_label(clusters.labels2, present, config.histogram_points, priorities(len(points2), 1))
    candidates = [np.zeros((count, 3)), centroid_shift(points1, points2, clusters)]
    if previous is not None:
        candidates.append(label_means(previous, clusters.labels1, count))
    if carried is not None:
        candidates.append(carried)
    if picks1.size and picks2.size:
        candidates += histogram_peaks(points1, points2, clusters, picks1, picks2, config)
    labels = clusters.labels1[picks1]
    shifts = np.stack(candidates)  # (candidates, clusters, 3)
    moved = (points1[picks1][None] + shifts[:, labels]).reshape(-1, 3)
    tries = np.repeat(np.arange(len(candidates)), labels.size) * count + np.tile(labels, len(candidates))
    scores = fit_quality(moved, tries, tree, clusters.labels2, np.tile(clusters.parent[labels], len(candidates)),
                         config, len(candidates) * count).residual
    best = scores.reshape(len(candidates), count).argmin(axis=0)
    return shifts[best, np.arange(count)]


def centroid_shift(points1: np.ndarray, points2: np.ndarray, clusters: Clusters) -> np.ndarray:
    """Per cluster, the horizontal shift between its centroid in scan t and its component's in scan t+1."""
    shift = np.zeros((clusters.count, 3))
    means2 = label_means(points2[:, :2], clusters.labels2, component_count(clusters))
    shift[:, :2] = means2[clusters.parent] - label_means(points1[:, :2], clusters.labels1, clusters.count)
    return shift


def histogram_peaks(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, picks1: np.ndarray,
                    picks2: np.ndarray, config: RigidConfig) -> list[np.ndarray]:
    """Per cluster, the `peaks` most frequent horizontal displacements between its points in the two scans."""
    count = clusters.count
    picks2 = picks2[np.argsort(clusters.labels2[picks2], kind="stable")]
    labels2 = clusters.labels2[picks2]
    wanted = clusters.parent[clusters.labels1[picks1]]
    starts = np.searchsorted(labels2, wanted, side="left")
    lengths = np.searchsorted(labels2, wanted, side="right") - starts
    first = np.repeat(picks1, lengths)
    second = picks2[np.repeat(starts, lengths) + ragged_arange(lengths)]
    displacement = points2[second, :2] - points1[first, :2]
    max_step = config.max_speed * config.dt
    near = np.linalg.norm(displacement, axis=1) <= max_step
    first, displacement = first[near], displacement[near]
    half = int(np.ceil(max_step / config.histogram_bin)) + 1
    width = 2 * half + 1
    cells = np.round(displacement / config.histogram_bin).astype(np.int64) + half
    codes = clusters.labels1[first] * width * width + cells[:, 0] * width + cells[:, 1]
    votes = np.bincount(codes, minlength=count * width * width).reshape(count, width * width)
    rows = np.arange(count)
    peaks = []
    for _ in range(config.histogram_peaks):  # the most voted cell of each cluster (ties: the first), then the next
        cell = votes.argmax(axis=1)
        voted = votes[rows, cell] > 0
        votes[rows, cell] = -1
        shift = np.zeros((count, 3))
        shift[voted, 0] = (cell[voted] // width - half) * config.histogram_bin
        shift[voted, 1] = (cell[voted] % width - half) * config.histogram_bin
        peaks.append(shift)
    return peaks


class Fit(NamedTuple):
    """How well scan t+1 explains each cluster under one motion hypothesis."""

    residual: np.ndarray  # mean distance to the same component in scan t+1, each capped at residual_cap (m)
    plane: np.ndarray  # mean distance to its surfaces (along their normals) over the points near them (m)
    unexplained: np.ndarray  # share of points not near it, or farther than inlier_gate from its surfaces


def surface_distance(moved: np.ndarray, tree: cKDTree, points2: np.ndarray, normals2: np.ndarray | None, cap: float,
                     allowed: np.ndarray | None = None, labels2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the distance to the nearest point of scan t+1 (capped) and to its surface along the normal there
    (NaN where no point lies within the cap); `allowed`: the component each point must land on (labels2: the
    components of scan t+1)."""
    gap, index = tree.query(moved, distance_upper_bound=cap)
    hit = np.isfinite(gap)
    if allowed is not None:
        hit[hit] = labels2[index[hit]] == allowed[hit]
    point = np.where(hit, gap, cap)
    plane = np.full(len(moved), np.nan)
    if normals2 is None:
        plane[hit] = gap[hit]
    else:
        plane[hit] = np.abs(np.einsum("ij,ij->i", moved[hit] - points2[index[hit]], normals2[index[hit]]))
    return point, plane


def fit_quality(moved: np.ndarray, labels: np.ndarray, tree: cKDTree, labels2: np.ndarray, allowed: np.ndarray,
                config: RigidConfig, count: int, normals2: np.ndarray | None = None,
                points2: np.ndarray | None = None) -> Fit:
    """Per label, residuals and unexplained share of its moved points against their component in scan t+1
    (`allowed`: each point's component)."""
    point, plane = surface_distance(moved, tree, points2, normals2, config.residual_cap, allowed, labels2)
    return fit_of(point, plane, labels, count, config)


def fit_of(point: np.ndarray, plane: np.ndarray, labels: np.ndarray, count: int, config: RigidConfig) -> Fit:
    """Per label, the fit of its points' distances to the points and surfaces of scan t+1 (plane NaN: nothing near)."""
    near = np.isfinite(plane)
    sizes = np.maximum(np.bincount(labels, minlength=count), 1)
    return Fit(np.bincount(labels, point, count) / sizes,
               label_means(np.where(near, plane, 0.0), labels, count, near.astype(np.float64)),
               np.bincount(labels, ~near | (np.where(near, plane, 0.0) > config.inlier_gate), count) / sizes)


def cluster_motions(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, config: RigidConfig,
                    belief: np.ndarray | None, normals2: np.ndarray | None, floors: np.ndarray,
                    tree: cKDTree | None = None, candidates: np.ndarray | None = None,
                    previous: np.ndarray | None = None, sensed: np.ndarray | None = None,
                    carried: Carried | None = None, bands: Bands | None = None) -> ClusterMotions:
    """Histogram-initialised batched ICP per cluster; a motion is kept where it explains the points better than
    standing still (as the moved sensor samples a still surface: `sensed`, the points where scan t saw them), and
    standing still misses the surfaces by more than its component's noise floor (`floors`, m); or where both of its
    ends moved alike (a flank sliding along itself) or the previous pair of the stream saw the cluster moving
    (`carried`), and that motion explains them no worse than standing still."""
    count = clusters.count
    yaw, translation = np.zeros(count), np.zeros((count, 3))
    if count == 0 or points1.shape[0] == 0 or points2.shape[0] == 0:
        return ClusterMotions(yaw, translation, np.zeros(count, dtype=bool), np.full(count, -1), np.zeros(count, np.int64))
    sizes1 = label_counts(clusters.labels1, count)
    sizes2 = label_counts(clusters.labels2, component_count(clusters))[clusters.parent]
    sizes = np.minimum(sizes1, sizes2)
    active = (sizes >= config.min_cluster_points) & (label_extents(points1, clusters.labels1, count) <= config.max_extent)
    believed = np.zeros(count, dtype=bool)
    if belief is not None:
        believed = label_means(belief, clusters.labels1, count) > config.mask_threshold
        active |= believed & (sizes >= config.min_masked_points)
    if candidates is not None:
        active &= candidates
    tree = cKDTree(points2) if tree is None else tree
    carry = None if carried is None else carried_motions(clusters, carried, config)
    members = ranked_per_label(clusters.labels1, active, config.icp_points, priorities(len(points1), 2))
    source, labels = points1[members], clusters.labels1[members]
    allowed = clusters.parent[labels]
    floor = floors[clusters.parent]
    counted = np.maximum(label_counts(labels, count), 1)

    def quality(moved: np.ndarray) -> Fit:
        return fit_quality(moved, labels, tree, clusters.labels2, allowed, config, count, normals2, points2)

    # clusters that standing still explains within their noise floor cannot be shown moving by a fitted motion (see
    # `explains`): they are not fitted (their ends, and a carried motion, are still tried below)
    fit = active.copy()
    if config.screen_still and previous is None:
        still = quality(source)
        carried_here = np.zeros(count, bool) if carry is None else carry.present
        fit &= ~(unprovable(still, floor, counted, config) & ~believed & ~carried_here)
    translation = initial_translations(points1, points2, clusters, fit, config, tree, previous,
                                       None if carry is None else carry.translation)
    max_yaw = config.max_yaw_rate * config.dt
    fitting = fit[labels]
    icp_source, icp_labels, icp_allowed = source[fitting], labels[fitting], allowed[fitting]
    for gate in np.geomspace(config.icp_gates[0], config.icp_gates[1], config.icp_iterations):
        moved = yaw_translate(icp_source, yaw[icp_labels], translation[icp_labels])
        gap, index = tree.query(moved, distance_upper_bound=gate)
        good = np.isfinite(gap)
        good[good] = clusters.labels2[index[good]] == icp_allowed[good]
        fitted = np.bincount(icp_labels[good], minlength=count) >= 3
        if normals2 is None:
            new_yaw, new_translation = planar_kabsch(icp_source[good], points2[index[good]], icp_labels[good], count,
                                                     max_yaw)
        else:
            new_yaw, new_translation = planar_plane_step(moved[good], points2[index[good]], normals2[index[good]],
                                                         icp_labels[good], yaw, translation, count, config.point_weight,
                                                         max_yaw)
        yaw[fitted], translation[fitted] = new_yaw[fitted], new_translation[fitted]
    translation[~fit], yaw[~fit] = 0.0, 0.0

    moved = yaw_translate(source, yaw[labels], translation[labels])
    fit_moving = quality(moved)
    if previous is not None:  # the loop never trades a motion for one that fits worse
        yaw, translation, fit_moving = better_of(source, labels, previous[members], yaw, translation, fit_moving,
                                                 quality, max_yaw)
        moved = yaw_translate(source, yaw[labels], translation[labels])
    height = np.column_stack([np.zeros((len(source), 2)), translation[labels, 2]])  # still, but at the height
    fit_static = quality(source + height)
    speed = np.linalg.norm(label_means((moved - source)[:, :2], labels, count), axis=1) / config.dt
    moving = active & (speed > config.min_speed) & explains(fit_moving, fit_static, believed, floor, counted, config)
    ends = np.zeros(count, dtype=bool)  # moved by the shift of their two ends: flanks sliding along themselves
    spare = active & ~moving & (sizes1 >= config.end_points)
    shifted, fit_ends = np.zeros(count, dtype=bool), None
    tried = spare | (moving & (sizes1 >= config.end_points))  # a motion may yet fail as the sensor resamples still
    if config.end_spacings > 0 and tried.any():
        shift = end_shifts(points1, points2, clusters, tried, config, bands)
        shifted = np.linalg.norm(shift[:, :2], axis=1) > config.min_speed * config.dt
        if shifted.any():  # judged on those clusters' points only
            on = shifted[labels]
            fit_ends = fit_quality(yaw_translate(source[on], np.zeros(np.count_nonzero(on)), shift[labels[on]]),
                                   labels[on], tree, clusters.labels2, allowed[on], config, count, normals2, points2)
            ends = spare & shifted & no_worse(fit_ends, fit_static, floor, config, config.end_slack)
            yaw, translation = np.where(ends, 0.0, yaw), np.where(ends[:, None], shift, translation)
            fit_moving = Fit(*(np.where(ends, mine, theirs) for mine, theirs in zip(fit_ends, fit_moving)))
    continued = np.zeros(count, dtype=bool)
    if carry is not None and (carry.usable & active & ~moving & ~ends).any():
        continued, yaw, translation, fit_moving = continue_carried(
            source, labels, carry, active & ~moving & ~ends, yaw, translation, fit_moving, fit_static, floor, config,
            quality)
    if sensed is not None and (moving | continued | ends).any():  # standing still once more, as the sensor samples it
        either = moving | continued | ends
        check = either[labels]
        resampled = static_fit(source[check] + height[check], sensed[members][check] + height[check], labels[check],
                               tree, clusters.labels2, allowed[check], config, count, normals2, points2,
                               floors[allowed][check])
        fit_static = Fit(*(np.where(either, again, first) for again, first in zip(resampled, fit_static)))
        fitted = moving.copy()
        moving &= explains(fit_moving, fit_static, believed, floor, counted, config)
        continued &= no_worse(fit_moving, fit_static, floor, config)
        ends &= no_worse(fit_moving, fit_static, floor, config, config.end_slack)
        if fit_ends is not None:  # a fitted motion the resampling explains away: its ends may still have moved
            rescued = fitted & ~moving & shifted & no_worse(fit_ends, fit_static, floor, config, config.end_slack)
            yaw, translation = np.where(rescued, 0.0, yaw), np.where(rescued[:, None], shift, translation)
            ends |= rescued
    moving |= ends
    streak, proven = np.where(moving, 0, -1), moving.astype(np.int64)  # a first sighting, or still
    if carry is not None:  # a motion seen before: one more pair that proved it, or one more carried
        streak = np.where(continued, carry.streak + 1, streak)
        proven = np.where(continued, carry.proven, np.where(moving & carry.present, carry.proven + 1, proven))
    moving |= continued
    yaw[~moving], translation[~moving] = 0.0, 0.0
    return ClusterMotions(yaw, translation, moving, streak, proven)


def end_shifts(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, candidates: np.ndarray,
               config: RigidConfig, bands: Bands | None = None) -> np.ndarray:
    """Per candidate cluster alone in its component, the shift along its main horizontal axis by which both of its ends
    moved from scan t to scan t+1, where the two agree within end_agreement and the shift is end_spacings times its
    sampling spacing or more (zero elsewhere): a flank's ends, where its sides say nothing. With the whole scans'
    `bands`, the ends and the spacing are those of all the points within a sampling spacing of the cluster's."""
    count = clusters.count
    shift = np.zeros((count, 3))
    alone = candidates & (np.bincount(clusters.parent, minlength=component_count(clusters)) == 1)[clusters.parent]
    on1 = (clusters.labels1 >= 0) & alone[np.maximum(clusters.labels1, 0)]
    if not on1.any():
        return shift
    cluster_of = np.full(component_count(clusters), -1)  # each component's only cluster
    cluster_of[clusters.parent[alone]] = np.flatnonzero(alone)
    on2 = (clusters.labels2 >= 0) & (cluster_of[np.maximum(clusters.labels2, 0)] >= 0)
    labels1, labels2 = clusters.labels1[on1], cluster_of[clusters.labels2[on2]]
    axis = label_main_axes(points1[on1, :2], labels1, count)
    along1, along2 = (np.einsum("ij,ij->i", points[:, :2], axis[labels]) for points, labels in
                      ((points1[on1], labels1), (points2[on2], labels2)))
    low1, high1 = label_spans(along1, labels1, count)
    low2, high2 = label_spans(along2, labels2, count)
    bottom, top = label_spans(points1[on1, 2], labels1, count)
    with np.errstate(invalid="ignore"):  # empty labels: inf - inf
        # a flank of length L and height H sampled with n points has them about sqrt(L H / n) apart
        spacing = np.sqrt((high1 - low1) * np.maximum(top - bottom, FLAT_HEIGHT) / np.maximum(label_counts(labels1, count), 1))
        if bands is not None:  # the sample's outermost points lie up to a spacing from the ends
            reach = np.where(np.isfinite(spacing), np.minimum(spacing, config.cluster_voxel), 0.0)
            low1, high1, denser = band_ends(bands.points1, points1[on1], labels1, along1, low1, high1, axis, reach)
            low2, high2, _ = band_ends(bands.points2, points2[on2], labels2, along2, low2, high2, axis, reach)
            spacing = spacing / np.sqrt(np.maximum(denser, 1.0))
        lows, highs = low2 - low1, high2 - high1
        middle = 0.5 * (lows + highs)
        agree = (alone & np.isfinite(middle) & (np.abs(lows - highs) <= config.end_agreement * np.abs(middle))
                 & (np.abs(middle) >= config.end_spacings * spacing))
    if agree.any():  # a window through a gap between nearer things slides along a wall as the sensor moves: not ends
        agree[agree] = ~hidden_ends(points2, on2, labels2, axis, np.flatnonzero(agree), spacing, config.end_occlusion)
    shift[agree, :2] = middle[agree, None] * axis[agree]
    return shift


def band_ends(band: np.ndarray, sampled: np.ndarray, labels: np.ndarray, along: np.ndarray, low: np.ndarray,
              high: np.ndarray, axis: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per label, where along its axis the band's points within `reach` of its sampled points near either end (two
    reaches from it or less) end, and how many band points lie there per such sampled point (the ends found in the
    sample, inf and -inf, and zero where none lie there)."""
    count = len(low)
    outer = (along <= low[labels] + 2.0 * reach[labels]) | (along >= high[labels] - 2.0 * reach[labels])
    sampled, labels = sampled[outer], labels[outer]
    cap = max(float(reach.max(initial=0.0)), 1e-9)
    near = np.flatnonzero(may_be_near(sampled, band, cap))
    gap, index = cKDTree(sampled).query(band[near], distance_upper_bound=cap)
    found = np.isfinite(gap)
    label = labels[index[found]]
    inside = gap[found] <= reach[label]
    points, label = band[near[found][inside]], label[inside]
    ends_low, ends_high = label_spans(np.einsum("ij,ij->i", points[:, :2], axis[label]), label, count)
    seen = label_counts(label, count) > 0
    density = label_counts(label, count) / np.maximum(label_counts(labels, count), 1)
    return np.where(seen, ends_low, low), np.where(seen, ends_high, high), density


def band_points(points: np.ndarray, height: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """A whole scan's points above the ground and below object_height (all above the ground where that is 0)."""
    return points[(height >= config.ground_height) & (height < object_top(config))]


def hidden_ends(points2: np.ndarray, on2: np.ndarray, labels2: np.ndarray, axis: np.ndarray, clusters: np.ndarray,
                spacing: np.ndarray, margin: float) -> np.ndarray:
    """Per given cluster, whether either end of its points in scan t+1 (`points2[on2]`, labelled `labels2`) along its
    axis has points of scan t+1 nearer the sensor by `margin` within three sampling spacings of it in azimuth."""
    azimuth2 = np.arctan2(points2[:, 1], points2[:, 0])
    range2 = np.hypot(points2[:, 0], points2[:, 1])
    own = np.flatnonzero(on2)
    hidden = np.zeros(len(clusters), dtype=bool)
    for row, cluster in enumerate(clusters):
        members = own[labels2 == cluster]
        along = points2[members, :2] @ axis[cluster]
        for end in members[[np.argmin(along), np.argmax(along)]]:
            window = 3.0 * spacing[cluster] / max(range2[end], 1e-6)
            beside = np.abs(np.angle(np.exp(1j * (azimuth2 - azimuth2[end])))) <= window
            beside[members] = False
            hidden[row] |= bool(np.any(beside & (range2 < range2[end] - margin)))
    return hidden


def carried_motions(clusters: Clusters, carried: Carried, config: RigidConfig) -> CarriedMotions:
    """Per cluster, the mean motion its points carry from the previous pair (where enough of them carry one), the
    longest streak and proof among them, and whether it may be carried on (not carried carry_pairs already, proven
    by carry_proven pairs)."""
    count = clusters.count
    live = carried.streak >= 0
    present = label_means(live.astype(np.float64), clusters.labels1, count) >= config.carry_share
    translation = label_means(carried.motion, clusters.labels1, count, live.astype(np.float64))
    translation[~present] = 0.0
    streak, proven = np.full(count, -1), np.zeros(count, np.int64)
    np.maximum.at(streak, clusters.labels1, np.where(live, carried.streak, -1))
    np.maximum.at(proven, clusters.labels1, np.where(live, carried.proven, 0))
    usable = present & (streak < config.carry_pairs) & (proven >= config.carry_proven)
    return CarriedMotions(translation, present, usable, streak, proven)


def continue_carried(source: np.ndarray, labels: np.ndarray, carry: CarriedMotions, candidates: np.ndarray,
                     yaw: np.ndarray, translation: np.ndarray, fit_moving: Fit, fit_static: Fit, floor: np.ndarray,
                     config: RigidConfig, quality) -> tuple[np.ndarray, np.ndarray, np.ndarray, Fit]:
    """Among the candidate clusters (not shown moving by this pair), those that keep their carried motion: it (or
    their own fitted motion, where the two agree) explains scan t+1 no worse than standing still and is no slower
    than min_speed. Returns them, and the yaw, translation and fit with their motions put in."""
    fit_carried = quality(yaw_translate(source, np.zeros(len(source)), carry.translation[labels]))
    own = ((np.linalg.norm(translation - carry.translation, axis=1) <= config.carry_tolerance)
           & (fit_moving.plane + fit_moving.residual <= fit_carried.plane + fit_carried.residual))
    chosen = Fit(*(np.where(own, mine, theirs) for mine, theirs in zip(fit_moving, fit_carried)))
    step = np.where(own[:, None], translation, carry.translation)
    fast = np.linalg.norm(step[:, :2], axis=1) > config.min_speed * config.dt
    kept = candidates & carry.usable & fast & no_worse(chosen, fit_static, floor, config)
    return (kept, np.where(kept & ~own, 0.0, yaw), np.where(kept[:, None], step, translation),
            Fit(*(np.where(kept, mine, theirs) for mine, theirs in zip(chosen, fit_moving))))


def no_worse(fit_moving: Fit, fit_static: Fit, floor: np.ndarray, config: RigidConfig, slack: float = 0.0) -> np.ndarray:
    """Per cluster, whether its motion lays it on the surfaces of scan t+1 (within the noise floor) and near its
    points no worse than standing still (by more than the `slack` share), and explains all but max_unexplained of it."""
    allowed = 1.0 + slack
    return ((fit_moving.plane <= allowed * np.maximum(fit_static.plane, floor))
            & (fit_moving.residual <= allowed * fit_static.residual) & (fit_moving.unexplained <= config.max_unexplained))


def unprovable(fit_static: Fit, floor: np.ndarray, counted: np.ndarray, config: RigidConfig) -> np.ndarray:
    """Per cluster, whether no motion could be proven by `explains` (without the mask's belief): standing still misses
    the surfaces by no more than the noise floor, and leaves too few of its points unexplained for a motion to explain
    min_explained_gain of them newly."""
    margin = 1.0 + np.sqrt(config.min_cluster_points / counted)
    return (fit_static.plane <= floor * margin) & (fit_static.unexplained < config.min_explained_gain)


def explains(fit_moving: Fit, fit_static: Fit, believed: np.ndarray, floor: np.ndarray, counted: np.ndarray,
             config: RigidConfig) -> np.ndarray:
    """Per cluster, whether its motion explains scan t+1 better than standing still (`floor`: its noise floor, m;
    `counted`: its points in the fits; `believed`: the mask calls it dynamic)."""
    keep = np.where(believed, 1.0 - config.mask_gain, 1.0 - config.min_gain)
    keep_point = np.where(believed, 1.0 - config.mask_gain, 1.0 - config.min_point_gain)
    margin = np.where(believed, 1.0, 1.0 + np.sqrt(config.min_cluster_points / counted))  # few points: wider margin
    misfit = fit_static.plane > floor * margin  # unless the mask already calls the cluster dynamic
    closer = fit_moving.residual < (1.0 - config.support_gain) * fit_static.residual  # not just sliding along planes
    proven = ((misfit & (((fit_moving.plane < keep * fit_static.plane) & closer)
                         | (fit_moving.residual < keep_point * fit_static.residual)))
              | (fit_static.unexplained - fit_moving.unexplained >= config.min_explained_gain))
    return no_worse(fit_moving, fit_static, floor, config) & proven


def static_fit(still: np.ndarray, sensed: np.ndarray, labels: np.ndarray, tree: cKDTree, labels2: np.ndarray,
               allowed: np.ndarray, config: RigidConfig, count: int, normals2: np.ndarray | None,
               points2: np.ndarray, floor: np.ndarray) -> Fit:
    """How well standing still, as the moved sensor samples it again (`sensed`: the points as scan t saw them), explains
    each cluster (`floor`: each point's noise floor, m)."""
    point, plane = surface_distance(still, tree, points2, normals2, config.residual_cap, allowed, labels2)
    if len(points2) < 2:
        return fit_of(point, plane, labels, count, config)
    # the sensor slid along the surfaces (standing still leaves most of the cluster on them, unlike a car ahead at the
    # ego's speed) and scan t+1 samples them along the slide no finer than half of it (far walls at grazing angles,
    # unlike a car beside us at the ego's speed; and coarser than resample_spacing, unlike a car's flank moving with a
    # crawling ego): there its beams land on a still surface's points up to a slide away
    resampled, resampled_plane = surface_distance(sensed, tree, points2, normals2, config.residual_cap, allowed,
                                                  labels2)
    slide = np.linalg.norm(sensed - still, axis=1)
    on_surface = np.nan_to_num(plane, nan=np.inf) < 0.5 * slide
    spacing = spacing_along(points2, tree, tree.query(still)[1], (sensed - still) / np.maximum(slide, 1e-9)[:, None])
    slid = ((spacing >= np.maximum(0.5 * slide, config.resample_spacing))
            & (label_means(on_surface.astype(np.float64), labels, count) > 0.5)[labels])
    # each point where it was, or where the beam that saw it lands again if that lies closer to the points of scan
    # t+1 and no farther from its surfaces (beyond the noise floor)
    along = slid & (resampled < point) & (np.nan_to_num(resampled_plane, nan=np.inf)
                                          <= np.maximum(np.nan_to_num(plane, nan=np.inf), floor))
    point, plane = np.where(along, resampled, point), np.where(along, resampled_plane, plane)
    # in clusters the resampling explains, a beam that now finds nothing passed the surface's end: no evidence
    passed = ((label_means(along.astype(np.float64), labels, count) >= 0.5)[labels] & np.isnan(resampled_plane)
              & ~(plane <= config.inlier_gate))
    return fit_of(point, np.where(passed, 0.0, plane), labels, count, config)


def spacing_along(points: np.ndarray, tree: cKDTree, index: np.ndarray, direction: np.ndarray,
                  neighbours: int = 8) -> np.ndarray:
    """Per query, how far the points of the tree lie apart along `direction` at points[index]: the distance to the
    nearest of its neighbours within 45 degrees of that direction (either way), else to the farthest neighbour."""
    gaps, near = tree.query(points[index], k=min(neighbours + 1, len(points)))
    offsets = points[near[:, 1:]] - points[index][:, None]
    aligned = np.abs(np.einsum("nkj,nj->nk", offsets, direction)) >= np.sqrt(0.5) * gaps[:, 1:]
    return np.where(aligned.any(axis=1), np.where(aligned, gaps[:, 1:], np.inf).min(axis=1), gaps[:, -1])


def better_of(source: np.ndarray, labels: np.ndarray, previous: np.ndarray, yaw: np.ndarray, translation: np.ndarray,
              fit: Fit, quality, max_yaw: float) -> tuple[np.ndarray, np.ndarray, Fit]:
    """Per cluster, the new motion or the one its points had before (as a planar rigid fit of their displacements),
    whichever lies closer to scan t+1 (surface plus point distance)."""
    count = yaw.size
    old_yaw, old_translation = planar_kabsch(source, source + previous, labels, count, max_yaw)
    old_fit = quality(yaw_translate(source, old_yaw[labels], old_translation[labels]))
    moved_before = label_means(np.abs(previous).sum(axis=1), labels, count) > 0
    keep = moved_before & (old_fit.plane + old_fit.residual < fit.plane + fit.residual)
    chosen = Fit(*(np.where(keep, old, new) for old, new in zip(old_fit, fit)))
    return np.where(keep, old_yaw, yaw), np.where(keep[:, None], old_translation, translation), chosen


def split_motions(points1: np.ndarray, surfaces: Surfaces, clusters: Clusters, config: RigidConfig,
                  belief: np.ndarray | None, previous: np.ndarray | None = None,
                  sensed: np.ndarray | None = None, carried: Carried | None = None,
                  bands: Bands | None = None) -> tuple[Clusters, ClusterMotions]:
    """Motions of the clusters; then components whose clusters stay still although enough of their points miss the
    surfaces of scan t+1 are clustered with the finer voxel, and their pieces get motions of their own (`sensed`:
    the points as scan t saw them, before the ego compensation)."""
    points2, normals2, tree = surfaces.points, surfaces.normals, surfaces.tree
    _, still = surface_distance(points1, tree, points2, normals2, config.residual_cap,
                                clusters.parent[clusters.labels1], clusters.labels2)
    near = np.isfinite(still)
    floors = noise_floors(surfaces, clusters, float(np.median(still[near])) if near.any() else 0.0, config)
    still = np.where(near, still, 0.0)  # points with nothing near them say nothing
    motions = cluster_motions(points1, points2, clusters, config, belief, normals2, floors, tree, previous=previous,
                              sensed=sensed, carried=carried, bands=bands)
    if config.split_voxel <= 0 or clusters.count == 0:
        return clusters, motions
    changed = still > floors[clusters.parent[clusters.labels1]]
    changed_clusters = label_counts(clusters.labels1[changed], clusters.count) >= config.min_cluster_points
    components = np.unique(clusters.parent[changed_clusters & ~motions.moving])
    if components.size == 0:
        return clusters, motions
    inside1 = np.isin(clusters.parent[clusters.labels1], components)
    inside2 = np.isin(clusters.labels2, components)
    pieces = joint_clusters(points1[inside1], points2[inside2], config.split_voxel,
                            None if belief is None else belief[inside1] > config.mask_threshold)
    offset, component_offset = clusters.count, component_count(clusters)
    labels1, labels2 = clusters.labels1.copy(), clusters.labels2.copy()
    labels1[inside1] = pieces.labels1 + offset
    labels2[inside2] = pieces.labels2 + component_offset
    split = Clusters(labels1, labels2, offset + pieces.count,
                     np.concatenate([clusters.parent, pieces.parent + component_offset]))
    origin = np.zeros(component_count(pieces), np.int64)  # the component each piece was cut from
    origin[pieces.parent[pieces.labels1]] = clusters.parent[clusters.labels1[inside1]]
    floors = np.concatenate([floors, floors[origin]])
    # pieces are tried only where they miss the surfaces of their whole component, not just of their own piece
    fresh = (np.arange(split.count) >= offset) & (
        label_means(still, split.labels1, split.count, near.astype(np.float64)) > floors[split.parent])
    more = cluster_motions(points1, points2, split, config, belief, normals2, floors, tree, fresh, previous, sensed,
                           carried, bands)
    return split, ClusterMotions(np.where(fresh, more.yaw, np.pad(motions.yaw, (0, pieces.count))),
                                 np.where(fresh[:, None], more.translation, np.pad(motions.translation, ((0, pieces.count), (0, 0)))),
                                 np.where(fresh, more.moving, np.pad(motions.moving, (0, pieces.count))),
                                 np.where(fresh, more.carried, np.pad(motions.carried, (0, pieces.count), constant_values=-1)),
                                 np.where(fresh, more.proven, np.pad(motions.proven, (0, pieces.count))))


def noise_floors(surfaces: Surfaces, clusters: Clusters, noise: float, config: RigidConfig) -> np.ndarray:
    """Per component, the miss (m) below which standing still explains it: the scene's median miss, the component's
    own roughness (the median distance of scan t+1's points from their neighbours' surfaces) and half a step at
    min_speed."""
    rough = label_quantiles(surfaces.roughness, clusters.labels2, component_count(clusters), 0.5)
    return np.maximum(config.surface_noise * np.maximum(rough, noise), 0.5 * config.min_speed * config.dt)


def attach_to_moving(points: np.ndarray, clustered: np.ndarray, labels: np.ndarray, motions: ClusterMotions,
                     surfaces: Surfaces, config: RigidConfig) -> np.ndarray:
    """Label of the moving cluster within attach_distance of each point, where that cluster's motion brings the point
    onto the surfaces of scan t+1 clearly better than standing still (-1 elsewhere)."""
    attached = np.full(points.shape[0], -1)
    on_moving = (labels >= 0) & motions.moving[np.maximum(labels, 0)]
    points2, normals, tree = surfaces.points, surfaces.normals, surfaces.tree
    if not on_moving.any() or points.shape[0] == 0 or points2.shape[0] == 0:
        return attached
    gap, index = cKDTree(clustered[on_moving]).query(points, distance_upper_bound=config.attach_distance)
    near = np.flatnonzero(np.isfinite(gap))
    if near.size == 0:
        return attached
    cluster = labels[on_moving][index[near]]
    moved = yaw_translate(points[near], motions.yaw[cluster], motions.translation[cluster])
    still = np.nan_to_num(surface_distance(points[near], tree, points2, normals, config.residual_cap)[1],
                          nan=config.residual_cap)
    carried = np.nan_to_num(surface_distance(moved, tree, points2, normals, config.residual_cap)[1],
                            nan=config.residual_cap)
    better = (carried < (1.0 - config.min_gain) * still) & (still - carried > 0.5 * config.min_speed * config.dt)
    attached[near[better]] = cluster[better]
    return attached


def apply_motions(points: np.ndarray, labels: np.ndarray, motions: ClusterMotions) -> np.ndarray:
    """Move each clustered point with its cluster's motion."""
    moved = points.copy()
    on = labels >= 0
    moved[on] = yaw_translate(points[on], motions.yaw[labels[on]], motions.translation[labels[on]])
    return moved.astype(np.float32)
