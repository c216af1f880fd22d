"""Odometry on rolling-shutter sweeps: the first scan deskewed with the flow's motion, the sensor's rise or fall within
a sweep fitted with the pose, and instant sweeps taken as scans without time."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import interpolate_poses, invert, make_pose, transform_points
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, Odometry, centred_mean, make_odometry

PERIOD = 0.1
STEP_NS = 100_000_000
HEIGHTS = (0.0, 0.04, 0.0, 0.05, 0.01, 0.05)  # the sensor's height at each stamp (m): a rough road under the car
SPEED_STEP = 1.0  # m along x per scan


def static_street() -> np.ndarray:
    """World points of a street without traffic: ground, a wall each side, a cross wall ahead and one behind."""
    rng = np.random.default_rng(1)
    ground = np.c_[rng.uniform(-40, 40, (4000, 2)), rng.normal(-1.8, 0.01, 4000)]
    walls = [np.c_[rng.uniform(-40, 40, 1500), np.full(1500, side), rng.uniform(-1.8, 3.0, 1500)] for side in (12.0, -9.0)]
    cross = [np.c_[np.full(600, ahead), rng.uniform(-9, 12, 600), rng.uniform(-1.8, 3.0, 600)] for ahead in (30.0, -25.0)]
    return np.vstack([ground, *walls, *cross])


def swept(world: np.ndarray, start: np.ndarray, stamp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points as a sweep ending at `stamp` takes them: each at the time its azimuth fires (s before the stamp),
    in the sensor frame of that time, the sensor moving at constant twist from `start` to `stamp`."""
    local = transform_points(invert(stamp), world)
    time = ((np.arctan2(local[:, 1], local[:, 0]) + np.pi) / (2 * np.pi) - 1.0) * PERIOD
    poses = interpolate_poses(start, stamp, 1.0 + time / PERIOD)
    moved = np.einsum("nji,nj->ni", poses[:, :3, :3], world - poses[:, :3, 3])  # R^T (w - t), per point
    return moved.astype(np.float32), time.astype(np.float32)


def drive(config: OdomConfig, times: str = "swept") -> tuple[list, list[np.ndarray]]:
    """Steps of ssf odometry over a static street swept from poses along x that rise and fall with HEIGHTS, each scan
    with its exact static flow and the flow's ego motion to the next (`times`: each point's time as "swept", "zero"
    or "none"); and the true poses (first scan's frame)."""
    world = static_street()
    poses = [make_pose(SPEED_STEP * index, 0.0, height) for index, height in enumerate((0.0, *HEIGHTS))]
    odometry, steps = make_odometry("ssf", config), []
    for index in range(1, len(poses) - 1):
        points, time = swept(world, poses[index - 1], poses[index])
        ego = invert(poses[index + 1]) @ poses[index]  # the flow's convention: this scan's frame -> the next one's
        flow = transform_points(ego, points) - points
        given = {"swept": time, "zero": np.zeros_like(time), "none": None}[times]
        steps.append(odometry.step(OdomInput(index * STEP_NS, points, flow, np.zeros(len(points), np.float32),
                                             ego=ego, time=given)))
    return steps, [invert(poses[1]) @ pose for pose in poses[1:-1]]


def test_a_swept_scan_of_a_rising_sensor_is_registered_at_its_stamp():
    steps, truth = drive(OdomConfig(near_range=0.0))
    for index in range(1, len(steps)):
        assert np.linalg.norm(steps[index].pose[:3, 3] - truth[index][:3, 3]) < 0.005
        sank = (invert(truth[index]) @ truth[index - 1])[2, 3]  # the sweep's motion: height of the last stamp's frame
        assert steps[index].extras["sweep_lift"] == pytest.approx(sank, abs=0.005)


def test_without_the_vertical_fit_the_height_is_off_by_about_half_the_rise():
    steps, truth = drive(OdomConfig(near_range=0.0, sweep_gates=()))
    heights = np.array([step.pose[2, 3] - pose[2, 3] for step, pose in zip(steps, truth)])
    assert np.abs(heights[1:]).max() > 0.015  # the deskew along the ground leaves a ramp the registration splits
    assert all("sweep_lift" not in step.extras or step.extras["sweep_lift"] == 0.0 for step in steps)


def test_the_first_scan_is_deskewed_with_the_flows_motion_to_the_next():
    world = static_street()
    turn = make_pose(SPEED_STEP, 0.0, 0.0, 0.02)  # one period at constant speed and yaw rate
    points, time = swept(world, invert(turn), np.eye(4))
    ego = invert(turn)  # the flow's convention: the stamp's frame -> the next stamp's
    odometry = make_odometry("ssf", OdomConfig())
    flow = transform_points(ego, points) - points
    frame = OdomInput(0, points, flow, np.zeros(len(points)), ego=ego, time=time)
    motion = odometry.sweep_motion(points, frame, np.eye(4), flow, np.zeros(len(points)))
    deskewed = odometry.prepared(points, frame, flow, np.zeros(len(points)), motion)
    assert np.abs(points - world).max() > 0.5  # the sweep took the points up to a metre apart
    assert np.abs(deskewed.scan - world).max() < 0.01
    np.testing.assert_allclose(deskewed.shares, -time / PERIOD)
    assert odometry.sweep_motion(points, OdomInput(0, points, time=time), np.eye(4)) is None  # no motion: as swept


def test_an_instant_sweep_is_registered_as_a_scan_without_time():
    for instant, plain in zip(drive(OdomConfig(), "zero")[0], drive(OdomConfig(), "none")[0]):
        np.testing.assert_array_equal(instant.pose, plain.pose)
        np.testing.assert_array_equal(instant.covariance, plain.covariance)
        assert instant.extras == plain.extras == {}


def test_where_the_flow_contradicts_constant_velocity_its_search_registers_the_sweep_deskewed_at_that_velocity():
    world = static_street()
    poses = [make_pose(SPEED_STEP * index, 0.0, 0.0) for index in range(5)]
    odometry = make_odometry("ssf", OdomConfig())
    for index in (1, 2, 3):
        points, time = swept(world, poses[index - 1], poses[index])
        ego = invert(poses[index + 1]) @ poses[index]
        flow = transform_points(ego, points) - points
        frame = OdomInput(index * STEP_NS, points, flow, np.zeros(len(points), np.float32), ego=ego, time=time)
        if index == 3:
            by_flow, by_velocity = odometry.predict(frame.stamp_ns)
            flow_motion = odometry.sweep_motion(points, frame, by_flow)
            assert odometry.velocity_deskewed(points, frame, flow, None, flow_motion, by_flow, by_velocity) is None
            turned = by_flow @ make_pose(0.0, 0.0, 0.0, 0.05)  # a flow that misjudged a turn by 3 degrees
            found = odometry.velocity_deskewed(points, frame, flow, None, odometry.sweep_motion(points, frame, turned),
                                               turned, by_velocity)
            assert found is not None and np.abs(found.scan - transform_points(invert(poses[3]), world)).max() < 0.02
        odometry.step(frame)


def test_three_smooth_pair_motions_are_averaged_and_a_sudden_turn_keeps_the_sweeps_own():
    steady = np.array([[1.00, 0.0, 0.0], [1.02, 0.0, 0.0], [1.04, 0.0, 0.0]])  # constant acceleration
    np.testing.assert_allclose(centred_mean(steady, (0.1, 0.005)), make_pose(1.02, 0.0, 0.0, 0.0), atol=1e-12)
    noisy = steady + np.array([[0.004, 0.0, 0.0005], [-0.006, 0.001, -0.001], [0.002, 0.0, 0.0005]])
    np.testing.assert_allclose(centred_mean(noisy, (0.1, 0.005)), make_pose(1.02, 1 / 3000, 0.0, 0.0), atol=1e-12)
    turning = steady + np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.01, -0.05]])  # a turn begins at the stamp
    np.testing.assert_allclose(centred_mean(turning, (0.1, 0.005)), make_pose(1.02, 0.0, 0.0, 0.0), atol=1e-12)


def noisy_drive(config: OdomConfig, errors: np.ndarray,
                gap_at: int | None = None) -> tuple[list, list[np.ndarray], Odometry]:
    """Steps of ssf odometry along a flat street at constant speed whose flow's ego motion of each pair is off along x
    by `errors` (m), as a deskew by a noisy wheel odometer leaves it: each error also in the next pair, the other way;
    and the true poses. `gap_at`: that scan comes a period late (one skipped)."""
    world = static_street()
    stamps = [index + (index >= gap_at if gap_at is not None else 0) for index in range(len(errors) + 2)]
    poses = [make_pose(SPEED_STEP * stamp, 0.0, 0.0) for stamp in stamps]
    odometry, steps = make_odometry("ssf", config), []
    for index in range(1, len(poses) - 1):
        points, time = swept(world, make_pose(poses[index][0, 3] - SPEED_STEP, 0.0, 0.0), poses[index])
        ego = make_pose(errors[index - 1], 0.0, 0.0) @ invert(poses[index + 1]) @ poses[index]
        flow = transform_points(ego, points) - points
        steps.append(odometry.step(OdomInput(stamps[index] * STEP_NS, points, flow, np.zeros(len(points), np.float32),
                                             ego=ego, time=time)))
    return steps, [invert(poses[1]) @ pose for pose in poses[1:-1]], odometry


def test_the_mean_of_three_pairs_motions_deskews_a_sweep_closer_than_its_own_noisy_motion():
    noise = np.array([0.0, 0.01, -0.01, 0.01, -0.01, 0.01, -0.01, 0.01, 0.0])
    errors = noise[1:] - noise[:-1]  # a pair's error is its two sweeps' deskew errors apart: neighbours cancel
    off = [np.abs(step.pose[:3, 3] - pose[:3, 3]).max()
           for step, pose in zip(*noisy_drive(OdomConfig(near_range=0.0, sweep_mean=False), errors)[:2])]
    on = [np.abs(step.pose[:3, 3] - pose[:3, 3]).max()
          for step, pose in zip(*noisy_drive(OdomConfig(near_range=0.0), errors)[:2])]
    assert max(off[2:]) > 0.01  # each sweep's own motion is 2 cm off: its points up to 2 cm apart along the street
    assert np.sqrt(np.mean(np.square(on[2:]))) < 0.6 * np.sqrt(np.mean(np.square(off[2:])))  # the mean: 7 mm off


def test_pair_motions_across_skipped_scans_are_not_averaged():
    errors = np.zeros(5)
    _, _, odometry = noisy_drive(OdomConfig(near_range=0.0), errors, gap_at=4)  # scans 4 on came a period late
    assert len(odometry.pair_motions) == 2  # scan 4 came after a gap: its pair and scan 5's kept since
    _, _, odometry = noisy_drive(OdomConfig(near_range=0.0), errors[:4], gap_at=4)
    assert len(odometry.pair_motions) == 1  # only the pair that starts after the gap: the next sweep is not averaged
