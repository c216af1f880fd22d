"""Whole-scan misses: neighbours a short gap apart stay two objects, sparse far objects stay one, and a slow walker
the fusion loop's mask already calls dynamic keeps its motion.

The numbers of the walker are those of a missed pedestrian on the tuning seeds (urban_200/dense_500, seeds 10-19, a
person at ~17 m walking ~1 m/s, 27 points in its ICP): standing still misses scan t+1's surfaces by 0.064 m against a
noise floor of 0.045 m, its fitted step brings that to 0.026 m and the point residual from 0.112 to 0.078 m."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.clustering import angular_spacing, spacing_components, voxel_components
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.fits import Fit, explains
from ssf_seg_node.core.geometric import GeometricConfig, GeometricSegmenter

ANGLES = np.radians([0.35, 0.43])  # a 64-beam sensor's column and ring spacing


def scanned_box(centre: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    """The points a LiDAR at the origin sees on the near side (facing the sensor, the -x face) of an upright box."""
    rng = float(np.linalg.norm(centre[:2]))
    step_y, step_z = ANGLES * rng
    ys = np.arange(-size[1] / 2, size[1] / 2, step_y)
    zs = np.arange(0.0, size[2], step_z)
    grid = np.stack(np.meshgrid(ys, zs), axis=-1).reshape(-1, 2)
    return np.column_stack([np.full(len(grid), centre[0] - size[0] / 2), centre[1] + grid[:, 0],
                            centre[2] + grid[:, 1]]).astype(np.float32)


def test_two_walkers_side_by_side_stay_two_and_a_far_car_stays_one():
    walkers = [scanned_box(np.array([12.0, y, -1.7]), (0.4, 0.5, 1.7)) for y in (0.0, 1.5)]  # 1.0 m apart
    points = np.concatenate(walkers)
    assert voxel_components(points, 1.0).count == 1  # the old 1 m voxel merged them
    labels, count = spacing_components(points, 0.2, 2.5, 1.0, 2.0)
    assert count == 2 and len(set(labels[: len(walkers[0])])) == 1
    far = scanned_box(np.array([100.0, 0.0, -1.7]), (1.8, 4.4, 1.5))  # rings 0.75 m apart: links grow with the range
    assert spacing_components(far, 0.2, 2.5, 0.5, 2.0).count == 1
    assert spacing_components(far, 0.2, 2.5, 0.5, 0.5).count > 1


def test_the_spacing_is_measured_per_metre_of_range():
    points = np.concatenate([scanned_box(np.array([r, 0.0, -1.7]), (0.5, 3.0, 1.5)) for r in (10.0, 30.0)])
    assert ANGLES.min() * 0.9 < angular_spacing(points) < ANGLES.max() * 1.5


def test_two_cars_in_neighbouring_lanes_get_an_instance_each():
    cars = [scanned_box(np.array([20.0, y, -1.7]), (4.4, 1.8, 1.5)) for y in (0.0, 3.3)]  # 1.5 m apart
    background = np.random.default_rng(0).uniform([-30, -30, -1.8], [30, 30, 3], (4000, 3)).astype(np.float32)
    points = np.concatenate([*cars, background])
    flow = np.zeros_like(points)
    flow[: len(cars[0]), 0] = 1.0  # both drive at 10 m/s, one a little faster
    flow[len(cars[0]): len(cars[0]) + len(cars[1]), 0] = 1.1
    seg = GeometricSegmenter(GeometricConfig()).segment(points, flow, ego=np.eye(4)).segmentation
    first, second = seg.instance[: len(cars[0])], seg.instance[len(cars[0]): len(cars[0]) + len(cars[1])]
    assert (first > 0).all() and (second > 0).all()
    assert len(set(first)) == 1 and len(set(second)) == 1 and first[0] != second[0]


def slow_walker_fits() -> tuple[Fit, Fit, np.ndarray, np.ndarray]:
    """The fits of the missed walker: moving, standing still, its noise floor and its points in the ICP."""
    moving, still = Fit(*np.array([[0.078], [0.026], [0.0]])), Fit(*np.array([[0.112], [0.064], [0.0]]))
    return moving, still, np.array([0.045]), np.array([27])


def test_a_slow_walker_the_mask_calls_dynamic_keeps_its_motion():
    moving, still, floor, counted = slow_walker_fits()
    config = RigidConfig()
    assert not explains(moving, still, np.array([False]), floor, counted, config)[0]  # on its own: too little evidence
    assert explains(moving, still, np.array([True]), floor, counted, config)[0]


def test_a_still_cluster_the_mask_calls_dynamic_stays_still():
    """The mask lowers the bar, it does not remove it: a motion that fits no better than standing still is refused."""
    _, still, floor, counted = slow_walker_fits()
    assert not explains(still, still, np.array([True]), floor, counted, RigidConfig())[0]
    quiet = Fit(still.residual, np.array([0.03]), still.unexplained)  # standing still within the noise floor
    assert not explains(Fit(np.array([0.05]), np.array([0.01]), still.unexplained), quiet, np.array([True]), floor,
                        counted, RigidConfig())[0]
