"""What one scan pair keeps across the fusion loop's calls: samples, surfaces, ground split and the ego fit's points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ssf_common.geometry.neighbours import may_be_near
from ssf_flow_node.core.base import FlowResult, PreparedPair
from ssf_flow_node.core.preprocess import Sample
from ssf_flow_node.core.registration import ScanMatcher
from ssf_flow_node.core.rigid.carry import Carried
from ssf_flow_node.core.rigid.clusters import Surfaces
from ssf_flow_node.core.rigid.ends import Bands

PAIR_HISTORY = 3  # pairs whose work is kept: the loop's next iteration on a pair may come after the next pair


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
    low: TopView | None  # those points seen from above
    bands: Bands | None  # the whole scans' non-ground points below object_height (scan t as sensed)
    prior: np.ndarray | None = None  # the pair's measured ego motion, else the previous pair's (constant velocity)
    measured: np.ndarray | None = None  # the pair's ego motion as the vehicle measured it, where it did
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


class TopView:
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


def shows_ground(matcher: ScanMatcher, low: np.ndarray) -> bool:
    """Whether the lowest points of the sampled scan t+1 lie mostly on level surfaces (a ground), rather than being the
    bottoms of walls and objects of a scan whose ground was cut away."""
    level = np.abs(matcher.normals()[: low.size, 2]) > 0.9
    return bool(low.any() and level[low].mean() > 0.5)


def with_ground(points: np.ndarray, sample: Sample) -> np.ndarray:
    """The sampled points of a scan followed by its ground points kept for the ego registration."""
    return sample.points if sample.ground is None else np.concatenate([sample.points, points[sample.ground]])
