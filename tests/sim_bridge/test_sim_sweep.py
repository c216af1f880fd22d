"""The rolling-shutter sweep: columns fire clockwise from behind across the period, the last at the stamp; each from
where the sensor is then, at each agent where it is then; a straight wall seen while driving is bent by the ego's
motion over each point's time, and straight again once each point is moved by it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sim_bridge.agent_rays import MovingAgentCaster, Pairs
from sim_bridge.agents import AgentKind, AgentStates, agent_mesh
from sim_bridge.ego import EgoVehicle, VelocityCommand
from sim_bridge.lidar import Lidar, ray_fan, soup_distance
from sim_bridge.meshes import TriangleSoup
from sim_bridge.node import SimBridgeNode
from sim_bridge.ros_messages import scan_cloud
from sim_bridge.scenario import LidarConfig, load_scenario
from sim_bridge.simulator import Simulator
from sim_bridge.sweep import Sweep
from ssf_common import messages, pointcloud
from ssf_common.geometry.se3 import make_pose, yaw_of
from ssf_common.pointcloud import cloud_to_array

WALL_X = 15.0
SPEED = 10.0  # m/s along x
MOUNT = 1.8


def wall() -> TriangleSoup:
    """A wall across the x axis at WALL_X, 80 m wide and 13 m high (two triangles), nothing else."""
    corners = np.array([[WALL_X, -40.0, -3.0], [WALL_X, 40.0, -3.0], [WALL_X, 40.0, 10.0], [WALL_X, -40.0, 10.0]])
    return TriangleSoup(corners.astype(np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                        np.full(2, 1, np.uint8), np.full(2, -1, np.int32))


def puck(rolling: bool) -> LidarConfig:
    return LidarConfig(model="vlp16", columns=720, range_noise=0.0, rolling_shutter=rolling)


def driving(agents: AgentStates | None = None, agents_start: AgentStates | None = None) -> Sweep:
    """A sweep of the sensor driving along x at SPEED, ending at the origin (MOUNT above it) at the stamp."""
    period = puck(True).spec().period
    agents = AgentStates.empty() if agents is None else agents
    return Sweep(period, make_pose(-SPEED * period, 0.0, MOUNT), make_pose(0.0, 0.0, MOUNT),
                 agents if agents_start is None else agents_start, agents)


def test_columns_fire_clockwise_from_behind_one_period_long_the_last_at_the_stamp():
    spec = puck(True).spec()
    fan = ray_fan(spec)
    order = np.argsort(fan.column_time)
    azimuth = 2 * np.pi * order / spec.columns  # column c looks at azimuth 2 pi c / columns in the sensor frame
    assert azimuth[0] == pytest.approx(np.pi)  # the first column looks backward: the seam is behind
    steps = np.angle(np.exp(1j * np.diff(azimuth)))
    np.testing.assert_allclose(steps, -2 * np.pi / spec.columns, atol=1e-9)  # clockwise seen from above
    assert fan.column_time[order[-1]] == 0.0 and fan.column_time[order[0]] == pytest.approx(-spec.period, rel=2e-3)
    np.testing.assert_allclose(np.diff(fan.column_time[order]), spec.period / spec.columns, rtol=1e-4)


def test_a_straight_wall_is_bent_by_the_ego_motion_over_each_points_time_and_straight_once_moved_by_it():
    sweep = driving()
    scan = Lidar(puck(True), wall()).scan(sweep, np.random.default_rng(0))
    assert len(scan) > 2000 and scan.time.min() < -0.06 and scan.time.max() > -0.04  # the front half of the turn
    # taken from where the sensor was: the earlier the point, the farther the wall, by the speed times the time
    slope, offset = np.polyfit(scan.time, scan.points[:, 0], 1)
    assert slope == pytest.approx(-SPEED, rel=1e-3) and offset == pytest.approx(WALL_X, abs=1e-3)
    np.testing.assert_allclose(scan.points[:, 0], WALL_X - SPEED * scan.time, atol=2e-4)
    assert np.ptp(scan.points[:, 0]) > 0.3  # bent: not one plane in the sensor frame
    # each point moved by the ego's motion from its time to the stamp: the wall is straight again
    to_stamp = np.linalg.inv(sweep.pose) @ sweep.sensor_poses(scan.time.astype(np.float64))
    deskewed = np.einsum("nij,nj->ni", to_stamp[:, :3, :3], scan.points) + to_stamp[:, :3, 3]
    np.testing.assert_allclose(deskewed[:, 0], WALL_X, atol=2e-4)
    instant = Lidar(puck(False), wall()).scan(sweep, np.random.default_rng(0))
    assert not instant.time.any()
    np.testing.assert_allclose(instant.points[:, 0], WALL_X, atol=2e-4)  # an instant sweep sees it straight


def oncoming_car(x: float, yaw: float) -> AgentStates:
    """One 4.5 x 1.8 x 1.5 m car ahead, its centre at x, heading towards the sensor."""
    return AgentStates(np.array([1], np.int32), np.array([AgentKind.VEHICLE], np.uint8), np.array([[x, 0.5, 0.0]]),
                       np.array([yaw]), np.array([[-SPEED, 0.0]]), np.zeros(1), np.array([[4.5, 1.8, 1.5]]))


def test_each_ray_meets_a_moving_car_where_the_car_is_when_the_ray_fires():
    period = puck(True).spec().period
    before, after = oncoming_car(9.0 + SPEED * period, np.pi - 0.05), oncoming_car(9.0, np.pi - 0.1)  # turning
    still = make_pose(0.0, 0.0, MOUNT)
    sweep = Sweep(period, still, still, before, after)
    scan = Lidar(puck(True), TriangleSoup.empty()).scan(sweep, np.random.default_rng(0))
    on_car = scan.instance == 1
    assert on_car.sum() > 100 and (scan.label[on_car] == 5).all()
    time = scan.time[on_car].astype(np.float64)
    world = scan.points[on_car] + np.array([0.0, 0.0, MOUNT])
    to_stamp = sweep.agent_poses(np.zeros(on_car.sum(), int), np.zeros(on_car.sum())) @ np.linalg.inv(
        sweep.agent_poses(np.zeros(on_car.sum(), int), time))
    carried = np.einsum("nij,nj->ni", to_stamp[:, :3, :3], world) + to_stamp[:, :3, 3]
    car = agent_mesh(after, np.zeros(2), 100.0)
    assert soup_distance(car, carried).max() < 1e-3  # on the car as it was when each ray fired
    assert np.median(soup_distance(car, world)) > 0.2  # not where it is at the stamp: it came ~0.5 m closer


def test_a_sweep_in_which_nothing_moves_is_the_instant_sweep(small_scenario):
    sim = Simulator(small_scenario(agents=40, **{"agents.keep_clear_of_start": 8.0, "lidar.range_noise": 0.0}), seed=2)
    frame = sim.reset()
    still = Sweep.still(frame.pose, frame.agents, sim.lidar.spec.period)
    config = sim.scenario.lidar
    instant = Lidar(config, sim.lidar.static).scan(still, np.random.default_rng(1))
    rolling = Lidar(config.model_copy(update={"rolling_shutter": True}), sim.lidar.static).scan(
        still, np.random.default_rng(1))
    assert (instant.instance > 0).sum() > 100 and len(rolling) == len(instant)
    np.testing.assert_array_equal(rolling.instance, instant.instance)
    np.testing.assert_array_equal(rolling.label, instant.label)
    np.testing.assert_allclose(rolling.points, instant.points, atol=2e-4)
    assert rolling.time.min() < -0.09 and not instant.time.any()


def test_within_a_sweep_the_sensor_follows_the_egos_arc(small_scenario):
    sim = Simulator(small_scenario(agents=0, **{"lidar.rolling_shutter": True}), seed=1)
    sim.reset()
    for turn in [0.0] * 22 + [0.5] * 4:  # up to speed, then into a left turn
        before = sim.ego.state
        frame = sim.step(VelocityCommand(8.0, turn))
    assert frame.ego.speed > 6.0 and frame.ego.yaw_rate == pytest.approx(0.5)
    halfway = EgoVehicle(sim.scenario.ego, sim.world.ground, dataclasses.replace(before, speed=frame.ego.speed))
    halfway.apply(VelocityCommand(frame.ego.speed, frame.ego.yaw_rate), sim.dt / 2)  # the step's own arc, half of it
    expected = halfway.base_pose() @ sim.mount
    middle = frame.sweep.sensor_poses(np.array([-sim.lidar.spec.period / 2]))[0]
    assert np.linalg.norm(middle[:2, 3] - expected[:2, 3]) < 5e-5 and abs(yaw_of(middle) - yaw_of(expected)) < 1e-5
    chord = (frame.sweep.pose_start[:2, 3] + frame.sweep.pose[:2, 3]) / 2
    assert np.linalg.norm(chord - expected[:2, 3]) > 2e-3  # a straight line between the steps would miss the arc


def test_rolling_shutter_is_a_scenario_setting_of_the_node_and_of_scenario_files(tmp_path):
    assert not load_scenario("urban_100").lidar.rolling_shutter  # scenario files: instant (the demo graph turns it on)
    (tmp_path / "rolling.yaml").write_text("agents:\n  count: 0\nlidar:\n  model: vlp16\n  rolling_shutter: true\n")
    assert load_scenario(tmp_path / "rolling.yaml").lidar.spec().rolling_shutter
    small = ["route.waypoints=[[0,0],[60,0]]", "ground.margin=30", "agents.count=0"]
    node = SimBridgeNode(argv=["--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={json.dumps(small)}",
                               "-p", "lidar.rolling_shutter:=true", "-p", "markers:=false"])
    try:
        assert node.sim.lidar.spec.rolling_shutter and node.sim.frame.scan.time.min() < -0.09
        assert node.sim.lidar.spec.summary()["rolling_shutter"] is True
    finally:
        node.destroy_node()


def test_the_published_cloud_carries_each_points_time_and_reads_back(small_scenario):
    for rolling in (False, True):
        sim = Simulator(small_scenario(agents=10, **{"lidar.rolling_shutter": rolling}), seed=4)
        sim.reset()
        frame = sim.step(VelocityCommand(5.0, 0.0))
        msg = messages.deserialize(messages.serialize(scan_cloud(frame.scan, frame.stamp_ns)), pointcloud.POINTCLOUD2)
        cloud = pointcloud.decode_cloud(msg)
        assert cloud.time_problem is None and cloud_to_array(msg)["time"].dtype == np.float32
        if rolling:  # the velodyne_pointcloud layout: float32 s, <= 0, the stamp at the sweep's end
            np.testing.assert_array_equal(cloud.time, frame.scan.time)
            assert cloud.time.max() == 0.0 and cloud.time.min() < -0.09
        else:  # every point at the stamp: no per-point time to deskew with, and nothing wrong with that
            assert cloud.time is None and not cloud_to_array(msg)["time"].any()


class EveryPair(MovingAgentCaster):
    """Casts every ray against every agent: what the culling must agree with."""

    def candidates(self, sweep, rays):
        ray, agent = np.meshgrid(np.arange(len(rays)), np.arange(len(sweep.agents)), indexing="ij")
        return Pairs(ray.reshape(-1), agent.reshape(-1))


def test_the_culled_cast_meets_every_agent_that_casting_every_pair_meets(small_scenario):
    scenario = small_scenario(agents=40, **{"lidar.model": "vlp16", "lidar.columns": 360, "lidar.rolling_shutter": True,
                                            "agents.keep_clear_of_start": 6.0})
    sim = Simulator(scenario, seed=5)
    frame = sim.reset()
    for _ in range(20):
        frame = sim.step(VelocityCommand(9.0, 0.3))
    sweep = frame.sweep
    rays = sim.lidar.world_rays(sweep)
    spec = sim.lidar.spec
    culled = MovingAgentCaster(spec.max_range, spec.columns).cast(sweep, rays, sim.lidar.rays.time)
    every = EveryPair(spec.max_range, spec.columns).cast(sweep, rays, sim.lidar.rays.time)
    assert (every.owner >= 0).sum() > 200 and np.linalg.norm(sweep.pose[:3, 3] - sweep.pose_start[:3, 3]) > 0.5
    np.testing.assert_array_equal(culled.owner, every.owner)
    np.testing.assert_array_equal(culled.distance, every.distance)
