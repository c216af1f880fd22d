"""One navigation trial in process, in lockstep: simulator core -> perception core -> planner core -> simulator,
calling the same core code as the nodes. The route is the simulator's route (A -> B, the ego's lane) in the
odometry frame, i.e. the frame of the ego's start pose: the planner gets no map."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from sim_bridge.ego import Outcome, VelocityCommand
from sim_bridge.scenario import Scenario, load_scenario
from sim_bridge.simulator import Simulator
from ssf_common.config import build
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import invert
from ssf_eval.nav.perception import ODOM_FRAME, Observation, make_perception
from ssf_planner_node.core.config import PlannerConfig
from ssf_planner_node.core.frames import vehicle_state
from ssf_planner_node.core.planner import RdaPlanner, TickStatus
from ssf_planner_node.core.route import Route

# the paper's densities as the shipped scenarios (their vehicle shares); other counts: urban_100 with that count
DENSITY_SCENARIOS = {50: "sparse_50", 100: "urban_100", 200: "urban_200", 500: "dense_500", 800: "dense_800",
                     1000: "crowd_1000"}
PERCEPTION_NAMES = ("gt", "dbscan", "dbscan0", "ssf", "follower")
STUCK_WINDOW_S = 45.0  # no progress of STUCK_PROGRESS_M along the route in this long: stuck
STUCK_PROGRESS_M = 2.0


class TrialOutcome(str, Enum):
    """How a trial ended (mutually exclusive, CrowdNav / social-navigation style)."""

    SUCCESS = "success"
    COLLISION_VEHICLE = "collision_vehicle"
    COLLISION_PEDESTRIAN = "collision_pedestrian"
    COLLISION_STRUCTURE = "collision_structure"
    TIMEOUT = "timeout"
    STUCK = "stuck"


@dataclass(frozen=True)
class TrialSpec:
    """One seeded trial: perception source, agent count, seed, route length, time limit, pose source, planner."""

    perception: str
    agents: int
    seed: int
    route_length: float | None = None  # metres along the scenario's route; None: all of it (~961 m)
    time_limit: float | None = None  # seconds; None: the scenario's, scaled to the route length
    pose: str = "gt"
    planner: dict[str, Any] = field(default_factory=dict)  # PlannerConfig overrides (dotted names)

    @property
    def key(self) -> str:
        """A unique name of the trial (resume matches on it)."""
        length = "full" if self.route_length is None else f"{self.route_length:g}m"
        return f"{self.perception}/{self.agents}/{self.seed}/{length}/{self.pose}"


@dataclass(frozen=True)
class TrialRecord:
    """What a trial did: outcome, time, speed, clearance, path length, fallbacks and costs."""

    key: str
    perception: str
    agents: int
    seed: int
    scenario: str
    outcome: str
    collided_with: str
    navigation_time_s: float
    average_speed_mps: float
    path_length_m: float
    route_length_m: float
    min_clearance_m: float
    time_limit_s: float
    ticks: int
    fallbacks: int
    fallback_reasons: dict[str, int]
    solve_ms_median: float
    solve_ms_p95: float
    solve_ms_max: float
    perception_ms_median: float
    step_ms_median: float
    wall_s: float

    @property
    def success(self) -> bool:
        """Reached the goal without a collision."""
        return self.outcome == TrialOutcome.SUCCESS.value

    def to_json(self) -> dict[str, Any]:
        """A plain dict (one JSONL line)."""
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrialRecord:
        """Back from a JSONL line."""
        return cls(**{name: data[name] for name in cls.__dataclass_fields__})


def scenario_for(agents: int) -> tuple[Scenario, float]:
    """The shipped scenario of a density (or urban_100 with that many agents) and its time limit; the simulator's
    own time limit is lifted (the trial keeps its own)."""
    name = DENSITY_SCENARIOS.get(agents, "urban_100")
    overrides: dict[str, Any] = {} if agents in DENSITY_SCENARIOS else {"agents.count": agents}
    limit = load_scenario(name, overrides).episode.time_limit
    return load_scenario(name, {**overrides, "episode.time_limit": 100000.0}), limit


def run_trial(spec: TrialSpec) -> TrialRecord:
    """Drive one trial to its end: success, collision, timeout or stuck."""
    started = time.perf_counter()
    if spec.perception not in PERCEPTION_NAMES:
        raise ConfigError(f"unknown perception '{spec.perception}'; choose from {', '.join(PERCEPTION_NAMES)}")
    if spec.pose != "gt":
        raise ConfigError("--pose ssf needs the SSF odometry core (ssf_odom_node.core), which is not on this branch; "
                          "use --pose gt")
    scenario, scenario_limit = scenario_for(spec.agents)
    sim = Simulator(scenario, spec.seed)
    frame = sim.reset()
    world_to_odom = invert(frame.base_pose)
    waypoints = sim.route_waypoints(spec.route_length)
    route = Route((waypoints @ world_to_odom[:3, :3].T + world_to_odom[:3, 3])[:, :2], ODOM_FRAME)
    time_limit = spec.time_limit or max(60.0, scenario_limit * route.length / sim.world.route_length)
    follower = sim.follower() if spec.perception == "follower" else None
    perception = None if follower else make_perception(spec.perception)
    # lockstep: simulated time waits for the planner, so no wall-clock deadline (the same trial, the same result)
    settings = build(PlannerConfig, {"solver": {"deadline_ms": 0.0}}, spec.planner, source="planner settings")
    planner = None if follower else RdaPlanner(settings, route)
    solve_ms, perceive_ms, step_ms = [], [], []
    progress = [(0.0, 0.0)]  # (time, arc length)
    outcome = None
    while outcome is None:
        base = world_to_odom @ frame.base_pose
        if follower is not None:
            command = follower.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome)
        else:
            tick = time.perf_counter()
            obstacles = perception.observe(Observation(frame, world_to_odom @ frame.pose, world_to_odom))
            perceive_ms.append((time.perf_counter() - tick) * 1e3)
            plan = planner.step(vehicle_state(frame.stamp_ns, base, frame.ego.speed), obstacles)
            solve_ms.append(plan.solve_ms)
            command = VelocityCommand(plan.command.linear, plan.command.angular)
        tick = time.perf_counter()
        frame = sim.step(command)
        step_ms.append((time.perf_counter() - tick) * 1e3)
        outcome = _judge(sim, frame, route, world_to_odom, time_limit, progress)
    status = frame.status
    stats = planner.stats if planner else None
    return TrialRecord(
        key=spec.key, perception=spec.perception, agents=spec.agents, seed=spec.seed, scenario=scenario.name,
        outcome=outcome.value, collided_with=status.collided_with, navigation_time_s=round(status.time, 2),
        average_speed_mps=round(status.average_speed, 3), path_length_m=round(status.distance, 2),
        route_length_m=round(route.length, 2), min_clearance_m=round(float(status.min_clearance), 3),
        time_limit_s=round(time_limit, 1), ticks=stats.total if stats else len(step_ms),
        fallbacks=stats.fallbacks if stats else 0, fallback_reasons=dict(stats.reasons) if stats else {},
        solve_ms_median=_stat(solve_ms, 50), solve_ms_p95=_stat(solve_ms, 95), solve_ms_max=_stat(solve_ms, 100),
        perception_ms_median=_stat(perceive_ms, 50), step_ms_median=_stat(step_ms, 50),
        wall_s=round(time.perf_counter() - started, 1))


def _judge(sim: Simulator, frame, route: Route, world_to_odom: np.ndarray, time_limit: float,
           progress: list[tuple[float, float]]) -> TrialOutcome | None:
    """The trial's outcome after this step, or None while it goes on."""
    status = frame.status
    if status.outcome == Outcome.COLLISION:
        kind = status.collided_with.split(" ")[0]
        return {"vehicle": TrialOutcome.COLLISION_VEHICLE, "pedestrian": TrialOutcome.COLLISION_PEDESTRIAN}.get(
            kind, TrialOutcome.COLLISION_STRUCTURE)
    xy = (world_to_odom @ frame.base_pose)[:2, 3]
    if route.remaining(xy) <= 0.0 or np.linalg.norm(xy - route.goal) <= sim.scenario.ego.goal_tolerance:
        return TrialOutcome.SUCCESS
    if status.time >= time_limit - 1e-9:
        return TrialOutcome.TIMEOUT
    s = route.length - route.remaining(xy)
    if s >= progress[-1][1] + STUCK_PROGRESS_M:
        progress.append((status.time, s))
    elif status.time - progress[-1][0] >= STUCK_WINDOW_S:
        return TrialOutcome.STUCK
    return None


def _stat(values: list[float], percentile: float) -> float:
    return round(float(np.percentile(values, percentile)), 2) if values else 0.0
