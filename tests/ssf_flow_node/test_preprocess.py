"""Shared pre-processing: crop, downsampling, ground split, flow propagation, input validation."""

import numpy as np
import pytest

from ssf_common.errors import DataError
from ssf_common.geometry.ground import ground_mask
from ssf_flow_node.core.preprocess import (PreprocessConfig, Sampling, check_mask, check_scan, downsample, propagate,
                                           propagate_motion)


def scan(count=20000, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-40, 40, (count, 3)) * [1, 1, 0.05]).astype(np.float32)


@pytest.mark.parametrize("sampling", list(Sampling))
def test_downsample_keeps_at_most_n_points_inside_range(sampling):
    points = scan()
    config = PreprocessConfig(points=2048, sampling=sampling, max_range=30.0, min_range=2.0, voxel_size=0.5)
    sample = downsample(points, config, np.random.default_rng(0))
    assert 0 < len(sample.indices) <= 2048
    assert np.array_equal(sample.points, points[sample.indices])
    distance = np.linalg.norm(sample.points[:, :2], axis=1)
    assert distance.min() >= 2.0 and distance.max() <= 30.0
    assert len(np.unique(sample.indices)) == len(sample.indices)


def test_small_scans_are_kept_whole():
    points = scan(500)
    sample = downsample(points, PreprocessConfig(points=8192, max_range=100.0), np.random.default_rng(0))
    assert len(sample.indices) == 500


@pytest.mark.parametrize("count, share, kept", [(20000, 0.0, 2048), (20000, 0.05, 2048), (20000, 0.3, 6000),
                                                (1000, 0.3, 1000)])
def test_dense_scans_keep_a_share_of_their_points(count, share, kept):
    points = scan(count) * np.float32([0.5, 0.5, 1.0])  # all within 30 m: every point is a candidate
    config = PreprocessConfig(points=2048, points_share=share, max_range=100.0)
    sample = downsample(points, config, np.random.default_rng(0))
    assert len(sample.indices) == kept and len(np.unique(sample.indices)) == kept


def test_motion_propagation_is_exact_on_sampled_points_and_reaches_only_their_surroundings():
    points = scan(5000)
    sample = downsample(points, PreprocessConfig(points=1000, max_range=100.0), np.random.default_rng(1))
    motion = propagate_motion(points, sample, np.tile([1.0, 2.0, 3.0], (1000, 1)).astype(np.float32))
    assert motion.shape == (5000, 3)
    assert np.allclose(motion, [1.0, 2.0, 3.0], atol=1e-5)
    relative = np.zeros((1000, 3), np.float32)
    mover = sample.points[:, 0] > 0  # half of the scene moves by 1 m along x
    relative[mover, 0] = 1.0
    motion = propagate_motion(points, sample, relative, k=1, radius=0.5)
    assert np.array_equal(motion[sample.indices], relative)
    gap_to_mover = np.linalg.norm(points[:, None, :] - sample.points[mover][None], axis=2).min(axis=1)
    assert not motion[gap_to_mover > 0.5].any()
    assert set(np.unique(motion[:, 0])) <= {0.0, 1.0}


def test_propagate_inverse_distance():
    source = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    values = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    out = propagate(source, values, np.array([[0.25, 0, 0]]), k=2)
    # weights 1/0.25 and 1/0.75 -> 0.75 and 0.25
    assert out[0, 0] == pytest.approx(0.25)


def test_propagate_stops_at_the_radius():
    source = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    values = np.array([[2.0, 0, 0], [4.0, 0, 0]])
    out = propagate(source, values, np.array([[0.1, 0, 0], [5.0, 0, 0]]), k=2, radius=0.5)
    assert out[0, 0] == pytest.approx(2.0)  # only the near source counts
    assert not out[1].any()  # nothing within reach


def test_ground_mask_separates_ground_and_box():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-20, 20, (4000, 2)), rng.normal(-1.8, 0.02, 4000)])
    box = np.column_stack([rng.uniform(4, 6, (500, 2)), rng.uniform(-1.2, 0.0, 500)])
    flags = ground_mask(np.concatenate([ground, box]))
    assert flags[:4000].mean() > 0.97
    assert flags[4000:].mean() < 0.05


def test_structure_above_every_road_user_leaves_the_flow_sample_but_joins_the_ego_registration():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-20, 20, (4000, 2)), rng.normal(-1.8, 0.02, 4000)])
    car = np.column_stack([rng.uniform(4, 8, (3000, 1)), rng.uniform(-6, -4, (3000, 1)), rng.uniform(-1.6, 0.0, 3000)])
    facade = np.column_stack([rng.uniform(-15, 15, (6000, 1)), np.full((6000, 1), 12.0), rng.uniform(-1.6, 30.0, 6000)])
    points = np.concatenate([ground, car, facade]).astype(np.float32)
    height = points[:, 2] + 1.8
    base = dict(points=1000, max_range=100.0, remove_ground=True, ego_ground_points=100)
    kept = downsample(points, PreprocessConfig(**base), np.random.default_rng(0), height)
    assert (height[kept.indices] > 4.5).mean() > 0.5  # the facade's upper floors take most of the budget
    config = PreprocessConfig(**base, object_height=4.5, ego_structure_points=200)
    sample = downsample(points, config, np.random.default_rng(0), height)
    assert height[sample.indices].max() < 4.5 and height[sample.indices].min() >= 0.3
    assert np.count_nonzero((sample.indices >= 4000) & (sample.indices < 7000)) > 1.8 * np.count_nonzero(
        (kept.indices >= 4000) & (kept.indices < 7000))  # the car gets the points the upper floors had
    ego_only = height[sample.ground]
    assert np.count_nonzero(ego_only < 0.3) == 100 and np.count_nonzero(ego_only >= 4.5) == 200
    shared = downsample(points, PreprocessConfig(**{**base, "points": 64}, points_share=0.3, object_height=4.5),
                        np.random.default_rng(0), height)
    assert shared.indices.size == int(0.3 * np.count_nonzero(height >= 0.3))  # the budget counts the upper floors too


def test_bad_scans_and_masks_are_one_line_errors():
    with pytest.raises(DataError, match="shape"):
        check_scan(np.zeros((10, 2)), "scan t")
    with pytest.raises(DataError, match="empty"):
        check_scan(np.zeros((0, 3)), "scan t")
    with pytest.raises(DataError, match="NaN"):
        check_scan(np.array([[0.0, np.nan, 0.0]]), "scan t")
    with pytest.raises(DataError, match="expected 5"):
        check_mask(np.zeros(4), 5)
    with pytest.raises(DataError, match=r"\[0, 1\]"):
        check_mask(np.full(5, 2.0), 5)
    assert check_mask(np.ones((5, 1), bool), 5).dtype == np.float32
    with pytest.raises(DataError, match="no points"):
        downsample(np.full((10, 3), 500.0, np.float32), PreprocessConfig(), np.random.default_rng(0))



def test_scan_cache_prepares_each_scan_of_a_stream_once(monkeypatch):
    """In a stream, scan t+1 of one pair is scan t of the next: it is split and sampled once, the same way in both."""
    import ssf_flow_node.core.base as base

    original, calls = base.prepare_scan, []

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    rng = np.random.default_rng(3)
    scans = [rng.uniform(-30, 30, (5000, 3)).astype(np.float32) for _ in range(4)]
    config = PreprocessConfig(points=1000, remove_ground=True, max_range=100.0)
    monkeypatch.setattr(base, "prepare_scan", counted)
    cache = base.ScanCache(config)
    pairs = [base.prepare(a, b, None, config, cache) for a, b in zip(scans, scans[1:])]
    assert len(calls) == len(scans)
    for earlier, later in zip(pairs, pairs[1:]):
        assert np.array_equal(earlier.sample2.indices, later.sample1.indices)
        assert np.array_equal(earlier.sample2.ground, later.sample1.ground)
    uncached = base.prepare(scans[1], scans[2], None, config)
    assert np.array_equal(uncached.sample1.indices, pairs[1].sample1.indices)  # the cache changes the work, not the answer
    assert np.array_equal(uncached.height1, pairs[1].height1)


def test_zone_ground_keeps_a_cars_lowest_ring_between_sparse_ground_rings():
    azimuth = np.radians(np.arange(0.0, 360.0, 0.2))
    rings = [np.column_stack([r * np.cos(azimuth), r * np.sin(azimuth), np.full(azimuth.size, -1.73)])
             for r in (6.5, 8.0, 9.8, 11.0, 14.0, 19.8, 33.0)]  # a 16-beam sensor's ground rings, none from 20 to 33 m
    side = np.radians(np.arange(-2.0, 2.0, 0.2))
    car = [np.column_stack([26.0 * np.cos(side), 26.0 * np.sin(side), np.full(side.size, -1.73 + lift)])
           for lift in (0.45, 1.4)]  # its two rings, no ground return in or next to its cells
    points = np.concatenate(rings + car).astype(np.float32)
    lowest_ring = np.arange(len(points) - 2 * side.size, len(points) - side.size)
    kept = {}
    for zones in (False, True):
        config = PreprocessConfig(points=64, points_share=1.0, remove_ground=True, max_range=100.0, ground_zones=zones)
        kept[zones] = np.isin(lowest_ring, downsample(points, config, np.random.default_rng(0)).indices).mean()
    assert kept[False] == 0.0 and kept[True] == 1.0  # the grid takes it for the ground, the zone's ground does not
