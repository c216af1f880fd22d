"""Obstacle boxes where the objects are: the heading from the motion or the fitted footprint, grown away from the
sensor."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import invert, make_pose
from ssf_common.records import EgoMotion, MotionLabel, ObstacleKind, Segmentation, SemanticFlow
from ssf_seg_node.core.obstacles import (ObstacleConfig, extract_obstacles, fit_footprint_axis, heading_of_nearest_side,
                                         result_obstacles)

DT = 0.1


def visible_faces(centre, yaw, length, width, per_metre, rng, noise=0.02):
    """Points (N, 3) on the faces of an upright box that face the sensor at the origin, with range-like noise."""
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
    points = []
    for axis, (half, span) in enumerate(((length / 2, width), (width / 2, length))):
        for sign in (-1.0, 1.0):
            middle = np.asarray(centre) + sign * half * axes[axis]
            if axes[axis] @ middle * sign >= 0:  # the face looks away from the sensor
                continue
            count = max(2, int(per_metre * span))
            along = rng.uniform(-span / 2, span / 2, count)
            xy = middle + along[:, None] * axes[1 - axis] + rng.normal(0, noise, (count, 1)) * axes[axis]
            points.append(np.column_stack([xy, rng.uniform(0.2, 1.5, count)]))
    return np.concatenate(points)


def obstacle_of(points, velocity, config=ObstacleConfig()):
    """The one obstacle of points that move rigidly with velocity (sensor standing still)."""
    flow = np.tile(np.asarray(velocity, dtype=np.float64) * DT, (len(points), 1))
    n = len(points)
    segmentation = Segmentation(np.ones(n, np.float32), np.ones(n, np.uint8), np.ones(n, np.int32))
    obstacles = extract_obstacles(points, flow, segmentation, np.eye(4), DT, 0, "lidar", config)
    assert len(obstacles) == 1
    return obstacles


def angle_between(a, b):
    return abs((a - b + np.pi) % (2 * np.pi) - np.pi)


@pytest.mark.parametrize("seed", range(5))
def test_a_moving_car_seen_from_a_corner_gets_its_heading_and_centre(seed):
    rng = np.random.default_rng(seed)
    centre, yaw, length, width = np.array([14.0, 9.0]), np.radians(200.0), 4.6, 1.9  # driving towards the sensor
    points = visible_faces(centre, yaw, length, width, 12, rng)  # an L: its front and its right side
    velocity = 4.0 * np.array([np.cos(yaw), np.sin(yaw), 0.0])
    obstacles = obstacle_of(points, velocity)
    assert obstacles.kinds[0] == ObstacleKind.VEHICLE
    assert np.degrees(angle_between(obstacles.yaws[0], yaw)) < 3.0  # along the motion, not the L's diagonal
    assert np.linalg.norm(obstacles.centres[0, :2] - centre) < 0.3
    assert obstacles.sizes[0, 0] >= 4.4 and obstacles.sizes[0, 1] >= 1.8


def test_the_fitted_footprint_follows_the_sides_not_the_diagonal():
    rng = np.random.default_rng(7)
    for degrees in (5.0, 20.0, 35.0, 60.0, 80.0):
        points = visible_faces(np.array([20.0, -6.0]), np.radians(degrees), 4.5, 1.8, 8, rng, noise=0.03)
        axis = fit_footprint_axis(points[:, :2], np.radians(1.0), 0.05)
        assert np.degrees(angle_between(4 * axis, 4 * np.radians(degrees))) / 4 < 2.0  # modulo 90 degrees


def test_a_single_visible_side_grows_away_from_the_sensor():
    rng = np.random.default_rng(3)
    side = np.column_stack([rng.uniform(10.0, 13.0, 150), rng.normal(5.0, 0.02, 150), rng.uniform(0.2, 1.5, 150)])
    obstacles = obstacle_of(side, [3.0, 0.0, 0.0])  # 3 m of its right side, the rest hidden
    np.testing.assert_allclose(obstacles.sizes[0, :2], [4.4, 1.8], atol=0.1)
    assert abs(np.cos(obstacles.yaws[0]) - 1.0) < 1e-3  # heading +x, along the motion
    # the seen side stays where it is; the box extends to +x (away from the sensor) and to +y (behind the side)
    np.testing.assert_allclose(obstacles.centres[0, :2], [10.0 + 2.2, 5.0 + 0.9], atol=0.1)


def test_a_car_moving_diagonally_takes_its_heading_from_its_velocity():
    rng = np.random.default_rng(4)
    yaw = np.radians(45.0)
    heading, across = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    rear_middle = np.array([12.0, 12.0])  # driving away: only the rear face (1.8 m, across the motion) is seen
    xy = rear_middle + rng.uniform(-0.9, 0.9, (120, 1)) * across + rng.normal(0, 0.02, (120, 1)) * heading
    points = np.column_stack([xy, rng.uniform(0.2, 1.4, 120)])
    obstacles = obstacle_of(points, [3.0, 3.0, 0.0])
    assert obstacles.kinds[0] == ObstacleKind.VEHICLE
    assert np.degrees(angle_between(obstacles.yaws[0], yaw)) < 2.0  # not the face's direction, and not backwards
    np.testing.assert_allclose(obstacles.sizes[0, :2], [4.4, 1.8], atol=0.1)
    np.testing.assert_allclose(obstacles.centres[0, :2], rear_middle + 2.2 * heading, atol=0.1)  # grown ahead


def test_a_velocity_lost_in_its_noise_leaves_the_heading_to_the_footprint():
    rng = np.random.default_rng(5)
    side = np.column_stack([rng.uniform(10.0, 14.4, 40), rng.normal(-5.0, 0.02, 40), rng.uniform(0.2, 1.5, 40)])
    n = len(side)
    velocities = np.column_stack([rng.normal(0.0, 1.0, n) - 0.2, rng.normal(1.2, 20.0, n), np.zeros(n)])  # noisy
    flow = velocities * DT
    segmentation = Segmentation(np.ones(n, np.float32), np.ones(n, np.uint8), np.ones(n, np.int32))
    config = ObstacleConfig()
    obstacles = extract_obstacles(side, flow, segmentation, np.eye(4), DT, 0, "lidar", config)
    speed = np.hypot(*obstacles.velocities[0, :2])
    assert speed >= config.heading_speed  # fast enough, but not clearly moving: the side says the heading
    assert abs(np.cos(obstacles.yaws[0])) > 0.999
    np.testing.assert_allclose(obstacles.centres[0, 1], -5.0 - 0.9, atol=0.05)  # grown behind the side


def test_heading_of_nearest_side():
    assert heading_of_nearest_side(np.radians(10.0), np.radians(100.0)) == pytest.approx(np.radians(100.0))
    assert heading_of_nearest_side(np.radians(10.0), np.radians(-170.0)) == pytest.approx(np.radians(-170.0))
    assert heading_of_nearest_side(np.radians(10.0), np.radians(150.0)) == pytest.approx(np.radians(-170.0))  # 190°
    assert heading_of_nearest_side(np.radians(10.0), np.radians(130.0)) == pytest.approx(np.radians(100.0))


def test_a_finished_scan_moves_its_obstacles_by_its_own_ego_motion_or_by_one_fitted_to_its_static_flow():
    rng = np.random.default_rng(5)
    ground = np.column_stack([rng.uniform(-20, 20, (800, 2)), rng.uniform(-1.7, -1.6, 800)]).astype(np.float32)
    car = visible_faces((8.0, 3.0), 0.3, 4.5, 1.8, 40, rng).astype(np.float32)
    points = np.concatenate([ground, car])
    ego = make_pose(1.0, 0.0, 0.0)  # the sensor drove 1 m forward in 0.1 s: the still scene comes 1 m nearer
    flow = (points - np.array([1.0, 0.0, 0.0], np.float32)) - points
    flow[len(ground):] += np.array([0.5, 0.0, 0.0], np.float32)  # the car moves 5 m/s on top
    dynamic = np.arange(len(points)) >= len(ground)
    labels = np.where(dynamic, MotionLabel.DYNAMIC, MotionLabel.STATIC).astype(np.uint8)
    segmentation = Segmentation(dynamic.astype(np.float32), labels, dynamic.astype(np.int32))
    config = ObstacleConfig()
    motion = EgoMotion(7, 7 + 100_000_000, "lidar", invert(ego))
    with_ego = SemanticFlow(7, "lidar", points, flow, segmentation, ego=motion)
    found = result_obstacles(with_ego, config, fallback_dt=0.5).moving  # the ego motion's own dt (0.1 s) counts
    assert len(found) == 1 and found.velocities[0, 0] == pytest.approx(5.0, abs=0.3)
    fitted = result_obstacles(SemanticFlow(7, "lidar", points, flow, segmentation), config, fallback_dt=0.1).moving
    np.testing.assert_allclose(fitted.velocities, found.velocities, atol=1e-3)
    slower = result_obstacles(SemanticFlow(7, "lidar", points, flow, segmentation), config, fallback_dt=0.2).moving
    np.testing.assert_allclose(slower.velocities, found.velocities / 2, atol=1e-3)

