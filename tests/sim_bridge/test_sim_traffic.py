"""Traffic: agents never overlap (exact footprints), move along their routes, and are deterministic."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from sim_bridge.footprints import Rectangles, point_rectangle_distance, rectangles_overlap
from sim_bridge.scenario import load_scenario
from sim_bridge.agents import AgentKind, AgentStates, EgoFootprint
from sim_bridge.traffic import Traffic
from sim_bridge.world import World


def overlapping_pairs(agents: AgentStates) -> list[tuple[int, int]]:
    """Pairs of agents whose exact footprints (boxes, discs) intersect."""
    pairs = cKDTree(agents.position[:, :2]).query_pairs(6.0, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    vehicle = agents.kind == AgentKind.VEHICLE
    rects = Rectangles(agents.position[:, :2], agents.yaw, agents.size[:, 0], agents.size[:, 1])
    radius = agents.size[:, 0] / 2
    hit = np.zeros(len(pairs), bool)
    both = vehicle[a] & vehicle[b]
    hit[both] = rectangles_overlap(rects.take(a[both]), rects.take(b[both]))
    mixed = vehicle[a] != vehicle[b]
    box, disc = np.where(vehicle[a], a, b)[mixed], np.where(vehicle[a], b, a)[mixed]
    hit[mixed] = point_rectangle_distance(agents.position[disc, :2], rects.take(box)) < radius[disc]
    people = ~vehicle[a] & ~vehicle[b]
    gap = np.linalg.norm(agents.position[a[people], :2] - agents.position[b[people], :2], axis=1)
    hit[people] = gap < radius[a[people]] + radius[b[people]]
    return [tuple(pair) for pair in pairs[hit]]


def test_overlap_check_detects_overlaps():
    agents = AgentStates(
        ids=np.array([1, 2, 3], np.int32),
        kind=np.array([1, 1, 2], np.uint8),
        position=np.array([[0.0, 0.0, 0.0], [4.0, 1.5, 0.0], [20.0, 0.0, 0.0]]),
        yaw=np.array([0.0, 0.3, 0.0]),
        velocity=np.zeros((3, 2)),
        yaw_rate=np.zeros(3),
        size=np.array([[4.5, 1.8, 1.5], [4.5, 1.8, 1.5], [0.6, 0.6, 1.7]]),
    )
    assert overlapping_pairs(agents) == [(0, 1)]


@pytest.fixture(scope="module")
def world_200():
    scenario = load_scenario("urban_200")
    return scenario, World(scenario, scenario.seed)


def run(world_200, steps: int, seed: int) -> tuple[Traffic, list[AgentStates]]:
    scenario, world = world_200
    start = world.centreline.to_xy(np.array(0.0), np.array(world.lane_offset(0)))
    traffic = Traffic(world, scenario.agents, np.random.default_rng(seed), start)
    history = [traffic.states()]
    for step in range(steps):
        s = 8.0 * 0.1 * step
        ego_xy = world.centreline.to_xy(np.array(s), np.array(world.lane_offset(0)))
        heading = float(world.centreline.heading(np.array(s)))
        ego = EgoFootprint(ego_xy, heading, 4.69, 1.85, 8.0 * np.array([np.cos(heading), np.sin(heading)]))
        traffic.step(0.1, ego)
        history.append(traffic.states())
    return traffic, history


def test_two_hundred_agents_never_overlap_in_two_hundred_steps(world_200):
    traffic, history = run(world_200, 200, seed=11)
    for step, agents in enumerate(history):
        assert overlapping_pairs(agents) == [], f"overlap at step {step}"
        assert np.abs(agents.yaw_rate).max() <= traffic.max_yaw_rate.max() + 1e-9
    first, last = history[0], history[-1]
    travelled = np.linalg.norm(last.position[:, :2] - first.position[:, :2], axis=1)
    assert np.median(travelled) > 0.3 * np.median(traffic.speed) * 20.0  # they get somewhere in 20 s
    kinds = set(np.unique(last.kind))
    assert kinds == {AgentKind.VEHICLE, AgentKind.PEDESTRIAN}


def test_same_seed_same_traffic_bit_for_bit(world_200):
    _, one = run(world_200, 30, seed=5)
    _, two = run(world_200, 30, seed=5)
    _, other = run(world_200, 30, seed=6)
    assert np.array_equal(one[-1].position, two[-1].position)
    assert np.array_equal(one[-1].yaw, two[-1].yaw)
    assert not np.array_equal(one[-1].position, other[-1].position)
