"""In a stream of scans, an object seen moving keeps its motion where one pair cannot tell it from standing still.

A car's flank sliding along itself stays on its own plane: one pair proves its motion only at its ends, and where
they are hidden (a car beside the ego, seen side on) standing still explains the pair as well as the motion. The
previous pairs of the stream saw the car moving, and no car stops within a tenth of a second: its carried motion
stands while it explains the pair no worse than standing still, for a bounded number of pairs, and only once two
pairs proved it on their own evidence."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_flow_node.core.estimator import FlowConfig, make_estimator
from ssf_flow_node.core.rigid.carry import Carried
from ssf_flow_node.core.rigid.clusters import Clusters
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.motions import cluster_motions

STEP = np.array([0.35, 0.0, 0.0])  # 3.5 m/s along the flank, over one 0.1 s pair
FLOOR = 0.05  # the flank's noise floor (m): standing still misses its surfaces by less


def flank(offset: float, rng: np.random.Generator, bump: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals of a 4.5 m flank whose ends lie outside the view (always the same window of it, x 0..4.5,
    at y = 4), with a mirror (a 0.2 m box) that moves with it, `offset` metres along it."""
    count = 400
    x, z = rng.uniform(0.0, 4.5, count), rng.uniform(0.3, 1.5, count)
    points = [np.column_stack([x, np.full(count, 4.0), z])]
    normals = [np.tile([0.0, -1.0, 0.0], (count, 1))]
    if bump:  # the mirror's face towards the sensor and its two ends
        face = rng.uniform(0.0, 1.0, (40, 2))
        points.append(np.column_stack([2.0 + offset + 0.2 * face[:, 0], np.full(40, 3.8), 1.0 + 0.2 * face[:, 1]]))
        normals.append(np.tile([0.0, -1.0, 0.0], (40, 1)))
        for end, sign in ((2.0, -1.0), (2.2, 1.0)):
            side = rng.uniform(0.0, 1.0, (20, 2))
            points.append(np.column_stack([np.full(20, end + offset), 3.8 + 0.2 * side[:, 0], 1.0 + 0.2 * side[:, 1]]))
            normals.append(np.tile([sign, 0.0, 0.0], (20, 1)))
    return np.concatenate(points), np.concatenate(normals)


def motions(step: np.ndarray, carried_motion: np.ndarray | None, streak: int = 0, proven: int = 2,
            config: RigidConfig | None = None):
    """What cluster_motions makes of the flank moved by `step` between the scans, given a motion carried from the
    previous pair (None: a pair on its own)."""
    rng = np.random.default_rng(4)
    points1, _ = flank(0.0, rng)
    points2, normals2 = flank(float(step[0]), rng)
    clusters = Clusters(np.zeros(len(points1), np.int64), np.zeros(len(points2), np.int64), 1, np.array([0]))
    carried = None if carried_motion is None else Carried(
        np.tile(carried_motion, (len(points1), 1)), np.full(len(points1), streak), np.full(len(points1), proven))
    return cluster_motions(points1, points2, clusters, config or RigidConfig(), None, normals2, np.full(1, FLOOR),
                           carried=carried)


def test_one_pair_cannot_tell_a_flank_sliding_along_itself_from_standing_still():
    alone = motions(STEP, None)
    assert not alone.moving[0] and alone.carried[0] == -1 and alone.proven[0] == 0


def test_the_carried_motion_stands_where_it_explains_the_pair_no_worse():
    kept = motions(STEP, STEP)
    assert kept.moving[0]
    assert np.linalg.norm(kept.translation[0] - STEP) < 0.1
    assert kept.carried[0] == 1 and kept.proven[0] == 2  # carried one more pair, proven by two


@pytest.mark.parametrize("streak, proven", [(10, 5), (0, 1)])
def test_a_motion_is_carried_neither_too_long_nor_before_two_pairs_proved_it(streak, proven):
    """carry_pairs (10) pairs carried already; or one pair's evidence only, which a phantom also has."""
    assert not motions(STEP, STEP, streak=streak, proven=proven).moving[0]


def test_carrying_can_be_switched_off():
    assert not motions(STEP, STEP, config=RigidConfig(carry_pairs=0)).moving[0]


@pytest.mark.parametrize("carried_motion", [STEP, np.array([0.0, -0.35, 0.0])])
def test_a_still_object_refutes_a_carried_motion(carried_motion):
    """Along the flank the mirror stays behind, across it the flank leaves its plane: standing still explains the
    pair better, and the motion is not carried."""
    still = motions(np.zeros(3), carried_motion)
    assert not still.moving[0] and np.all(still.translation == 0.0)


def test_the_estimator_carries_motions_only_between_the_pairs_of_a_stream():
    pair = synthetic_pair(seed=1, agents=2, ego_step=1.0)
    estimator = make_estimator("rigid", build(FlowConfig, {}))
    estimator.estimate(pair.pc1, pair.pc2)
    first = estimator.state
    assert first.carried is None  # nothing came before
    moved_boxes = first.streak >= 0
    boxes = np.isin(pair.instance1[first.pair.sample1.indices], (1, 2))
    assert moved_boxes[boxes].mean() > 0.9 and moved_boxes[~boxes].mean() < 0.01  # the boxes (and a few points at their feet)
    assert np.all(first.proven[moved_boxes] == 1) and np.all(first.streak[moved_boxes] == 0)
    estimator.estimate(pair.pc2, pair.pc1)  # the next pair starts with the last one's scan t+1
    second = estimator.state
    assert second.carried is not None and (second.carried.streak >= 0).any()
    estimator.estimate(pair.pc1, pair.pc2, np.zeros(len(pair.pc1)))  # the loop's next iteration on the first pair
    assert estimator.state is first  # its work is kept, whatever came in between
    estimator.estimate(pair.pc2, pair.pc1)
    assert estimator.state is second
    other = synthetic_pair(seed=2, agents=2, ego_step=1.0)
    estimator.estimate(other.pc1, other.pc2)  # not the stream's next pair: nothing is carried
    assert estimator.state.carried is None
