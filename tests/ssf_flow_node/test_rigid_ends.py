"""A flank sliding along itself: its sides fit standing still as well as its motion, its two ends do not."""

from __future__ import annotations

import numpy as np

from ssf_flow_node.core.rigid.clusters import Clusters
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.ends import Bands
from ssf_flow_node.core.rigid.motions import cluster_motions


def flank(start: float, length: float, spacing: float) -> np.ndarray:
    """Points of a car's side 3 m to the left, 1.5 m tall, on a grid `spacing` apart from x = start."""
    x = np.arange(start, start + length + 1e-9, spacing)
    z = np.arange(-1.5, 1e-9, spacing)
    grid = np.stack(np.meshgrid(x, z, indexing="ij"), axis=-1).reshape(-1, 2)
    return np.column_stack([grid[:, 0], np.full(len(grid), 3.0), grid[:, 1]])


def motion_of(points1: np.ndarray, points2: np.ndarray, config: RigidConfig, bands: Bands | None = None):
    """The one cluster's motion (one cluster, one component, side normals)."""
    clusters = Clusters(np.zeros(len(points1), np.int64), np.zeros(len(points2), np.int64), 1, np.array([0]))
    normals2 = np.tile([0.0, 1.0, 0.0], (len(points2), 1))
    return cluster_motions(points1, points2, clusters, config, None, normals2, np.full(1, 0.025), bands=bands)


def test_a_flank_whose_ends_moved_moves_by_their_shift():
    """Overtaking 0.4 m per scan, sampled where scan t sampled it: every inner point is where a point was."""
    points1, points2 = flank(0.0, 4.5, 0.05), flank(0.4, 4.5, 0.05)
    assert not motion_of(points1, points2, RigidConfig(end_spacings=0.0)).moving[0]  # the sides alone: still
    motion = motion_of(points1, points2, RigidConfig())
    assert motion.moving[0]
    np.testing.assert_allclose(motion.translation[0, :2], [0.4, 0.0], atol=0.02)


def test_a_thinned_near_flank_finds_its_ends_in_the_whole_scans():
    """A side 2.5 m away keeps ~1 % of its points after the range-balanced sample: their outermost ones lie up to a
    spacing (~0.25 m) from the ends, each scan's elsewhere, so only the whole scans tell where the ends are."""
    whole1, whole2 = flank(0.0, 4.5, 0.03), flank(0.4, 4.5, 0.03)
    rng = np.random.default_rng(4)
    points1, points2 = (whole[rng.choice(len(whole), 110, replace=False)] for whole in (whole1, whole2))
    assert not motion_of(points1, points2, RigidConfig()).moving[0]  # the sampled ends disagree
    motion = motion_of(points1, points2, RigidConfig(), Bands(whole1, whole2))
    assert motion.moving[0]
    np.testing.assert_allclose(motion.translation[0, :2], [0.4, 0.0], atol=0.03)


def test_a_thinned_flank_moves_by_its_ends_whichever_points_the_sample_keeps():
    """Sliding along itself, a flank fits its sample's points either way only within the noise of which ones were
    kept: now and then standing still fits them a little better, and end_slack keeps that from hiding the motion."""
    whole1, whole2 = flank(0.0, 4.5, 0.03), flank(0.4, 4.5, 0.03)
    moved, strict = [], []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        points1, points2 = (whole[rng.choice(len(whole), 110, replace=False)] for whole in (whole1, whole2))
        motion = motion_of(points1, points2, RigidConfig(), Bands(whole1, whole2))
        moved.append(motion.moving[0] and abs(motion.translation[0, 0] - 0.4) < 0.03)
        strict.append(motion_of(points1, points2, RigidConfig(end_slack=0.0), Bands(whole1, whole2)).moving[0])
    assert all(moved) and not all(strict)
    still = motion_of(flank(0.0, 4.5, 0.05), flank(0.0, 4.5, 0.05), RigidConfig(), Bands(whole1, whole1))
    assert not still.moving[0]


def test_ends_that_disagree_or_move_less_than_the_sampling_tells_say_nothing():
    coarse1, coarse2 = flank(0.0, 10.0, 0.5), flank(0.3, 10.0, 0.5)  # a far wall: ends known to half a metre
    assert not motion_of(coarse1, coarse2, RigidConfig()).moving[0]
    stretched = flank(0.4, 4.1, 0.05)  # the front moved 0.4 m, the back stayed: not one rigid shift
    assert not motion_of(flank(0.0, 4.5, 0.05), stretched, RigidConfig()).moving[0]


def wall_window(start: float, length: float) -> np.ndarray:
    """Points of a still wall 18 m to the left, seen through a gap from x = start, on a 5 cm grid."""
    x = np.arange(start, start + length + 1e-9, 0.05)
    z = np.arange(-1.5, -0.6 + 1e-9, 0.05)
    grid = np.stack(np.meshgrid(x, z, indexing="ij"), axis=-1).reshape(-1, 2)
    return np.column_stack([grid[:, 0], np.full(len(grid), 18.0), grid[:, 1]])


def test_a_window_through_a_gap_sliding_along_a_still_wall_does_not_move():
    """As the sensor drives on, the part of a far wall seen between two nearer things slides along it: both ends move
    alike, but each is the edge of something nearer, not the wall's end."""
    points1, window2 = wall_window(0.0, 3.0), wall_window(0.4, 3.0)
    ends = (window2[:, 0].min(), window2[:, 0].max())
    posts = np.concatenate([[[x * 10.0 / 18.0 + offset, 10.0, z] for z in np.arange(-1.5, 0.01, 0.1)]
                            for x, offset in zip(ends, (-0.05, 0.05))])  # 10 m away, just beside each end's ray

    def motion(points2: np.ndarray, labels2: np.ndarray):
        clusters = Clusters(np.zeros(len(points1), np.int64), labels2, 1, np.array([0]))
        normals2 = np.tile([0.0, 1.0, 0.0], (len(points2), 1))
        return cluster_motions(points1, points2, clusters, RigidConfig(), None, normals2, np.full(2, 0.025))

    assert motion(window2, np.zeros(len(window2), np.int64)).moving[0]  # with nothing nearer, the ends would count
    hidden = np.concatenate([window2, posts])
    assert not motion(hidden, np.repeat([0, 1], [len(window2), len(posts)])).moving[0]
