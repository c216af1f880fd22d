"""Solve-time benchmark of the MPC: a straight road with M obstacles kept around the ego (vehicles in the lanes
beside it, pedestrians on the pavements, some crossing), driven closed-loop at the reference speed. The obstacles
do not give way (the simulator's agents do), so fallbacks here are an upper bound."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ssf_common.records import ObstacleKind, Obstacles
from ssf_planner_node.core.config import PlannerConfig
from ssf_planner_node.core.planner import RdaPlanner, VehicleState
from ssf_planner_node.core.route import Route

AHEAD, BEHIND = 40.0, 15.0  # obstacles stay between these distances from the ego (m)


@dataclass(frozen=True)
class BenchRow:
    """Solve times for one obstacle count."""

    obstacles: int
    max_obstacles: int
    max_considered: int
    ticks: int
    solve_ms_median: float
    solve_ms_p95: float
    solve_ms_max: float
    fallbacks: int
    fallback_rate: float
    fallback_reasons: dict[str, int]
    rounds_mean: float
    cpu_ms_median: float = 0.0  # CPU time of a tick (the budget is CPU, the target p95 wall)


class BenchTraffic:
    """M obstacles around a moving ego: vehicles in the two lanes to its left (y = 3.5, 7), pedestrians on the
    pavements (|y| 9-11), a third of them crossing the road."""

    def __init__(self, count: int, rng: np.random.Generator) -> None:
        kinds = rng.choice([ObstacleKind.VEHICLE, ObstacleKind.PEDESTRIAN], count)
        vehicle = kinds == ObstacleKind.VEHICLE
        crossing = ~vehicle & (rng.random(count) < 0.3)
        self.kinds = kinds
        self.offset = rng.uniform(-BEHIND, AHEAD, count)
        self.y0 = np.where(vehicle, rng.choice([3.5, 7.0], count), rng.choice([-1.0, 1.0], count) * rng.uniform(9, 11, count))
        self.vx = np.where(vehicle, rng.uniform(6.0, 12.0, count), rng.uniform(-1.5, 1.5, count))
        self.vy = np.where(crossing, -np.sign(self.y0) * rng.uniform(1.0, 1.8, count), 0.0)
        self.sizes = np.where(vehicle[:, None], np.c_[rng.uniform(4, 5, count), rng.uniform(1.7, 2, count)],
                              np.full((count, 2), 0.6))

    def at(self, t: float, ego_x: float) -> Obstacles:
        """The obstacles at time t: constant velocities, each wrapped to stay within range of the ego."""
        count = len(self.kinds)
        x = ego_x + np.mod(self.offset + self.vx * t - ego_x + BEHIND, AHEAD + BEHIND) - BEHIND
        y = np.where(self.vy != 0, np.mod(self.y0 + self.vy * t + 11.0, 22.0) - 11.0, self.y0)
        return Obstacles(int(round(t * 1e9)), "odom", ids=np.arange(1, count + 1), kinds=self.kinds,
                         centres=np.c_[x, y, np.ones(count)], sizes=np.c_[self.sizes, np.full(count, 1.6)],
                         yaws=np.zeros(count), velocities=np.c_[self.vx, self.vy, np.zeros(count)])


MAX_SLOTS = 50  # the most obstacles a problem takes (AvoidanceConfig.max_obstacles' bound)


def run_bench_planner(config: PlannerConfig, count: int, ticks: int, seed: int = 0) -> BenchRow:
    """Drive `ticks` control periods among `count` obstacles, timing every tick (K = max(count, config's K) up to 50
    obstacles, so that every one is in the problem; beyond, the config's K: a flood goes through the planner's own
    selection, the obstacles.max_considered nearest, then the K nearest to the planned motion)."""
    slots = max(count, config.obstacles.max_obstacles) if count <= MAX_SLOTS else config.obstacles.max_obstacles
    config = config.model_copy(update={"obstacles": config.obstacles.model_copy(update={"max_obstacles": slots})})
    planner = RdaPlanner(config, Route(np.array([[0.0, 0.0], [100000.0, 0.0]])))
    traffic = BenchTraffic(count, np.random.default_rng([seed, count]))
    x, y, yaw, speed = 0.0, 0.0, 0.0, config.reference_speed
    period = config.control_period
    spent, cpu, rounds = [], [], []
    planner.step(VehicleState(0, x, y, yaw, speed), traffic.at(0.0, x))  # warm-up: first call, allocations
    for tick in range(1, ticks + 1):
        t = tick * period
        obstacles = traffic.at(t, x)
        started, started_cpu = time.perf_counter(), time.process_time()
        step = planner.step(VehicleState(int(round(t * 1e9)), x, y, yaw, speed), obstacles)
        spent.append((time.perf_counter() - started) * 1e3)
        cpu.append((time.process_time() - started_cpu) * 1e3)
        rounds.append(step.rounds)
        limit = config.vehicle
        speed += float(np.clip(step.command.linear - speed, -limit.max_decel * period, limit.max_accel * period))
        heading = yaw + step.command.angular * period / 2
        x, y, yaw = x + speed * period * np.cos(heading), y + speed * period * np.sin(heading), yaw + step.command.angular * period
    stats = planner.stats
    return BenchRow(count, slots, config.obstacles.max_considered, ticks, round(float(np.median(spent)), 2), round(float(np.percentile(spent, 95)), 2),
                    round(float(np.max(spent)), 2), stats.fallbacks, round(stats.fallbacks / stats.total, 4),
                    dict(stats.reasons), round(float(np.mean(rounds)), 2), round(float(np.median(cpu)), 2))
