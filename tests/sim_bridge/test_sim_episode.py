"""Episodes: the ego stops on collision and the episode says so; success and timeout; messages."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.ego import Outcome, VelocityCommand
from sim_bridge.ros_messages import episode_result, markers, obstacles, scan_cloud, truth_cloud, vehicle_twist
from sim_bridge.simulator import MeasuredMotion, Simulator
from ssf_common import messages
from ssf_common.geometry.kinematics import measured_motion
from ssf_common.pointcloud import cloud_to_array


def test_driving_into_the_roadside_is_a_collision_and_the_ego_stops(small_scenario):
    sim = Simulator(small_scenario(agents=0), seed=1)
    frame = sim.reset()
    for _ in range(200):
        frame = sim.step(VelocityCommand(6.0, 0.4))  # turn left off the road into the structure
        if sim.done:
            break
    assert frame.status.outcome == Outcome.COLLISION
    assert frame.status.collided_with.startswith("structure")
    assert frame.status.min_clearance == 0.0
    stopped_at = (frame.ego.x, frame.ego.y)
    for _ in range(5):
        frame = sim.step(VelocityCommand(6.0, 0.0))
    assert (frame.ego.x, frame.ego.y) == stopped_at and frame.ego.speed == 0.0
    assert frame.status.outcome == Outcome.COLLISION
    assert sim.log.collisions and sim.log.collisions[0][2] == frame.status.collided_with


def test_rear_ending_a_vehicle_is_a_collision(small_scenario):
    one_lane = {
        "route.waypoints": [[0.0, 0.0], [250.0, 0.0]],
        "route.lanes_per_direction": 1,
        "agents.vehicle_fraction": 1.0,
        "agents.keep_clear_of_start": 10.0,
    }
    sim = Simulator(small_scenario(agents=30, **one_lane), seed=2)
    frame = sim.reset()
    for _ in range(250):  # full speed along the lane, ignoring everyone
        frame = sim.step(VelocityCommand(12.0, 0.0))
        if sim.done:
            break
    assert frame.status.outcome == Outcome.COLLISION
    assert frame.status.collided_with.startswith("vehicle")
    assert frame.ego.speed == 0.0


def test_follower_reaches_the_goal_of_an_empty_route(small_scenario):
    sim = Simulator(small_scenario(agents=0), seed=0)
    frame = sim.reset()
    driver = sim.follower()
    while not sim.done:
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    status = frame.status
    assert status.outcome == Outcome.SUCCESS
    assert abs(status.distance - sim.world.route_length) < 10.0
    assert 3.0 < status.average_speed <= sim.scenario.ego.max_speed
    assert status.min_clearance > 0.5


def test_time_limit_ends_the_episode(small_scenario):
    sim = Simulator(small_scenario(agents=0, **{"episode.time_limit": 1.0}), seed=0)
    sim.reset()
    for _ in range(10):
        frame = sim.step(VelocityCommand(0.0, 0.0))
    assert frame.status.outcome == Outcome.TIMEOUT
    assert abs(frame.status.time - 1.0) < 1e-9 and frame.stamp_ns == 1_000_000_000


def test_frames_become_ros_messages(small_scenario):
    sim = Simulator(small_scenario(agents=20), seed=4)
    first = sim.reset()
    second = sim.step(VelocityCommand(2.0, 0.0))
    cloud = messages.deserialize(
        messages.serialize(scan_cloud(second.scan, second.stamp_ns)), "sensor_msgs/msg/PointCloud2"
    )
    array = cloud_to_array(cloud)
    assert set(array.dtype.names) >= {"x", "y", "z", "intensity", "ring", "time"}
    np.testing.assert_array_equal(array["x"], second.scan.points[:, 0])
    truth = cloud_to_array(truth_cloud(first.scan, second.flow, first.stamp_ns))
    np.testing.assert_array_equal(truth["flow_z"], second.flow.flow[:, 2])
    decoded_obstacles = messages.deserialize(
        messages.serialize(obstacles(second.agents, second.stamp_ns)), "ssf_interfaces/msg/ObstacleArray"
    )
    assert [o.id for o in decoded_obstacles.obstacles] == list(second.agents.ids)
    assert abs(decoded_obstacles.obstacles[0].velocity.x - second.agents.velocity[0, 0]) < 1e-9
    marker_array = markers(second.agents, second.stamp_ns)
    assert len(messages.serialize(marker_array)) > 0 and len(marker_array.markers) == 20
    result = episode_result(second.status, "small", 4, 20, second.stamp_ns)
    decoded = messages.deserialize(messages.serialize(result), "ssf_interfaces/msg/EpisodeResult")
    assert decoded.outcome == 0 and decoded.num_agents == 20


def drive_with_odometer(sim: Simulator, steps: int) -> list:
    """The frames of a drive that speeds up, turns left and brakes."""
    frames = [sim.reset()]
    for step in range(steps):
        command = VelocityCommand(6.0, 0.3 if 10 <= step < 20 else 0.0) if step < 25 else VelocityCommand(0.0, 0.0)
        frames.append(sim.step(command))
    return frames


def test_the_odometer_measures_each_step_and_errs_as_configured(small_scenario):
    """Without errors the wheel speed and the gyro give back the driven motion; with them, the scale error and the
    bias are one per episode and the noise has the configured spread."""
    exact = {f"odometer.{name}": 0.0 for name in ("speed_scale", "speed_noise", "yaw_rate_bias", "yaw_rate_noise")}
    frames = drive_with_odometer(Simulator(small_scenario(agents=0, **exact), seed=1), 30)
    assert frames[0].measured is None
    for before, after in zip(frames, frames[1:]):
        truth = np.linalg.inv(before.pose) @ after.pose  # the sensor's motion over the step
        dt = (after.stamp_ns - before.stamp_ns) * 1e-9
        measured = measured_motion([(after.stamp_ns, *after.measured)], before.stamp_ns, after.stamp_ns,
                                   np.linalg.inv(after.base_pose) @ after.pose)
        assert np.linalg.norm(measured[:2, 3] - truth[:2, 3]) < 1e-3 * max(1.0, after.ego.speed * dt * 10)
        turned = np.arctan2(truth[1, 0], truth[0, 0])
        assert abs(after.measured.yaw_rate * dt - turned) < 1e-4  # planar: the slope tilts the sensor a little
    assert max(frame.measured.speed for frame in frames[1:]) > 5.0
    noisy = {"odometer.speed_noise": 0.05, "odometer.yaw_rate_noise": 0.003}  # scale error and bias as by default
    drawn = []
    for seed in (1, 2):
        sim = Simulator(small_scenario(agents=0, **noisy), seed=seed)
        measured = drive_with_odometer(sim, 60)
        truth = drive_with_odometer(Simulator(small_scenario(agents=0, **exact), seed=seed), 60)
        drawn.append((sim.odometer.scale, sim.odometer.bias))
    assert drawn[0][0] != drawn[1][0] and drawn[0][1] != drawn[1][1]  # drawn once per episode
    speed_error = np.array([m.measured.speed - t.measured.speed for m, t in zip(measured[1:], truth[1:])])
    yaw_error = np.array([m.measured.yaw_rate - t.measured.yaw_rate for m, t in zip(measured[1:], truth[1:])])
    still = np.array([t.measured.speed == 0.0 for t in truth[1:]])  # where the car stands, only the noise is left
    assert still.sum() > 20 and 0.03 < np.std(speed_error[still]) < 0.08
    assert 0.0015 < np.std(yaw_error) < 0.0045 and np.mean(yaw_error) == pytest.approx(sim.odometer.bias, abs=0.002)


def test_the_odometer_is_a_twist_stamped_in_base_link():
    msg = vehicle_twist(MeasuredMotion(4.5, -0.2), 300_000_000)
    assert msg.header.frame_id == "base_link" and messages.stamp_ns(msg.header.stamp) == 300_000_000
    assert (msg.twist.linear.x, msg.twist.angular.z) == (4.5, -0.2)


def test_a_run_without_scans_drives_the_same_world(small_scenario):
    """Drivers that read only the agents (ground truth, the follower) skip the LiDAR: the same traffic, ego, odometer
    and scores step by step, an empty scan and no flow truth."""
    scenario = small_scenario(agents=30)
    with_scans, without = Simulator(scenario, seed=4), Simulator(scenario, seed=4, scans=False)
    frames = [with_scans.reset(), without.reset()]
    for step in range(40):
        command = VelocityCommand(min(6.0, 0.5 * step), 0.05)
        frames = [with_scans.step(command), without.step(command)]
        seen, blind = frames
        assert np.array_equal(seen.agents.position, blind.agents.position) and seen.ego == blind.ego
        assert seen.status == blind.status and seen.measured == blind.measured
    assert len(seen.scan) > 1000 and seen.flow is not None
    assert len(blind.scan) == 0 and blind.scan.points.shape == (0, 3) and blind.flow is None
