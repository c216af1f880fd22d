"""The shared geometry against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ssf_common.geometry.boxes import bounding_box, bounding_boxes, box_corners, min_area_rectangle
from ssf_common.geometry.clustering import dbscan, hdbscan, relabel_by_size, voxel_components
from ssf_common.geometry.fitting import batched_kabsch, planar_kabsch, planar_plane_step, weighted_kabsch
from ssf_common.geometry.ground import ground_mask, height_above_ground
from ssf_common.geometry.kinematics import PlanarState, commanded_motion, driven, forward_speed, measured_motion
from ssf_common.geometry.labels import (label_extents, label_main_axes, label_means, label_quantiles, label_spans,
                                         label_sums_of_rows, pick_per_label, ragged_arange)
from ssf_common.geometry.neighbours import PointIndex, chamfer_distance, knn, may_be_near, nearest, propagate
from ssf_common.geometry.sampling import (Sampling, farthest_point_indices, greedy_farthest_indices, grid_cells, sample_indices,
                                          voxel_indices, voxel_keys)
from ssf_common.geometry.se3 import (compose, exp_twists, interpolate_poses, invert, make_pose, relative_pose, rigid_flow,
                                     rotation_angle, transform_points, yaw_of, yaw_translate)
from ssf_common.geometry.sweep import arc_poses, is_planar


def random_transform(rng: np.random.Generator) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    matrix[:3, 3] = rng.normal(0, 5, 3)
    return matrix


def test_se3_by_hand():
    quarter = make_pose(1.0, 2.0, 3.0, np.pi / 2)
    np.testing.assert_allclose(transform_points(quarter, np.array([[1.0, 0.0, 0.0]])), [[1.0, 3.0, 3.0]], atol=1e-6)
    np.testing.assert_allclose(rigid_flow(quarter, np.zeros((1, 3))), [[1.0, 2.0, 3.0]])
    assert yaw_of(quarter) == pytest.approx(np.pi / 2) and rotation_angle(quarter) == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(compose(quarter, invert(quarter)), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(invert(quarter), np.linalg.inv(quarter), atol=1e-12)
    stack = np.stack([quarter, make_pose(yaw=0.3)])
    np.testing.assert_allclose(invert(stack), np.linalg.inv(stack), atol=1e-12)
    # a sensor moving 1 m forward sees a static point 1 m closer
    ego = relative_pose(make_pose(0, 0, 0), make_pose(1, 0, 0))
    np.testing.assert_allclose(transform_points(ego, np.array([[10.0, 0, 0]])), [[9.0, 0, 0]])
    moved = yaw_translate(np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.array([np.pi / 2, 0.0]), np.array([[0, 0, 1.0], [1, 0, 0]]))
    np.testing.assert_allclose(moved, [[0, 1, 1], [1, 1, 0]], atol=1e-12)


def test_screw_interpolation_follows_an_arc_and_ends_exactly_at_the_end():
    radius, turn = 20.0, 0.3  # a unicycle's arc: constant speed and yaw rate, then a 3D motion
    start, end = make_pose(5.0, -1.0, 0.5, 0.2), compose(make_pose(5.0, -1.0, 0.5, 0.2),
                                                     make_pose(radius * np.sin(turn), radius * (1 - np.cos(turn)), 0.0, turn))
    shares = np.array([0.0, 0.25, 0.5, 1.0])
    poses = interpolate_poses(start, end, shares)
    assert np.array_equal(poses[-1], end)  # bit-exact at the end (an instant sweep's stamp)
    np.testing.assert_allclose(poses[0], start, atol=1e-12)
    for share, pose in zip(shares, poses):
        on_arc = compose(start, make_pose(radius * np.sin(share * turn), radius * (1 - np.cos(share * turn)), 0.0,
                                          share * turn))
        np.testing.assert_allclose(pose, on_arc, atol=1e-12)
    rng = np.random.default_rng(4)
    a, b = random_transform(rng), random_transform(rng)
    b[:3, :3] = a[:3, :3] @ Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()  # less than half a turn apart
    halfway = interpolate_poses(a, b, np.array([0.5]))[0]
    np.testing.assert_allclose(interpolate_poses(a, halfway, np.array([2.0]))[0], b, atol=1e-9)  # a constant twist
    for angle in (1e-9, np.pi - 1e-5):  # the rotation vector's two delicate ends
        b[:3, :3] = a[:3, :3] @ Rotation.from_rotvec([0.0, 0.6 * angle, 0.8 * angle]).as_matrix()
        halfway = interpolate_poses(a, b, np.array([0.5]))[0]
        assert rotation_angle(invert(a) @ halfway) == pytest.approx(angle / 2, abs=1e-9)
        np.testing.assert_allclose(interpolate_poses(a, halfway, np.array([2.0]))[0], b, atol=1e-9)
    np.testing.assert_allclose(exp_twists(np.zeros((1, 3)), np.array([[1.0, 2.0, 3.0]]))[0], make_pose(1.0, 2.0, 3.0))


@pytest.mark.parametrize("turn", [0.3, -1e-3, 1e-7, 0.0])
def test_a_motion_along_the_ground_is_interpolated_on_its_arc_in_closed_form(turn):
    length = 1.2  # a sweep's arc at constant speed and yaw rate, the way a deskew takes it
    def on_arc(share):
        if turn == 0.0:
            return make_pose(share * length, 0.0, 0.0, 0.0)
        radius = length / turn  # 1 - cos as 2 sin^2 of the half angle: no cancellation on a gentle curve
        return make_pose(radius * np.sin(share * turn), radius * 2 * np.sin(share * turn / 2) ** 2, 0.0, share * turn)
    shares = np.arange(-4096, 1) / 4096 + 1.0
    poses = arc_poses(on_arc(1.0), shares)
    for index in (0, 1000, 2048, 4096):
        np.testing.assert_allclose(poses[index], on_arc(shares[index]), atol=1e-12)
    np.testing.assert_allclose(poses, interpolate_poses(np.eye(4), on_arc(1.0), shares), atol=1e-8)  # its arccos
    assert is_planar(on_arc(1.0)) and not is_planar(make_pose(1.0, 0.0, 0.01, turn))
    assert not is_planar(on_arc(1.0) @ exp_twists(np.array([[0.01, 0.0, 0.0]]), np.zeros((1, 3)))[0])  # a roll


def test_weighted_kabsch_recovers_a_motion_and_ignores_zero_weights():
    rng = np.random.default_rng(0)
    truth = random_transform(rng)
    source = rng.normal(size=(200, 3))
    target = source @ truth[:3, :3].T + truth[:3, 3]
    target[:40] += rng.normal(0, 3.0, (40, 3))  # outliers ...
    weights = np.ones(200)
    weights[:40] = 0.0  # ... that carry no weight
    np.testing.assert_allclose(weighted_kabsch(source, target, weights), truth, atol=1e-9)
    assert not np.allclose(weighted_kabsch(source, target), truth, atol=1e-3)


def test_kabsch_fixes_reflections_and_degenerate_sets_give_identity():
    rng = np.random.default_rng(1)
    source = rng.normal(size=(50, 3))
    mirrored = source * [1, 1, -1]  # the best orthogonal map is a reflection; a rotation must come out
    rotation = weighted_kabsch(source, mirrored)[:3, :3]
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_array_equal(weighted_kabsch(source[:2], source[:2] + 1.0), np.eye(4))
    np.testing.assert_array_equal(weighted_kabsch(source, source + 1, np.zeros(50)), np.eye(4))
    assert np.isfinite(weighted_kabsch(np.full((5, 3), np.nan), source[:5])).all()


def test_batched_kabsch_fits_each_label():
    rng = np.random.default_rng(2)
    truths = [random_transform(rng) for _ in range(3)]
    labels = np.repeat(np.arange(4), 30)  # label 3 gets only 2 weighted points
    source = rng.normal(size=(120, 3))
    target = source.copy()
    for k, truth in enumerate(truths):
        on = labels == k
        target[on] = source[on] @ truth[:3, :3].T + truth[:3, 3]
    weights = np.ones(120)
    weights[np.flatnonzero(labels == 3)[2:]] = 0.0
    fitted = batched_kabsch(source, target, labels, 4, weights)
    for k, truth in enumerate(truths):
        np.testing.assert_allclose(fitted[k], truth, atol=1e-9)
    np.testing.assert_array_equal(fitted[3], np.eye(4))


def test_planar_fits_recover_yaw_and_translation():
    rng = np.random.default_rng(3)
    source = rng.normal(size=(100, 3))
    labels = np.repeat([0, 1], 50)
    yaw_true, shift = np.array([0.05, -0.08]), np.array([[1.0, 0.5, 0.0], [-0.3, 0.2, 0.1]])
    target = yaw_translate(source, yaw_true[labels], shift[labels])
    yaw, translation = planar_kabsch(source, target, labels, 2)
    np.testing.assert_allclose(yaw, yaw_true, atol=1e-9)
    np.testing.assert_allclose(translation, shift, atol=1e-9)
    clipped, _ = planar_kabsch(source, target, labels, 2, max_yaw=0.01)
    np.testing.assert_allclose(np.abs(clipped), 0.01)
    # Gauss-Newton on point-to-plane residuals with full normals converges to the same motion
    yaw_est, trans_est = np.zeros(2), np.zeros((2, 3))
    normals = rng.normal(size=(100, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for _ in range(6):
        moved = yaw_translate(source, yaw_est[labels], trans_est[labels])
        yaw_est, trans_est = planar_plane_step(moved, target, normals, labels, yaw_est, trans_est, 2, point_weight=1.0)
    np.testing.assert_allclose(yaw_est, yaw_true, atol=1e-6)
    np.testing.assert_allclose(trans_est, shift, atol=1e-6)


def test_label_reductions_by_hand():
    labels = np.array([0, 0, 1, 2, 2, 2])
    values = np.array([[0.0, 0, 0], [2, 0, 0], [5, 5, 5], [1, 0, 0], [3, 4, 0], [2, 2, 0]])
    np.testing.assert_allclose(label_means(values, labels, 4), [[1, 0, 0], [5, 5, 5], [2, 2, 0], [0, 0, 0]])
    np.testing.assert_allclose(label_means(values[:, 0], labels, 3, weights=np.array([1, 3, 1, 1, 1, 0.0])), [1.5, 5, 2])
    np.testing.assert_allclose(label_extents(values, labels, 4), [2, 0, 4, 0])
    low, high = label_spans(values[:, 1], labels, 4)
    np.testing.assert_allclose(low, [0, 5, 0, np.inf])
    np.testing.assert_allclose(high, [0, 5, 4, -np.inf])
    np.testing.assert_allclose(label_quantiles(values[:, 0], labels, 4), [2, 5, 2, 0])
    np.testing.assert_allclose(label_quantiles(values[:, 0], labels, 4, quantile=0.0), [0, 5, 1, 0])
    np.testing.assert_allclose(label_quantiles(values[:, 0], labels, 4, quantile=1.0), [2, 5, 3, 0])
    np.testing.assert_allclose(label_quantiles(np.zeros(0), np.zeros(0, dtype=np.int64), 2), [0, 0])
    np.testing.assert_array_equal(ragged_arange(np.array([2, 0, 3])), [0, 1, 0, 1, 2])
    picked = pick_per_label(labels, np.array([True, False, True]), 2, np.random.default_rng(0))
    assert sorted(labels[picked].tolist()) == [0, 0, 2, 2]


def test_main_axes_follow_each_labels_longest_spread():
    rng = np.random.default_rng(3)
    along = rng.uniform(-2.0, 2.0, 200)
    across = rng.uniform(-0.2, 0.2, 200)
    angle = np.radians([30.0, -75.0])
    labels = np.repeat([0, 1], 100)
    direction = np.column_stack([np.cos(angle), np.sin(angle)])[labels]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    xy = along[:, None] * direction + across[:, None] * normal + np.array([5.0, -3.0])
    axes = label_main_axes(xy, labels, 3)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", axes[:2], direction[[0, 100]])), 1.0, atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)


def test_sampling_one_vocabulary():
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.normal(0, 0.1, (2000, 3)), rng.normal(10, 0.1, (20, 3))]).astype(np.float32)
    random = sample_indices(points, 64, np.random.default_rng(1), Sampling.RANDOM)
    assert np.array_equal(random, sample_indices(points, 64, np.random.default_rng(1), "random"))
    assert len(np.unique(random)) == 64 and np.all(np.diff(random) > 0)
    fps = sample_indices(points, 8, np.random.default_rng(1), Sampling.FPS)
    assert (np.linalg.norm(points[fps], axis=1) > 5).sum() >= 1  # the far cluster is picked
    grid = np.array([[0.01, 0, 0], [0.02, 0, 0], [0.5, 0, 0], [0.51, 0, 0]])
    np.testing.assert_array_equal(voxel_indices(grid, 0.1), [0, 2])
    assert len(sample_indices(grid, 10, np.random.default_rng(0), Sampling.VOXEL)) == 2
    few = sample_indices(points[:10], 32, np.random.default_rng(1), pad=True)
    assert len(few) == 32 and set(few) == set(range(10))



@pytest.mark.parametrize("scale, voxel, dims", [(30.0, 0.8, 3), (30.0, 0.01, 3), (1e5, 1e-4, 3), (5.0, 0.3, 2)])
def test_voxel_indices_keep_the_first_point_of_every_occupied_voxel(scale, voxel, dims):
    """32-bit codes, 64-bit codes and the row-wise fallback (a volume beyond 2^62 voxels) all pick the same points as
    the definition."""
    points = (np.random.default_rng(7).normal(size=(4000, dims)) * scale).astype(np.float32)
    first_of: dict[tuple, int] = {}
    for index, key in enumerate(map(tuple, np.floor(points / np.float32(voxel)).astype(np.int64))):
        first_of.setdefault(key, index)
    np.testing.assert_array_equal(voxel_indices(points, voxel), sorted(first_of.values()))

def test_farthest_point_sampling_matches_the_greedy_definition():
    points = np.random.default_rng(4).normal(size=(3000, 3)).astype(np.float32)
    fast = farthest_point_indices(points, 256, start=17)
    greedy = greedy_farthest_indices(points.astype(np.float64), 256, start=17)
    assert greedy[0] == 17 and np.array_equal(fast, np.sort(greedy))
    duplicated = np.repeat(points[:5], 3, axis=0)
    assert len(np.unique(farthest_point_indices(duplicated, 8))) == 8


def test_neighbours_by_hand():
    reference = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]])
    found = knn(reference, np.array([[0.9, 0, 0]]), 2)
    np.testing.assert_array_equal(found.index, [[1, 0]])
    np.testing.assert_allclose(found.distance, [[0.1, 0.9]])
    far = nearest(reference, np.array([[3.0, 0, 0]]), radius=1.0)
    assert np.isinf(far.distance[0]) and far.index[0] == 3
    values = np.array([[1.0], [3.0], [100.0]])
    np.testing.assert_allclose(propagate(reference, values, np.array([[0.25, 0, 0]]), k=2), [[1.5]])
    np.testing.assert_allclose(propagate(reference, values, np.array([[3.0, 0, 0]]), k=2, radius=0.5), [[0.0]])
    assert chamfer_distance(reference, reference + [0, 0, 1.0]) == pytest.approx(2.0)


def test_point_index_answers_as_scipy_ckdtree_does():
    """The compiled tree finds the same neighbours at the same distances, with scipy's conventions for a bound (strictly
    closer), for missing neighbours (inf, n) and for k above the number of points."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    for count, k, bound in ((500, 1, np.inf), (500, 1, 0.8), (500, 3, 1.5), (4, 6, np.inf), (1, 2, 0.5)):
        points = rng.uniform(-10, 10, (count, 3))
        query = rng.uniform(-12, 12, (300, 3)).astype(np.float32)
        mine, theirs = PointIndex(points).query(query, k=k, distance_upper_bound=bound), cKDTree(points).query(
            query, k=k, distance_upper_bound=bound)
        np.testing.assert_array_equal(mine[1], theirs[1])
        np.testing.assert_allclose(mine[0], theirs[0], rtol=1e-12)
    on_bound = PointIndex(np.array([[0.0, 0, 0], [1, 0, 0]])).query(np.array([[0.5, 0, 0]]), distance_upper_bound=0.5)
    assert np.isinf(on_bound[0][0]) and on_bound[1][0] == 2
    empty = PointIndex(np.zeros((0, 3)))
    assert empty.n == 0 and np.isinf(empty.query(np.ones((3, 3)))[0]).all() and (empty.query(np.ones((3, 3)))[1] == 0).all()
    assert PointIndex(points).query(np.zeros((0, 3)), k=2)[0].shape == (0, 2)


def test_may_be_near_keeps_every_point_within_reach_and_drops_far_ones():
    rng = np.random.default_rng(3)
    for _ in range(100):
        reference = rng.uniform(-50, 50, (int(rng.integers(1, 40)), 3))
        query = rng.uniform(-70, 70, (2000, 3))
        reach = float(rng.uniform(0.1, 5.0))
        within = np.isfinite(nearest(reference, query, reach).distance)
        kept = may_be_near(reference, query, reach)
        assert kept[within].all()  # never drops a point that has a neighbour within reach
        gap = np.abs(query[:, None, :2] - reference[None, :, :2]).max(axis=2).min(axis=1)
        assert not kept[gap > 2 * reach].any()  # two cells away horizontally is never kept
    assert not may_be_near(np.zeros((0, 3)), query, 1.0).any()
    assert may_be_near(reference, query, np.inf).all()


def test_clustering():
    rng = np.random.default_rng(5)
    blobs = np.concatenate([rng.uniform(0, 1, (100, 3)), rng.uniform(0, 1, (50, 3)) + [5, 0, 0]])
    labels, count = voxel_components(blobs, 0.5)
    assert count == 2 and len(np.unique(labels[:100])) == 1 and labels[0] != labels[-1]
    density = dbscan(blobs, eps=0.6, min_samples=4)
    assert density.count == 2 and (density.labels >= 0).all()
    hierarchy = hdbscan(blobs, min_cluster_size=20)
    assert hierarchy.count == 2
    ranked = relabel_by_size(np.array([4, 4, 7, 7, 7, -1]))
    np.testing.assert_array_equal(ranked.labels, [1, 1, 0, 0, 0, -1])
    assert voxel_components(np.zeros((0, 3)), 0.5).count == 0


def test_ground_height_on_a_slope():
    xy = np.stack(np.meshgrid(np.arange(0, 20, 0.5), np.arange(0, 20, 0.5)), -1).reshape(-1, 2)
    ground = np.column_stack([xy, 0.05 * xy[:, 0]])
    box = np.array([[10.0, 10.0, 0.5 + 1.0], [10.2, 10.0, 0.5 + 1.5]])
    points = np.concatenate([ground, box])
    height = height_above_ground(points, cell=2.0)
    assert np.abs(height[: len(ground)]).max() < 0.3 and (height[len(ground):] > 0.9).all()
    flags = ground_mask(points)
    assert flags[: len(ground)].all() and not flags[len(ground):].any()


def test_min_area_rectangle_of_a_rotated_box():
    length, width, yaw = 4.0, 2.0, 0.4
    corners = box_corners(np.array([3.0, -1.0]), length, width, yaw)
    inside = np.random.default_rng(6).uniform(-0.5, 0.5, (200, 2)) * [length, width]
    points = np.concatenate([corners, inside @ np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]) + [3.0, -1.0]])
    centre, sides, heading = min_area_rectangle(points)
    np.testing.assert_allclose(centre, [3.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(sides, [length, width], atol=1e-9)
    assert heading == pytest.approx(yaw)
    box = bounding_box(np.column_stack([points, np.linspace(0.0, 1.5, len(points))]))
    np.testing.assert_allclose(box.size, [length, width, 1.5], atol=1e-9)
    assert box.centre[2] == pytest.approx(0.75)
    centre, sides, _ = min_area_rectangle(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]))  # collinear
    np.testing.assert_allclose(sides, [np.sqrt(8), 0.0], atol=1e-9)


def test_boxes_corners_is_box_corners_for_many():
    from ssf_common.geometry.boxes import boxes_corners

    rng = np.random.default_rng(5)
    centres, lengths, widths, yaws = rng.normal(size=(9, 3)), rng.uniform(1, 5, 9), rng.uniform(0.5, 3, 9), rng.uniform(-4, 4, 9)
    expected = np.array([box_corners(centres[i], lengths[i], widths[i], yaws[i]) for i in range(9)])
    assert np.allclose(boxes_corners(centres, lengths, widths, yaws), expected, atol=1e-12)
    assert boxes_corners(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0)).shape == (0, 4, 2)



def sparse_scan_with_a_car(start: float, mount: float = 1.73, slope: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """A 16-beam scan (-15..+15 deg every 2 deg, 0.2 deg azimuth) of a gently sloped ground z = -mount + slope * x
    and a car (4.5 x 1.8 m, 0.3..1.6 m above the ground) from `start` m ahead: the points and which hit the car."""
    elevation, azimuth = np.meshgrid(np.radians(np.arange(-15.0, 16.0, 2.0)), np.radians(np.arange(0.0, 360.0, 0.2)))
    rays = np.column_stack([np.cos(elevation.ravel()) * np.cos(azimuth.ravel()),
                            np.cos(elevation.ravel()) * np.sin(azimuth.ravel()), np.sin(elevation.ravel())])
    with np.errstate(divide="ignore"):
        ground = mount / (slope * rays[:, 0] - rays[:, 2])  # where z = -mount + slope * x along each ray
    ground[(ground <= 0) | (ground > 100.0)] = np.inf
    base = -mount + slope * (start + 2.25)
    lower, upper = np.array([start, -0.9, base + 0.3]), np.array([start + 4.5, 0.9, base + 1.6])
    with np.errstate(divide="ignore", invalid="ignore"):
        near, far = lower / rays, upper / rays
    entry, leave = np.nanmax(np.minimum(near, far), axis=1), np.nanmin(np.maximum(near, far), axis=1)
    car = np.where((entry <= leave) & (entry > 0), entry, np.inf)
    distance = np.minimum(ground, car)
    keep = np.isfinite(distance)
    return rays[keep] * distance[keep, None], (car < ground)[keep]


@pytest.mark.parametrize("start", [21.0, 34.0])  # between two ground rings; beyond the last one (27.7 m)
def test_zone_ground_passes_under_a_car_whose_cells_hold_no_ground_return(start):
    points, on_car = sparse_scan_with_a_car(start)
    lowest_ring = on_car & (points[:, 2] < points[on_car, 2].min() + 0.05)
    assert lowest_ring.sum() > 10
    grid = height_above_ground(points, cell=2.0)
    assert (grid[lowest_ring] < 0.08).all()  # the grid alone takes the car's lowest ring for the ground
    zoned = height_above_ground(points, cell=2.0, zones=True)
    assert (zoned[lowest_ring] > 0.3).all() and not ground_mask(points, zones=True)[on_car].any()
    assert np.abs(zoned[~on_car]).max() < 0.1  # the sloped ground stays ground
    np.testing.assert_array_equal(height_above_ground(points[:0], zones=True), np.zeros(0))


def test_commands_drive_the_vehicle_within_its_acceleration_limits():
    """Each command holds until the next; the speed follows it within the limits; the motion is the arc driven."""
    second = 1_000_000_000
    cruising = driven(PlanarState(0.0, 0.0, 0.0, 5.0), [(0, 5.0, 0.0)], second, 2 * second, 3.0, 6.0)
    assert cruising == pytest.approx((5.0, 0.0, 0.0, 5.0))
    braking = driven(PlanarState(0.0, 0.0, 0.0, 5.0), [(0, 5.0, 0.0), (second, 0.0, 0.0)], 0, 3 * second, 3.0, 6.0)
    assert braking.speed == 0.0 and braking.x == pytest.approx(5.0 + 5.0 ** 2 / 12.0, abs=0.05)  # 1 s, then 6 m/s^2
    motion = commanded_motion([(0, 4.0, 0.5)], 0, 2 * second, 4.0, 3.0, 6.0)
    assert np.arctan2(motion[1, 0], motion[0, 0]) == pytest.approx(1.0)
    assert motion[:2, 3] == pytest.approx([8.0 * np.sin(1.0), 8.0 * (1 - np.cos(1.0))], abs=0.01)  # radius 8 m
    mount = make_pose(1.5, 0.0, 1.8)
    mounted = commanded_motion([(0, 4.0, 0.5)], 0, 2 * second, 4.0, 3.0, 6.0, mount)
    assert mount @ mounted @ invert(mount) == pytest.approx(motion)
    assert commanded_motion([(second, 4.0, 0.0)], 0, 2 * second, 4.0, 3.0, 6.0) is None  # nothing in force at the start
    assert forward_speed(motion, 2.0) == pytest.approx(8.0 * np.sin(1.0) / 2.0, abs=0.005)
    assert forward_speed(mounted, 2.0, mount) == pytest.approx(forward_speed(motion, 2.0))


def test_measured_motion_integrates_each_sample_over_the_time_before_it():
    """Wheel speed and yaw rate, each measured over the time since the sample before: a straight stretch, then an arc;
    the last sample holds to the end; nothing measured after the start, or a sensor gone quiet, gives None."""
    tenth = 100_000_000
    straight = measured_motion([(tenth, 5.0, 0.0), (2 * tenth, 5.0, 0.0)], 0, 2 * tenth)
    assert straight[:3, 3] == pytest.approx([1.0, 0.0, 0.0]) and straight[:3, :3] == pytest.approx(np.eye(3))
    samples = [(tenth * k, 4.0, 0.5) for k in range(1, 21)]  # 2 s on a circle of radius 8 m
    arc = measured_motion(samples, 0, 20 * tenth)
    assert np.arctan2(arc[1, 0], arc[0, 0]) == pytest.approx(1.0)
    assert arc[:2, 3] == pytest.approx([8.0 * np.sin(1.0), 8.0 * (1 - np.cos(1.0))], abs=0.01)
    assert measured_motion(samples[:10], 0, 20 * tenth) is None  # the newest sample is a second old
    held = measured_motion(samples[:19], 0, 20 * tenth)  # one sample late: the last one holds
    assert held == pytest.approx(arc, abs=1e-9)
    assert measured_motion(samples, 20 * tenth, 21 * tenth) is None  # nothing measured after the start
    assert measured_motion(samples, -30 * tenth, -20 * tenth) is None  # measured a second after: another clock
    later = measured_motion(samples, 5 * tenth, 6 * tenth)  # only the sample over (0.5 s, 0.6 s]
    assert later[:2, 3] == pytest.approx([0.4 * np.cos(0.025), 0.4 * np.sin(0.025)])
    mount = make_pose(1.5, 0.0, 1.8)
    assert mount @ measured_motion(samples, 0, 20 * tenth, mount) @ invert(mount) == pytest.approx(arc)


def test_bounding_boxes_of_many_clusters_match_one_box_per_cluster():
    """The batched calipers give each label the box bounding_box gives its points alone: scattered, collinear,
    repeated, two-point and one-point clusters, shuffled together."""
    rng = np.random.default_rng(3)
    groups = [rng.normal(size=(40, 3)) * [3.0, 1.0, 0.5], np.column_stack([np.linspace(0, 3, 9), np.linspace(0, 1, 9),
              rng.random(9)]), np.repeat([[1.0, 2.0, 0.5]], 6, axis=0), rng.normal(size=(2, 3)), rng.normal(size=(1, 3)),
              rng.random((25, 3)) * [4.4, 1.8, 1.5] + [10.0, -4.0, 0.0]]
    labels = np.concatenate([np.full(len(group), index) for index, group in enumerate(groups)])
    points = np.concatenate(groups)
    order = rng.permutation(len(points))
    centres, sizes, yaws = bounding_boxes(points[order], labels[order], len(groups))
    for index, group in enumerate(groups):
        box = bounding_box(group)
        np.testing.assert_allclose(centres[index], box.centre, atol=1e-9)
        np.testing.assert_allclose(sizes[index], box.size, atol=1e-9)
        if box.size[0] > box.size[1] + 1e-9:  # a square's heading is any of four
            assert abs((yaws[index] - box.yaw + np.pi / 2) % np.pi - np.pi / 2) < 1e-9
    assert [array.shape for array in bounding_boxes(np.zeros((0, 3)), np.zeros(0, int), 0)] == [(0, 3), (0, 3), (0,)]


def test_grid_cells_number_the_occupied_grid_row_major_with_a_border():
    points = np.array([[0.1, 5.2], [1.9, 5.0], [-0.5, 7.9]])
    codes, shape = grid_cells(points, 1.0, border=1)
    assert shape == (5, 5)  # x cells -1..1 and y cells 5..7, one empty cell on each side
    keys = np.floor(points).astype(int) - [-1, 5] + 1
    np.testing.assert_array_equal(codes, keys[:, 0] * shape[1] + keys[:, 1])


def test_label_sums_of_rows_match_a_bincount_per_row():
    rng = np.random.default_rng(4)
    labels = rng.integers(0, 7, 200)
    labels[labels == 3] = 4  # an empty label sums to zero
    values = rng.normal(size=(5, 200))
    expected = np.stack([np.bincount(labels, row, 7) for row in values], axis=1)
    np.testing.assert_allclose(label_sums_of_rows(values, labels, 7), expected, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_dbscan_gives_scikit_learn_s_labels(seed):
    """Clusters, their numbering, border points between two clusters and noise, as scikit-learn labels them."""
    from sklearn.cluster import DBSCAN

    from ssf_common.geometry.clustering import dbscan

    rng = np.random.default_rng(seed)
    points = np.concatenate([rng.normal(centre, 0.4, (60, 2)) for centre in ((0, 0), (1.6, 0), (5, 5))]
                            + [rng.uniform(-5, 10, (40, 2))])
    expected = DBSCAN(eps=0.5, min_samples=5).fit_predict(points)
    found = dbscan(points, 0.5, 5)
    np.testing.assert_array_equal(found.labels, expected)
    assert found.count == expected.max() + 1 and (expected == -1).any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_one_voxel_key_gives_the_codes_the_map_and_the_trails_had(dtype):
    """Bit for bit the three encodings it replaced: the static map's voxels (3-D, clipped) and columns (2-D), the
    footprint grid of the evaluation's trails (2-D, 31 bits)."""
    rng = np.random.default_rng(3)
    points = np.concatenate([rng.uniform(-300.0, 300.0, (4000, 3)), rng.integers(-40, 40, (500, 3)) * 0.25,
                             [[1e7, -1e7, 0.0]]]).astype(dtype)
    for voxel in (0.25, 0.5, 0.3, 1.0):
        keys = np.floor(np.asarray(points, np.float64) / voxel).astype(np.int64) + (1 << 20)
        clipped = np.clip(keys, 0, (1 << 21) - 1)
        map_voxels = (clipped[:, 0] << 42) | (clipped[:, 1] << 21) | clipped[:, 2]
        map_columns = (keys[:, 0] << 21) | keys[:, 1]
        np.testing.assert_array_equal(voxel_keys(points, voxel, 21, clip=True), map_voxels)
        np.testing.assert_array_equal(voxel_keys(points[:, :2], voxel, 21), map_columns)
    trail = (np.floor(points[:, :2] / 0.25).astype(np.int64) + (1 << 30))
    np.testing.assert_array_equal(voxel_keys(points[:, :2], 0.25, 31), (trail[:, 0] << 31) | trail[:, 1])



def test_tukey_icp_without_matches_or_constraints_leaves_the_start():
    """Nothing within the gate: no step at all; a single match cannot fix six parameters: a least-norm step, finite."""
    from ssf_common.geometry.registration import PlaneTarget, tukey_icp

    target = PlaneTarget.build(np.array([[10.0, 0.0, 0.0], [10.0, 1.0, 0.0], [10.0, 0.0, 1.0]]),
                               np.tile([1.0, 0.0, 0.0], (3, 1)))
    far = tukey_icp(np.zeros((5, 3)), target, np.eye(4), distance=1.0, iterations=10, tolerance=1e-6)
    np.testing.assert_array_equal(far.transform, np.eye(4))
    assert far.fitness == 0.0 and far.inliers == 0
    one = tukey_icp(np.array([[9.9, 0.0, 0.0], [0.0, 0.0, 0.0]]), target, np.eye(4), 1.0, 10, 1e-6)
    assert np.isfinite(one.transform).all() and one.fitness == 0.5
    assert one.transform[0, 3] == pytest.approx(0.1, abs=1e-6)  # onto the plane x = 10 along its normal


def test_displacement_at_a_range_is_the_translation_plus_the_angle_times_the_range():
    from ssf_common.geometry.se3 import displacement_at, make_pose

    first, second = make_pose(1.0, 0.0, 0.0, 0.0), make_pose(1.0, 0.03, 0.0, np.radians(0.5))
    assert displacement_at(first, second, 20.0) == pytest.approx(0.03 + np.radians(0.5) * 20.0, rel=1e-6)
    assert displacement_at(first, first, 50.0) == pytest.approx(0.0, abs=1e-7)
