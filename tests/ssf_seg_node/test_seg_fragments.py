"""Whole-scan fragments: the pieces of one moving object that the scan samples more than a link apart (a car's flank
seen at a grazing angle, one column of beams every metre along it) are one instance, while neighbours that move
differently, or that together are larger than one object, stay two.

The car is the one behind most fragments on the tuning seeds (urban_100/urban_200/dense_500, seeds 0-1): ~20 m
ahead and 2.6 m to the side, its flank hit by a column of beams every 1.0-1.2 m along the line of sight."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.clustering import angular_neighbours, spacing_components
from ssf_seg_node.core.geometric import GeometricConfig, GeometricSegmenter

ANGLES = np.radians([0.35, 0.43])  # a 64-beam sensor's column and ring spacing
GROUND_Z = -1.7


def near_face(centre: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    """The points a LiDAR at the origin sees on the face of an upright box facing it (its -x face)."""
    rng = float(np.linalg.norm(centre[:2]))
    step_y, step_z = ANGLES * rng
    grid = np.stack(np.meshgrid(np.arange(-size[1] / 2, size[1] / 2, step_y), np.arange(0.0, size[2], step_z)),
                    axis=-1).reshape(-1, 2)
    return np.column_stack([np.full(len(grid), centre[0] - size[0] / 2), centre[1] + grid[:, 0],
                            GROUND_Z + grid[:, 1]])


def flank(x_range: tuple[float, float], side: float, height: float) -> np.ndarray:
    """The points a LiDAR at the origin sees on a vertical side y = side between x_range: one column of beams per
    azimuth step, where each ray meets the side."""
    low, high = sorted(np.arctan2(side, x) for x in x_range)
    columns = side / np.tan(np.arange(high, low, -ANGLES[0]))
    rows = [np.arange(0.0, height, ANGLES[1] * np.hypot(x, side)) for x in columns]
    return np.concatenate([np.column_stack([np.full(len(z), x), np.full(len(z), side), GROUND_Z + z])
                           for x, z in zip(columns, rows)])


def segment(objects: list[np.ndarray], velocities: list[tuple[float, float]]) -> list[np.ndarray]:
    """Each object's instance ids after segmenting it among static clutter, each moving at its velocity (m/s)."""
    clutter = np.random.default_rng(0).uniform([-40, -40, GROUND_Z], [40, 40, 3], (4000, 3))
    points = np.concatenate([*objects, clutter])
    flow = np.zeros_like(points)
    start = 0
    for item, velocity in zip(objects, velocities):
        flow[start: start + len(item), :2] = np.asarray(velocity) * 0.1
        start += len(item)
    instance = GeometricSegmenter(GeometricConfig(), dt=0.1).segment(points, flow, ego=np.eye(4)).segmentation.instance
    bounds = np.cumsum([0] + [len(item) for item in objects])
    return [instance[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def test_a_car_flank_seen_at_a_grazing_angle_is_one_instance():
    centre, size = np.array([22.1, -3.5, 0.0]), (4.4, 1.8, 1.5)
    car = np.concatenate([near_face(centre, size), flank((19.9, 24.3), -2.6, 1.5)])
    assert spacing_components(car, 0.2, 2.5, 1.0, 2.0).count > 1  # its flank's columns lie more than a link apart
    (instance,) = segment([car], [(10.0, 0.0)])
    assert (instance > 0).all() and len(set(instance)) == 1


def test_pieces_are_neighbours_in_the_sensors_view_at_any_range():
    near, far = near_face(np.array([12.0, 0.0, 0.0]), (0.4, 0.5, 1.7)), near_face(np.array([14.0, 0.2, 0.0]), (0.4, 0.5, 1.7))
    aside = near_face(np.array([12.0, 1.5, 0.0]), (0.4, 0.5, 1.7))  # 1.0 m to the side: 5 degrees away
    points = np.concatenate([near, far, aside])
    labels = np.repeat([0, 1, 2], [len(near), len(far), len(aside)])
    assert angular_neighbours(points, labels, 2.5 * ANGLES.max(), 0.2).tolist() == [[0, 1]]


def test_two_walkers_in_one_line_of_sight_crossing_stay_two():
    walkers = [near_face(np.array([12.0, 0.0, 0.0]), (0.4, 0.5, 1.7)), near_face(np.array([14.0, 0.2, 0.0]), (0.4, 0.5, 1.7))]
    first, second = segment(walkers, [(0.0, 1.4), (0.0, -1.4)])
    assert (first > 0).all() and (second > 0).all()
    assert len(set(first)) == 1 and len(set(second)) == 1 and first[0] != second[0]


def test_two_cars_in_a_queue_moving_alike_stay_two():
    cars = [near_face(np.array([20.0, 0.0, 0.0]), (4.4, 1.8, 1.5)), near_face(np.array([25.9, 0.8, 0.0]), (4.4, 1.8, 1.5))]
    first, second = segment(cars, [(10.0, 0.0), (10.0, 0.0)])  # 1.5 m apart, together longer than one car
    assert (first > 0).all() and (second > 0).all()
    assert len(set(first)) == 1 and len(set(second)) == 1 and first[0] != second[0]
