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


def speed_towards_an_oncoming_ego(world_200, share: float, ego_near: bool) -> tuple[float, float]:
    """A lone walker's speed along its way after one step with the ego driving at it from 3.5 m ahead (or far away),
    with agents taking `share` of the avoidance against the ego; and its speed before."""
    scenario, world = world_200
    config = scenario.agents.model_copy(update={"ego_yield": share, "count": 1, "vehicle_fraction": 0.0,
                                                "keep_clear_of_start": 0.0})
    far = EgoFootprint(np.array([1e4, 1e4]), 0.0, 4.69, 1.85, np.zeros(2))
    traffic = Traffic(world, config, np.random.default_rng(5), far.centre)
    for _ in range(5):  # under way
        traffic.step(0.1, far)
    walker = traffic.states()
    way = walker.velocity[0] / np.linalg.norm(walker.velocity[0])
    ego = EgoFootprint(walker.position[0, :2] + 3.5 * way, float(np.arctan2(way[1], way[0])), 4.69, 1.85, -3.0 * way)
    traffic.step(0.1, ego if ego_near else far)
    return float(traffic.states().velocity[0] @ way), float(np.linalg.norm(walker.velocity[0]))


def test_agents_give_way_to_the_ego_by_their_share(world_200):
    """ego_yield 1 (the default): a walker the ego drives at takes all of the avoidance and backs off; 0: it keeps its
    way as if the ego were not there (the ego must give way)."""
    yielding, speed = speed_towards_an_oncoming_ego(world_200, 1.0, ego_near=True)
    assert yielding < 0.0 < speed
    keeping, _ = speed_towards_an_oncoming_ego(world_200, 0.0, ego_near=True)
    unbothered, _ = speed_towards_an_oncoming_ego(world_200, 0.0, ego_near=False)
    assert keeping == pytest.approx(unbothered) == pytest.approx(speed)
