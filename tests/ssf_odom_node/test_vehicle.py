"""The vehicle around the sensor: the mount, base_link's odometry, the pose of the next scan, the motion priors."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import invert, make_pose
from ssf_odom_node.core.odometry import OdomStep
from ssf_common.vehicle import mount_matrix
from ssf_odom_node.core.vehicle import VehicleMotion, command_prior, next_scan_estimate, speed_ahead, to_base

PERIOD_NS = 100_000_000
MOUNT = (1.2, 0.0, 1.8, 0.0, 0.0, 0.0)


def step_of(pose: np.ndarray, twist=(5.0, 0.0, 0.0, 0.0, 0.0, 0.2), next_motion: np.ndarray | None = None) -> OdomStep:
    return OdomStep(3 * PERIOD_NS, pose, np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]), np.asarray(twist, float), next_motion,
                    100, 0.01, "flow", 10)


def test_the_mount_is_a_pose_of_xyz_and_roll_pitch_yaw():
    np.testing.assert_allclose(mount_matrix((1.0, 2.0, 3.0, 0.0, 0.0, np.pi / 2)), make_pose(1.0, 2.0, 3.0, np.pi / 2),
                               atol=1e-12)


def test_base_link_odometry_is_the_sensors_seen_through_the_mount():
    mount = mount_matrix(MOUNT)
    step = step_of(make_pose(4.0, 1.0, 0.0, 0.3), twist=(5.0, 0.24, 0.0, 0.0, 0.0, 0.2))
    estimate = to_base(step, mount, "odom", "base_link")
    np.testing.assert_allclose(estimate.pose, mount @ step.pose @ invert(mount))
    assert (estimate.frame_id, estimate.child_frame_id) == ("odom", "base_link") and estimate.stamp_ns == step.stamp_ns
    # turning at 0.2 rad/s, a sensor 1.2 m ahead moves sideways 0.24 m/s more than base_link: base_link's own is 0
    np.testing.assert_allclose(estimate.twist, [5.0, 0.0, 0.0, 0.0, 0.0, 0.2], atol=1e-12)


def test_the_next_scans_pose_comes_one_period_later_once_the_period_and_a_flow_are_known():
    mount = mount_matrix(MOUNT)
    ahead = make_pose(0.5, 0.0, 0.0, 0.02)
    step = step_of(make_pose(4.0, 1.0, 0.0, 0.3), next_motion=invert(ahead))
    estimate = to_base(step, mount, "odom", "base_link")
    next_pose = step.pose @ ahead
    assert next_scan_estimate(estimate, step, next_pose, mount, None) is estimate  # the period is not known yet
    assert next_scan_estimate(estimate, step_of(step.pose), None, mount, PERIOD_NS) is estimate  # no flow
    newest = next_scan_estimate(estimate, step, next_pose, mount, PERIOD_NS)
    assert newest.stamp_ns == step.stamp_ns + PERIOD_NS
    np.testing.assert_allclose(newest.pose, mount @ next_pose @ invert(mount))


def test_the_speed_at_a_scan_is_its_flows_motion_ahead_else_the_one_given():
    mount = mount_matrix(MOUNT)
    assert speed_ahead(step_of(np.eye(4)), 0.1, mount, without_flow=3.0) == 3.0
    moved = speed_ahead(step_of(np.eye(4), next_motion=invert(make_pose(0.5, 0.0, 0.0))), 0.1, mount, without_flow=3.0)
    assert moved == pytest.approx(5.0)


def test_commands_are_the_prior_from_the_last_scan_and_restarts_forget_the_old_ones():
    mount = mount_matrix(MOUNT)
    motion = VehicleMotion()
    assert motion.commanded(None, 10**9, 5.0, (3.0, 6.0), mount) is None  # no scan yet
    motion.add_command(0, 5.0, 0.2)
    prior = motion.commanded(0, 10**9, 5.0, (3.0, 6.0), mount)
    assert prior is not None
    np.testing.assert_array_equal(prior, command_prior([(0, 5.0, 0.2)], 0, 10**9, 5.0, (3.0, 6.0), mount))
    base = mount @ prior @ invert(mount)
    assert np.arctan2(base[1, 0], base[0, 0]) == pytest.approx(0.2, abs=1e-6)
    motion.add_command(-5, 1.0, 0.0)  # the clock went back: a restarted stream
    assert list(motion.commands) == [(-5, 1.0, 0.0)]


def test_measurements_are_the_measured_prior_and_repeats_and_restarts_are_handled():
    mount = mount_matrix(MOUNT)
    motion = VehicleMotion()
    assert motion.measured(0, 10 * PERIOD_NS, mount) == (None, None)  # none came
    for k in range(1, 11):
        motion.add_twist(k * PERIOD_NS, 5.0, 0.2)
    motion.add_twist(10 * PERIOD_NS, 9.0, 0.0)  # the same sample again
    assert len(motion.twists.samples) == 10
    assert motion.measured(None, 10 * PERIOD_NS, mount) == (None, None)  # no scan yet
    moved, newest = motion.measured(0, 10 * PERIOD_NS, mount)
    base = mount @ moved @ invert(mount)
    assert newest == 10 * PERIOD_NS and np.hypot(*base[:2, 3]) == pytest.approx(2 * 5.0 / 0.2 * np.sin(0.1), abs=0.01)
    assert motion.measured(100 * PERIOD_NS, 101 * PERIOD_NS, mount) == (None, 10 * PERIOD_NS)  # they stopped
    motion.add_twist(PERIOD_NS, 1.0, 0.0)
    assert list(motion.twists.samples) == [(PERIOD_NS, 1.0, 0.0)]
