"""The learning-free real-time estimator (ICP-Flow-like): ego motion, clusters, per-cluster rigid motion, every point
moved."""

from __future__ import annotations

import collections

import numpy as np

from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.se3 import transform_points
from ssf_flow_node.core.base import FlowResult, ScanCache, fingerprint, finish, prepare
from ssf_flow_node.core.preprocess import PreprocessConfig, check_mask
from ssf_flow_node.core.registration import RegistrationConfig, ScanMatcher
from ssf_flow_node.core.rigid.carry import Carried, carry_motions
from ssf_flow_node.core.rigid.clusters import joint_clusters, surfaces_of
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.ego import pair_ego_motion
from ssf_flow_node.core.rigid.ends import Bands, band_points
from ssf_flow_node.core.rigid.motions import apply_motions, attach_to_moving, split_motions
from ssf_flow_node.core.rigid.pair import PAIR_HISTORY, PairState, TopView, shows_ground, with_ground


class RigidFlowEstimator:
    """Ego motion by robust ICP, then rigid motions of clusters of the non-ground points."""

    name = "rigid"
    takes_measured = True  # the pair's measured ego motion, where given, stands in for the previous pair's

    def __init__(self, preprocess: PreprocessConfig, registration: RegistrationConfig, config: RigidConfig) -> None:
        self.preprocess = preprocess
        self.registration = registration
        self.config = config
        self.state: PairState | None = None  # the pair asked about last
        self.states: collections.OrderedDict[bytes, PairState] = collections.OrderedDict()  # the last few pairs
        self.scans = ScanCache(preprocess)

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None,
                 measured: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; the ego motion is also aligned without the mask's dynamic points, and clusters the
        mask calls dynamic need fewer points and less evidence to move. measured: the pair's ego motion as the vehicle
        measured it (wheel speed, gyro): the alignment's prior and judge, where the previous pair's motion is else."""
        state = self.pair_state(pc1, pc2, measured)
        pair = state.pair
        masked = None if mask is None else check_mask(mask, pair.pc1.shape[0])[pair.sample1.indices]
        points1, points2 = pair.sample1.points, pair.sample2.points
        dynamic = None if masked is None else masked > self.config.mask_threshold
        if dynamic is not None and state.result is not None and np.array_equal(dynamic, state.moved):
            return state.result  # the mask calls dynamic just what the last estimate moved: nothing new to use
        above1, above2 = state.above1, state.above2
        # 1. ego motion from every point and from the mask's static ones; where they differ, constant velocity judges
        ego = pair_ego_motion(state, dynamic, self.config)
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

    def get_ready(self, pc1: np.ndarray, pc2: np.ndarray, measured: np.ndarray | None = None) -> None:
        """The pair's work that needs no mask (samples, ground split, surfaces, normals), done now and kept."""
        self.pair_state(pc1, pc2, measured)

    def pair_state(self, pc1: np.ndarray, pc2: np.ndarray, measured: np.ndarray | None = None) -> PairState:
        """The cached work on this pair of scans (the fusion loop asks for the same pair again), or a fresh one."""
        key = fingerprint(pc1, pc2)
        if key in self.states:  # the loop asks again, perhaps after the stream's next pair (a node's mask hint)
            self.states.move_to_end(key)
            self.state = self.states[key]
            return self.state
        first = fingerprint(pc1)
        previous = next((state for state in reversed(self.states.values()) if state.next_key == first), None)
        latest = previous or self.state
        prior = np.asarray(measured, np.float64) if measured is not None else None if latest is None else latest.ego
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
            low = TopView(pair.pc1, np.flatnonzero(ground1))
            if self.config.end_whole:
                bands = Bands(band_points(pair.pc1, pair.height1, self.preprocess),
                              band_points(pair.pc2, pair.height2, self.preprocess))
        self.state = PairState(key, pair, matcher, source, order, above1, above2, above, every, ground1, low, bands,
                               prior, None if measured is None else prior, next_key=fingerprint(pc2))
        if previous is not None and self.config.carry_pairs > 0 and previous.landed is not None:  # its motions go on
            left = Carried(previous.motion, previous.streak, previous.proven)
            self.state.carried = carry_motions(left, previous.landed, points1, self.config.carry_radius)
        self.states[key] = self.state
        while len(self.states) > PAIR_HISTORY:
            self.states.popitem(last=False)
        return self.state
