"""Odometry metrics: evo's RPE (RMSE, SSE, STD) and ATE checked against a hand computation on hand-made
trajectories, and KITTI drift of a known scale error."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import invert, make_pose, rotation_angle
from ssf_eval.odom.metrics import end_error, kitti_drift, score
from ssf_eval.odom.trails import SweptPaths, left_behind, standing_now
from ssf_common.records import Obstacles


def line(steps: np.ndarray, yaws: np.ndarray | None = None) -> np.ndarray:
    """Poses along a gently curving path from per-step lengths (and per-step turns)."""
    yaws = np.zeros(len(steps)) if yaws is None else yaws
    poses = [np.eye(4)]
    for step, yaw in zip(steps, yaws):
        poses.append(poses[-1] @ make_pose(step, 0.0, 0.0, yaw))
    return np.stack(poses)


def test_rpe_and_ate_match_a_hand_computation():
    rng = np.random.default_rng(0)
    truth = line(np.full(150, 1.0), np.full(150, 0.002))
    estimate = line(1.0 + rng.normal(0, 0.02, 150), 0.002 + rng.normal(0, 0.001, 150))
    stamps = np.arange(151) * 0.1
    scores = score(truth, estimate, stamps)
    errors = [invert(invert(truth[i]) @ truth[i + 1]) @ (invert(estimate[i]) @ estimate[i + 1]) for i in range(150)]
    translation = np.array([np.linalg.norm(error[:3, 3]) for error in errors])
    rotation = np.degrees([rotation_angle(error) for error in errors])
    assert scores.rpe_translation.rmse == pytest.approx(np.sqrt(np.mean(translation ** 2)), rel=1e-6)
    assert scores.rpe_translation.sse == pytest.approx(np.sum(translation ** 2), rel=1e-6)
    assert scores.rpe_translation.std == pytest.approx(np.std(translation), rel=1e-6)
    assert scores.rpe_rotation.rmse == pytest.approx(np.sqrt(np.mean(rotation ** 2)), rel=1e-4)
    assert scores.distance == pytest.approx(150.0, rel=1e-6)


def test_ate_is_zero_after_alignment_of_a_rigidly_moved_trajectory():
    truth = line(np.full(60, 1.0), np.full(60, 0.01))
    moved = make_pose(3.0, -2.0, 0.5, 0.3) @ truth
    scores = score(truth, moved, np.arange(61) * 0.1)
    assert scores.ate.rmse < 1e-6
    assert scores.rpe_translation.rmse < 1e-9  # relative motions are untouched
    assert scores.endpoint_pct > 1.0  # the end point itself is far off (no alignment there)


def test_end_error_names_a_pitch_drift_as_height():
    from scipy.spatial.transform import Rotation

    truth = line(np.full(100, 1.0))
    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("y", -0.01, degrees=True).as_matrix()  # nose up a hundredth of a degree a step
    estimate = [np.eye(4)]
    for _ in range(100):
        estimate.append(estimate[-1] @ tilt @ make_pose(1.0, 0.0, 0.0, 0.0))
    end = end_error(truth, np.stack(estimate))
    assert end.pitch_deg == pytest.approx(-1.0, abs=1e-6) and abs(end.roll_deg) < 1e-9 and abs(end.yaw_deg) < 1e-9
    height = sum(np.sin(np.radians(0.01 * k)) for k in range(1, 101))  # each step climbs by the tilt so far
    assert end.height_m == pytest.approx(height, rel=1e-6) and end.height_m > 0.8
    assert end.horizontal_m < 0.01  # the ground distance is nearly the same


def test_kitti_drift_of_a_one_percent_scale_error():
    truth = line(np.full(250, 1.0))
    drift = kitti_drift(truth, line(np.full(250, 1.01)))
    assert drift.translation_pct == pytest.approx(1.0, rel=1e-6)
    assert drift.rotation_deg_per_100m == pytest.approx(0.0, abs=1e-9)
    assert drift.lengths == (100.0, 200.0)
    assert np.isnan(kitti_drift(truth[:50], truth[:50]).translation_pct)  # shorter than any segment


def test_swept_paths_mark_points_inside_agents_above_the_ground():
    paths = SweptPaths()
    car = Obstacles(0, "world", ids=[1], kinds=[1], centres=[[10.0, 0.0, 0.8]], sizes=[[4.0, 2.0, 1.6]], yaws=[0.0],
                    velocities=[[5.0, 0.0, 0.0]])
    paths.add(car)
    paths.add(car.transformed(make_pose(2.0), "world"))  # it drove 2 m
    points = np.array([[11.0, 0.5, 1.0], [13.5, -0.5, 1.2], [10.0, 0.0, 0.05], [10.0, 3.0, 1.0], [10.0, 0.0, 2.5]])
    np.testing.assert_array_equal(paths.on_paths(points), [True, True, False, False, False])


def test_left_behind_counts_only_paths_where_no_agent_stands_now():
    paths = SweptPaths()
    car = Obstacles(0, "world", ids=[1], kinds=[1], centres=[[10.0, 0.0, 0.8]], sizes=[[4.0, 2.0, 1.6]], yaws=[0.0],
                    velocities=[[5.0, 0.0, 0.0]])
    queued = Obstacles(0, "world", ids=[2], kinds=[1], centres=[[30.0, 0.0, 0.8]], sizes=[[4.0, 2.0, 1.6]],
                       yaws=[0.0], velocities=[[0.0, 0.0, 0.0]])
    moved = car.transformed(make_pose(6.0), "world")  # the car drove 6 m on: its first place is empty now
    paths.add(car)
    paths.add(queued)
    paths.add(moved)
    now = Obstacles(0, "world", ids=[1, 2], kinds=[1, 1], centres=[moved.centres[0], queued.centres[0]],
                    sizes=[[4.0, 2.0, 1.6]] * 2, yaws=[0.0, 0.0], velocities=[[5.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    points = np.array([[9.0, 0.5, 1.0],  # where the car was: a trail
                       [16.0, 0.0, 1.0],  # where the car is now
                       [30.5, 0.3, 1.2],  # the queued car, standing there all along
                       [20.0, 5.0, 1.0]])  # nobody's path
    on, left = left_behind(points, paths, now)
    np.testing.assert_array_equal(on, [True, True, True, False])
    np.testing.assert_array_equal(left, [True, False, False, False])
    np.testing.assert_array_equal(standing_now(points, now), [False, True, True, False])
    on, left = left_behind(points, paths, Obstacles.empty())  # nobody there now: every path voxel is left behind
    np.testing.assert_array_equal(left, on)


def test_the_static_world_floor_keeps_a_queued_car_on_the_paths_but_never_left_behind():
    """The simulator's static points within reach, sampled like a map: a car standing in a queue is static (on its
    path, not left behind), a moving car's points and points beyond reach are not sampled at all."""
    from ssf_eval.odom.evaluate import MethodRun, sample_trails, static_world
    from ssf_eval.odom.sequence import SimScan

    queued = Obstacles(0, "world", ids=[2], kinds=[1], centres=[[10.0, 0.0, 0.8]], sizes=[[4.0, 2.0, 1.6]],
                       yaws=[0.0], velocities=[[0.0, 0.0, 0.0]])
    points = np.array([[10.5, 0.3, 1.2],  # the queued car
                       [12.0, 8.0, 1.0],  # a wall nobody walked into
                       [20.0, 0.0, 1.0],  # a moving car
                       [50.0, 0.0, 1.0]], np.float32)  # a wall beyond reach
    scan = SimScan(0, 0, points, points, np.array([False, False, True, False]), np.zeros(4, np.int32),
                   make_pose(1.0), queued)
    kept = static_world(scan, 35.0)
    np.testing.assert_array_equal(kept, points[:2])
    paths = SweptPaths()
    paths.add(queued)
    floor = MethodRun("static world")
    sample_trails(floor, kept, paths, queued)
    assert (floor.map_voxels, floor.trail_voxels, floor.left_voxels) == (2, 1, 0)


def test_a_map_voxel_stays_where_the_sensor_saw_it_when_the_odometry_drifts_later():
    """Each map point is put into the world by the odometry's error when it first appeared: a road point 50 m away
    mapped while the pose was exact stays on the road after the estimate pitches by 0.6 deg (placing the whole map by
    the latest pose lifts it 0.5 m into an agent's path); a point first held after the drift takes the new error."""
    from ssf_eval.odom.trails import MapPlacement, world_from_odometry

    road = np.array([[50.0, 0.0, 0.0]], np.float32)
    placement = MapPlacement()
    truth = np.eye(4)
    np.testing.assert_allclose(placement.place(road, world_from_odometry(truth, truth)), road, atol=1e-6)
    pitched = np.eye(4)
    angle = np.radians(0.6)
    pitched[:3, :3] = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    drifted = world_from_odometry(truth, pitched)
    assert abs((drifted[:3, :3] @ road[0])[2]) > 0.5  # the latest pose would lift the road point by half a metre
    later = np.array([[20.0, 5.0, 0.0]], np.float32)
    placed = placement.place(np.concatenate([road, later]), drifted)
    np.testing.assert_allclose(placed[0], road[0], atol=1e-6)
    np.testing.assert_allclose(placed[1], drifted[:3, :3] @ later[0], atol=1e-6)
    assert len(placement.place(np.zeros((0, 3), np.float32), drifted)) == 0
