"""Carry-back along a stream: a motion one pair proved, kept while the next pairs cannot tell it from standing still."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.labels import label_means
from ssf_common.geometry.neighbours import PointIndex, may_be_near
from ssf_common.geometry.se3 import yaw_translate
from ssf_flow_node.core.rigid.clusters import Clusters
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.fits import Fit, no_worse


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


def carry_motions(left: Carried, landed: np.ndarray, points: np.ndarray, radius: float) -> Carried:
    """What the previous pair of a stream left on the points of its scan t+1 (this pair's scan t): each point takes the
    own motion and streak of the previous estimate's moving point (`left`, at `landed`, the points as the previous
    estimate moved them) that landed nearest it, within `radius` (m)."""
    motion, streak, proven = np.zeros((len(points), 3)), np.full(len(points), -1), np.zeros(len(points), np.int64)
    moving = np.flatnonzero(left.streak >= 0)
    near = np.flatnonzero(may_be_near(landed[moving], points, radius)) if moving.size else moving
    if near.size:  # the few points near the movers, not the whole scan, are searched
        gap, index = PointIndex(landed[moving]).query(points[near], distance_upper_bound=radius)
        hit = np.isfinite(gap)
        source = moving[index[hit]]
        near = near[hit]
        motion[near], streak[near], proven[near] = left.motion[source], left.streak[source], left.proven[source]
    return Carried(motion, streak, proven)


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
    fast = np.linalg.norm(step[:, :2], axis=1) > config.min_speed * config.scan_period
    kept = candidates & carry.usable & fast & no_worse(chosen, fit_static, floor, config)
    return (kept, np.where(kept & ~own, 0.0, yaw), np.where(kept[:, None], step, translation),
            Fit(*(np.where(kept, mine, theirs) for mine, theirs in zip(chosen, fit_moving))))
