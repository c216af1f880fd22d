"""Ground-truth scene flow is exact for every sensor model, on instant and rolling-shutter sweeps: rigid ego motion
for static points, agent motion on agents, and scan t + flow lies on the surfaces of t+1, each point at its own
time."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import relative_pose as relative_motion
from sim_bridge.lidar import soup_distance
from sim_bridge.meshes import TriangleSoup
from sim_bridge.sensors import sensor_names
from sim_bridge.simulator import Frame, Simulator

SETTINGS = [(name, rolling) for name in sensor_names() for rolling in (False, True)]


@pytest.fixture(scope="module", params=SETTINGS, ids=[f"{name}-{'rolling' if rolling else 'instant'}"
                                                      for name, rolling in SETTINGS])
def consecutive(request, small_scenario):
    """Two consecutive frames from mid-episode with moving agents and a moving ego (no range noise), per sensor model
    and sweep."""
    name, rolling = request.param
    overrides = {"lidar.model": name, "lidar.columns": 256 if name == "os1_128" else 512,
                 "lidar.range_noise": 0.0, "agents.keep_clear_of_start": 8.0, "lidar.rolling_shutter": rolling}
    sim = Simulator(small_scenario(agents=60, **overrides), seed=3)
    frame = sim.reset()
    driver = sim.follower()
    for _ in range(15):
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    following = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    return sim, frame, following


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


def _apply_each(transforms: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.einsum("nij,nj->ni", transforms[:, :3, :3], points) + transforms[:, :3, 3]


def _sensor_poses(frame: Frame, time: np.ndarray) -> np.ndarray:
    """World <- sensor of a frame's sweep at each time (s from its stamp)."""
    return frame.sweep.sensor_poses(time.astype(np.float64))


def _in_world_at_stamp(frame: Frame, points: np.ndarray, time: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """Points taken by a frame's sweep at their times, in the world, those on an agent carried with it to the stamp:
    where they lie on the surfaces as they are at the stamp."""
    world = _apply_each(_sensor_poses(frame, time), points)
    on = np.flatnonzero(instance > 0)
    agent, at = instance[on] - 1, time[on].astype(np.float64)
    to_stamp = frame.sweep.agent_poses(agent, np.zeros(len(on))) @ np.linalg.inv(frame.sweep.agent_poses(agent, at))
    world[on] = _apply_each(to_stamp, world[on])
    return world


def test_the_sweep_takes_its_period_or_no_time(consecutive):
    sim, first, _ = consecutive
    time, period = first.scan.time, sim.lidar.spec.period
    if sim.lidar.spec.rolling_shutter:
        assert time.max() == 0.0 and time.min() == pytest.approx(-period, abs=2 * period / sim.lidar.spec.columns)
        assert np.linalg.norm(first.sweep.pose_start[:3, 3] - first.pose[:3, 3]) > 0.3  # the ego moves in a sweep
    else:
        assert not time.any()
        np.testing.assert_array_equal(_sensor_poses(first, time[:1])[0], first.pose)


def test_static_points_move_with_the_ego_motion_only(consecutive):
    _, first, second = consecutive
    static = first.scan.instance == 0
    points, time = first.scan.points.astype(np.float64), first.scan.time
    motion = np.linalg.inv(_sensor_poses(second, time)) @ _sensor_poses(first, time)  # one period on, per point
    expected = _apply_each(motion, points) - points
    assert static.sum() > 1000
    assert np.linalg.norm(expected[static], axis=1).mean() > 0.3  # the ego really moved
    np.testing.assert_allclose(second.flow.flow[static], expected[static], atol=1e-5)
    assert not second.flow.dynamic[static].any()
    if not time.any():  # an instant sweep: the motion from stamp to stamp
        stamp_to_stamp = _apply(relative_motion(first.pose, second.pose), points) - points
        np.testing.assert_allclose(second.flow.flow[static], stamp_to_stamp[static], atol=1e-5)


def test_points_on_agents_carry_the_agent_rigid_motion(consecutive):
    _, first, second = consecutive
    on_agent = np.flatnonzero(first.scan.instance > 0)
    assert len(on_agent) > 50
    points = first.scan.points.astype(np.float64)
    for index in on_agent[:: max(1, len(on_agent) // 200)]:
        k, at = np.array([first.scan.instance[index] - 1]), first.scan.time[index : index + 1]
        agent_t, agent_next = first.sweep.agent_poses(k, at)[0], second.sweep.agent_poses(k, at)[0]
        motion = (np.linalg.inv(_sensor_poses(second, at)[0]) @ agent_next @ np.linalg.inv(agent_t)
                  @ _sensor_poses(first, at)[0])
        expected = _apply(motion, points[index : index + 1])[0] - points[index]
        np.testing.assert_allclose(second.flow.flow[index], expected, atol=1e-5)
    moving = np.linalg.norm(second.agents.position - first.agents.position, axis=1) > 1e-3
    assert np.array_equal(second.flow.dynamic[on_agent], moving[first.scan.instance[on_agent] - 1])
    assert second.flow.dynamic.sum() > 20


def test_the_scan_lies_on_the_surfaces_where_they_are_at_each_points_time(consecutive):
    sim, first, _ = consecutive
    scan = first.scan
    surfaces = TriangleSoup.merge([sim.lidar.static, sim.agent_surfaces(first.agents)])
    world = _in_world_at_stamp(first, scan.points.astype(np.float64), scan.time, scan.instance)
    distance = soup_distance(surfaces, world)
    assert np.percentile(distance, 99.9) < 1e-3 and distance.max() < 5e-3
    if scan.time.any():  # taken from where the sensor was at the time: from the stamp's pose it would be off
        off_ground = scan.label != 0  # along the ground, a point stays on the ground wherever it is taken from
        wrong = soup_distance(surfaces, _apply(first.pose, scan.points[off_ground].astype(np.float64)))
        assert (wrong > 0.05).mean() > 0.1  # walls and poles facing the motion are off by up to ~0.5 m


def test_scan_plus_flow_lies_on_the_next_surfaces(consecutive):
    sim, first, second = consecutive
    surfaces = TriangleSoup.merge([sim.lidar.static, sim.agent_surfaces(second.agents)])
    landed = first.scan.points.astype(np.float64) + second.flow.flow
    distance = soup_distance(surfaces, _in_world_at_stamp(second, landed, first.scan.time, first.scan.instance))
    assert np.percentile(distance, 99.9) < 1e-3
    assert distance.max() < 5e-3  # float32 coordinates at up to 100 m
    dynamic = second.flow.dynamic
    points = first.scan.points.astype(np.float64)
    ego_only = _apply(relative_motion(first.pose, second.pose), points) - points
    assert np.median(np.linalg.norm(second.flow.flow[dynamic] - ego_only[dynamic], axis=1)) > 0.05
