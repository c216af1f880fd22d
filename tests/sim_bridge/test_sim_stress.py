"""Stress scenarios: each loads, runs, and shows what it promises (on seeds that evaluations never use)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.agents import AgentKind
from sim_bridge.footprints import Rectangles, rectangle_distance
from sim_bridge.scenario import load_scenario, scenario_names
from sim_bridge.simulator import Frame, Simulator
from sim_bridge.world import START_CLEARANCE
from ssf_common.dataset.pairs import PointClass

STRESS = ["stress_junction", "stress_queue", "stress_crossing", "stress_parked", "stress_far"]
LIGHT = {"lidar.columns": 256}  # the promises are about the traffic; a light sweep keeps the tests fast


def episode(name: str, seed: int, after_warmup: int) -> tuple[Simulator, list[Frame]]:
    """The frames an evaluation would cut pairs from: after the scenario's warm-up, `after_warmup` of them."""
    sim = Simulator(load_scenario(name, LIGHT), seed)
    frame = sim.reset()
    driver = sim.follower()
    frames = []
    warmup = int(round(sim.scenario.episode.warmup_s / sim.dt))
    for index in range(warmup + after_warmup):
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
        if index >= warmup:
            frames.append(frame)
    assert all(f.status.outcome.name == "RUNNING" for f in frames)
    return sim, frames


def frenet(sim: Simulator, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return sim.world.centreline.to_frenet(np.atleast_2d(xy))


def moving_vehicle_gaps(sim: Simulator, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Footprint gap from the ego to every moving vehicle, and the vehicles' indices."""
    agents = frame.agents
    moving = np.flatnonzero((agents.kind == AgentKind.VEHICLE) & (np.linalg.norm(agents.velocity, axis=1) > 2.0))
    others = Rectangles(agents.position[moving, :2], agents.yaw[moving], agents.size[moving, 0], agents.size[moving, 1])
    return rectangle_distance(sim.ego.footprint().take(np.zeros(len(moving), int)), others), moving


def test_every_stress_scenario_is_shipped():
    assert set(STRESS) <= set(scenario_names())
    for name in STRESS:
        scenario = load_scenario(name)
        assert scenario.lidar.dropout > 0 and scenario.lidar.mixed_points > 0 and scenario.description


def test_junction_cross_traffic_passes_3_to_6_m_in_front_of_the_waiting_ego():
    sim, frames = episode("stress_junction", 11, 10)
    start = frames[0].base_pose
    heading = np.array([np.cos(frames[0].ego.yaw), np.sin(frames[0].ego.yaw)])
    for frame in frames:
        assert frame.ego.speed == 0.0 and np.array_equal(frame.base_pose, start)
        gaps, moving = moving_vehicle_gaps(sim, frame)
        close = moving[(gaps >= 3.0) & (gaps <= 6.0)]
        direction = frame.agents.velocity[close] / np.linalg.norm(frame.agents.velocity[close], axis=1)[:, None]
        assert (np.abs(direction @ heading) < 0.3).any()  # crossing the ego's view, not coming at it
        assert gaps.min() >= 3.0
    structure = sim.world.structure
    zone = Rectangles(sim.world.start.xy[None], np.array([sim.world.start.yaw]), np.array([4.69]), np.array([1.85]))
    boxes = Rectangles(structure.boxes[:, :2], structure.boxes[:, 2], structure.boxes[:, 3], structure.boxes[:, 4])
    assert rectangle_distance(zone.take(np.zeros(len(structure.boxes), int)), boxes).min() >= START_CLEARANCE


def test_queue_the_ego_crawls_in_the_kerb_lane_while_vehicles_overtake():
    sim, frames = episode("stress_queue", 12, 30)
    kerb = sim.world.lane_offset(1)
    passed = set()
    first_s = {}
    for frame in frames:
        assert frame.ego.speed <= 2.0 + 1e-9
        s_ego, d_ego = frenet(sim, np.array([frame.ego.x, frame.ego.y]))
        assert abs(d_ego[0] - kerb) < 0.3  # it keeps its lane
        agents = frame.agents
        s, d = frenet(sim, agents.position[:, :2])
        speed = np.linalg.norm(agents.velocity, axis=1)
        faster = speed > frame.ego.speed + 1.0
        beside = (agents.kind == AgentKind.VEHICLE) & (np.abs(d - sim.world.lane_offset(0)) < 0.8) & faster
        for index in np.flatnonzero(beside & (np.abs(s - s_ego[0]) < 15.0)):
            first_s.setdefault(index, s[index] - s_ego[0])
            if first_s[index] < 0 < s[index] - s_ego[0]:
                passed.add(index)
    assert frames[-1].ego.speed > 0.3  # crawling, not parked
    assert len(passed) >= 1


def test_crossing_pedestrians_walk_close_in_front_of_the_ego():
    sim, frames = episode("stress_crossing", 13, 20)
    close = 0
    for frame in frames:
        assert frame.ego.speed <= 1.5 + 1e-9
        s_ego, _ = frenet(sim, np.array([frame.ego.x, frame.ego.y]))
        agents = frame.agents
        s, d = frenet(sim, agents.position[:, :2])
        walking = (agents.kind == AgentKind.PEDESTRIAN) & (np.linalg.norm(agents.velocity, axis=1) > 0.5)
        on_road = np.abs(d) < sim.world.section.road_edge
        ahead = (s - s_ego[0] > 0) & (s - s_ego[0] < 12.0)
        close += int((walking & on_road & ahead).sum() > 0)
    assert close >= len(frames) - 2


def test_parked_rows_stand_beside_moving_vehicles_in_the_same_sweep():
    sim, frames = episode("stress_parked", 14, 5)
    for frame in frames[1:]:
        scan, truth = frames[frames.index(frame) - 1].scan, frame.flow
        near = np.linalg.norm(scan.points[:, :2], axis=1) < 25.0
        parked = near & (scan.label == PointClass.PARKED_CAR)
        moving = near & truth.dynamic & (scan.label == PointClass.VEHICLE)
        assert parked.sum() > 100 and moving.sum() > 20
        assert not truth.dynamic[scan.label == PointClass.PARKED_CAR].any()
        assert frame.ego.speed > 3.0


def test_far_the_only_moving_objects_are_35_to_60_m_away():
    sim, frames = episode("stress_far", 15, 10)
    far = 0
    for frame in frames[1:]:
        previous = frames[frames.index(frame) - 1]
        assert frame.ego.speed == 0.0
        dynamic = frame.flow.dynamic
        assert dynamic.sum() > 5
        distance = np.linalg.norm(previous.scan.points[dynamic, :2], axis=1)
        assert distance.min() >= 35.0
        far += int(((distance >= 35.0) & (distance <= 60.0)).sum())
    assert far > 100


@pytest.mark.parametrize("name", STRESS)
def test_stress_scenarios_take_any_sensor(name):
    scenario = load_scenario(name, {"lidar.model": "vlp16", "lidar.rate_hz": 20})
    assert scenario.lidar.spec().beams == 16 and scenario.episode.dt == pytest.approx(0.05)
    assert scenario.lidar.mixed_points == load_scenario(name).lidar.mixed_points
