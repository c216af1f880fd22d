"""Ground-truth scene flow is exact for every sensor model: rigid ego motion for static points, agent motion on
agents, and scan t + flow lies on the surfaces of t+1."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.geometry.se3 import relative_pose as relative_motion
from sim_bridge.lidar import surface_distance
from sim_bridge.meshes import TriangleSoup
from sim_bridge.sensors import sensor_names
from sim_bridge.simulator import Simulator


@pytest.fixture(scope="module", params=sensor_names())
def consecutive(request, small_scenario):
    """Two consecutive frames from mid-episode with moving agents and a moving ego (no range noise), per sensor model."""
    overrides = {"lidar.model": request.param, "lidar.columns": 256 if request.param == "os1_128" else 512,
                 "lidar.range_noise": 0.0, "agents.keep_clear_of_start": 8.0}
    sim = Simulator(small_scenario(agents=60, **overrides), seed=3)
    frame = sim.reset()
    driver = sim.follower()
    for _ in range(15):
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    following = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
    return sim, frame, following


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


def test_static_points_move_with_the_ego_motion_only(consecutive):
    _, first, second = consecutive
    static = first.scan.instance == 0
    points = first.scan.points.astype(np.float64)
    expected = _apply(relative_motion(first.pose, second.pose), points) - points
    assert static.sum() > 1000
    assert np.linalg.norm(expected[static], axis=1).mean() > 0.3  # the ego really moved
    np.testing.assert_allclose(second.flow.flow[static], expected[static], atol=1e-5)
    assert not second.flow.dynamic[static].any()


def test_points_on_agents_carry_the_agent_rigid_motion(consecutive):
    _, first, second = consecutive
    on_agent = np.flatnonzero(first.scan.instance > 0)
    assert len(on_agent) > 50
    points = first.scan.points.astype(np.float64)
    agent_t, agent_next = first.agents.poses(), second.agents.poses()
    for index in on_agent[:: max(1, len(on_agent) // 200)]:
        k = first.scan.instance[index] - 1
        motion = np.linalg.inv(second.pose) @ agent_next[k] @ np.linalg.inv(agent_t[k]) @ first.pose
        expected = _apply(motion, points[index : index + 1])[0] - points[index]
        np.testing.assert_allclose(second.flow.flow[index], expected, atol=1e-5)
    moving = np.linalg.norm(second.agents.position - first.agents.position, axis=1) > 1e-3
    assert np.array_equal(second.flow.dynamic[on_agent], moving[first.scan.instance[on_agent] - 1])
    assert second.flow.dynamic.sum() > 20


def test_scan_plus_flow_lies_on_the_next_surfaces(consecutive):
    sim, first, second = consecutive
    surfaces = TriangleSoup.merge([sim.lidar.static, sim.agent_surfaces(second.agents)])
    landed = first.scan.points.astype(np.float64) + second.flow.flow
    distance = surface_distance(surfaces, _apply(second.pose, landed))
    assert np.percentile(distance, 99.9) < 1e-3
    assert distance.max() < 5e-3  # float32 coordinates at up to 100 m
    dynamic = second.flow.dynamic
    points = first.scan.points.astype(np.float64)
    ego_only = _apply(relative_motion(first.pose, second.pose), points) - points
    assert np.median(np.linalg.norm(second.flow.flow[dynamic] - ego_only[dynamic], axis=1)) > 0.05
