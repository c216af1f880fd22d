"""Episodes: the ego stops on collision and the episode says so; success and timeout; messages."""

from __future__ import annotations

import numpy as np

from sim_bridge.ego import Outcome, VelocityCommand
from sim_bridge.ros_messages import episode_result, markers, obstacles, scan_cloud, truth_cloud
from sim_bridge.simulator import Simulator
from ssf_common import messages
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
