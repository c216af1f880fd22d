"""One navigation trial in process, in lockstep: simulator core -> perception core -> planner core -> simulator,
calling the same core code as the nodes. The route is the simulator's route (A -> B, the ego's lane) in the
odometry frame, i.e. the frame of the ego's start pose: the planner gets no map."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from sim_bridge.agents import AgentKind
from sim_bridge.ego import Outcome, VelocityCommand
from sim_bridge.scenario import Scenario, load_scenario
from sim_bridge.simulator import Simulator
from ssf_common.config import build
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import invert
from ssf_common.records import Obstacles, Plan
from ssf_eval.nav.film import TrialFilm
from ssf_eval.nav.observation import ODOM_FRAME, Observation
from ssf_eval.nav.perception import GroundTruthPerception, make_perception
from ssf_eval.nav.ssf_source import ConsecutiveScans, SsfPose, whole_scan_config
from ssf_planner_node.core.config import PlannerConfig
from ssf_planner_node.core.frames import carried_forward, vehicle_state
from ssf_planner_node.core.models import Command
from ssf_planner_node.core.planner import RdaPlanner, VehicleState
from ssf_planner_node.core.route import Route

# the paper's densities as the shipped scenarios (their vehicle shares); other counts: urban_100 with that count
DENSITY_SCENARIOS = {50: "sparse_50", 100: "urban_100", 200: "urban_200", 500: "dense_500", 800: "dense_800",
                     1000: "crowd_1000"}
PERCEPTION_NAMES = ("gt", "dbscan", "dbscan0", "ssf", "follower")
POSE_SOURCES = ("gt", "ssf")  # the ego pose from the simulator's ground truth or from SSF odometry
STUCK_WINDOW_S = 45.0  # no progress of STUCK_PROGRESS_M along the route in this long: stuck
STUCK_PROGRESS_M = 2.0
MOVING_SPEED_MPS = 0.1  # the car moves (for the paper's moving average speed) when faster than this over a step
QUEUE_REACH_M = 30.0  # a stuck or timed-out trial counts the vehicles standing in the route's lane this far ahead
STANDING_SPEED = 0.5  # m/s: slower is standing
QUEUE_MIN = 2  # that many standing there: the car is behind a queue, not stuck on its own


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
    scenario: dict[str, Any] = field(default_factory=dict)  # scenario overrides (dotted names), e.g. a lighter LiDAR
    video: str = ""  # film the trial into this file (.mp4 or .gif); not part of its key
    latency_s: float = 0.0  # perception answers this long after their scan, as in the real-time graph
    answer_every: int = 1  # perception answers one scan in this many (the others are dropped, as a busy node does)
    loop_iterations: int = 1  # ssf: flow <-> segmentation iterations per scan pair (1: as the real-time graph runs it)

    @property
    def uses_ssf(self) -> bool:
        """Whether the trial runs the SSF chain on the scans (for its obstacles or its pose)."""
        return "ssf" in (self.perception, self.pose) and self.perception != "follower"

    @property
    def key(self) -> str:
        """A unique name of the trial (resume matches on it)."""
        length = "full" if self.route_length is None else f"{self.route_length:g}m"
        timing = f"+late{self.latency_s:g}s-every{self.answer_every}" if self.latency_s or self.answer_every > 1 else ""
        world = "".join(f"+{name}={value}" for name, value in sorted(self.scenario.items()))
        loop = f"+loop{self.loop_iterations}" if self.uses_ssf and self.loop_iterations != 1 else ""
        return f"{self.perception}/{self.agents}/{self.seed}/{length}{timing}{loop}{world}/{self.pose}"


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
    pose: str = "gt"
    pose_error_median_m: float = 0.0  # with --pose ssf: |estimated - true| ego position over the trial
    pose_error_max_m: float = 0.0
    standing_ahead: int | None = None  # stuck or timed out: vehicles standing in the route's lane in the 30 m ahead
    moving_speed_mps: float | None = None  # the paper's moving average speed: distance over the time spent moving
    latency_s: float = 0.0  # perception answered this long after its scan (0: lockstep)
    answer_every: int = 1  # perception answered one scan in this many

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
        return cls(**{name: data[name] for name in cls.__dataclass_fields__ if name in data})


def scenario_for(agents: int, settings: dict[str, Any] | None = None) -> tuple[Scenario, float]:
    """The shipped scenario of a density (or urban_100 with that many agents) and its time limit; the simulator's
    own time limit is lifted (the trial keeps its own)."""
    name = DENSITY_SCENARIOS.get(agents, "urban_100")
    overrides: dict[str, Any] = {**({} if agents in DENSITY_SCENARIOS else {"agents.count": agents}), **(settings or {})}
    limit = load_scenario(name, overrides).episode.time_limit
    return load_scenario(name, {**overrides, "episode.time_limit": 100000.0}), limit


@dataclass(frozen=True)
class Tick:
    """One lockstep tick: what the planner was given (state, pose, obstacles in the odometry frame) and answered."""

    state: VehicleState
    pose: np.ndarray  # (4, 4) odom <- base_link
    obstacles: Obstacles | None
    command: VelocityCommand
    status: str  # the planner's TickStatus value, or "follower"
    plan: Plan | None = None  # the MPC plan (odometry frame); None for the follower


SENT_KEPT = 100  # commands kept to carry a late pose forward: 10 s at 10 Hz, far more than any latency


@dataclass
class MovingTime:
    """Distance and time over the steps in which the car moves (faster than MOVING_SPEED_MPS): the paper's moving
    average speed leaves the time standing in traffic out."""

    seconds: float = 0.0
    metres: float = 0.0

    def add(self, seconds: float, metres: float) -> None:
        """One simulator step of `seconds` in which the car drove `metres`."""
        if seconds > 0 and metres > MOVING_SPEED_MPS * seconds:
            self.seconds += seconds
            self.metres += metres

    @property
    def speed(self) -> float:
        """m/s while moving (0 if it never moved)."""
        return round(self.metres / self.seconds, 3) if self.seconds > 0 else 0.0


class DelayLine:
    """Perception as a loaded real-time graph delivers it: one scan in `every` answered, each `latency_s` late, the
    obstacles and the pose of a scan together (the odometry answers the same scan); the planner plans with the newest
    answer that has arrived (None before the first), its pose carried forward to now by the commands sent since, as
    the planner node does."""

    def __init__(self, latency_s: float, every: int, dt: float) -> None:
        if not (np.isfinite(latency_s) and latency_s >= 0):
            raise ConfigError(f"perception latency must be a finite number of seconds >= 0, got {latency_s}")
        if every < 1:
            raise ConfigError(f"perception must answer at least every scan (answer_every >= 1), got {every}")
        self.delay_ticks = int(round(latency_s / dt))
        self.every = every
        self.pending: list[tuple[int, Obstacles, VehicleState]] = []  # (tick it arrives, answer, pose of its scan)
        self.newest: tuple[Obstacles, VehicleState] | None = None

    def through(self, tick: int, obstacles: Obstacles, state: VehicleState) -> tuple[Obstacles, VehicleState] | None:
        """The answer the planner has at this tick (obstacles, state at their scan), given this tick's scan."""
        if tick % self.every == 0:
            self.pending.append((tick + self.delay_ticks, obstacles, state))
        while self.pending and self.pending[0][0] <= tick:
            self.newest = self.pending.pop(0)[1:]
        return self.newest


class ClosedLoop:
    """Simulator core -> perception core -> planner core -> simulator, one `tick()` per simulated step."""

    def __init__(self, spec: TrialSpec) -> None:
        if spec.perception not in PERCEPTION_NAMES:
            raise ConfigError(f"unknown perception '{spec.perception}'; choose from {', '.join(PERCEPTION_NAMES)}")
        if spec.pose not in POSE_SOURCES:
            raise ConfigError(f"unknown pose source '{spec.pose}'; choose from {', '.join(POSE_SOURCES)}")
        self.spec = spec
        self.scenario, scenario_limit = scenario_for(spec.agents, spec.scenario)
        scans = ConsecutiveScans(whole_scan_config(spec.loop_iterations), every=spec.answer_every) if spec.uses_ssf else None
        self.perception = None if spec.perception == "follower" else make_perception(spec.perception, scans=scans)
        # the LiDAR is cast only for those who read it (a video shows the scan): ground truth and the follower do not
        reads = spec.uses_ssf or bool(spec.video) or (self.perception is not None and self.perception.reads_scan)
        self.sim = Simulator(self.scenario, spec.seed, scans=reads)
        if isinstance(self.perception, GroundTruthPerception):
            self.perception.know(self.sim.world)
        self.frame = self.sim.reset()
        self.world_to_odom = invert(self.frame.base_pose)  # the odometry frame: the ego's start pose
        # both drivers follow the whole route (the follower knows no other); the trial is won `route_length` along it
        self.route = self._route(spec.route_length)
        drive = self.route if spec.route_length is None else self._route(None)
        self.time_limit = spec.time_limit or max(60.0, scenario_limit * self.route.length / self.sim.world.route_length)
        self.follower = self.sim.follower() if spec.perception == "follower" else None
        timed = spec.latency_s > 0 or spec.answer_every > 1
        self.delay = DelayLine(spec.latency_s, spec.answer_every, self.sim.dt) if timed and not self.follower else None
        mount = invert(self.frame.base_pose) @ self.frame.pose  # base_link <- lidar
        # lockstep: simulated time waits for the planner, so no wall-clock deadline (the same trial, the same result)
        # and the corridor of the simulated road for the car's width (both overridden by what the trial's planner says)
        width = build(PlannerConfig, {}, spec.planner, source="planner settings").vehicle.width
        settings = build(PlannerConfig, {"solver": {"deadline_ms": 0.0}, **lanes_corridor(self.sim, width)},
                         spec.planner, source="planner settings")
        self.ssf_pose = None
        if spec.pose == "ssf" and scans is not None:
            limits = (settings.vehicle.max_accel, settings.vehicle.max_decel)  # how the ego follows the commands
            self.ssf_pose = SsfPose(mount, scans, limits=limits)
        self.pose_errors: list[float] = []  # |estimated - true| ego position (m), with --pose ssf
        self.planner = None if self.follower else RdaPlanner(settings, drive)
        self.sent: list[tuple[int, Command]] = []  # (stamp, command) the planner sent, to carry a late pose forward
        self.solve_ms: list[float] = []
        self.perceive_ms: list[float] = []
        self.step_ms: list[float] = []
        self.progress = [(0.0, 0.0)]  # (time, arc length) whenever the ego got STUCK_PROGRESS_M further
        self.moving = MovingTime()
        self.outcome: TrialOutcome | None = None

    def _route(self, length: float | None) -> Route:
        """The route's first `length` metres (all of it: None) in the odometry frame."""
        waypoints = self.sim.route_waypoints(length)
        return Route((waypoints @ self.world_to_odom[:3, :3].T + self.world_to_odom[:3, 3])[:, :2], ODOM_FRAME)

    def tick(self) -> Tick:
        """Perceive, plan, step the simulator, judge the trial."""
        frame = self.frame
        started = time.perf_counter()
        pose, lidar_pose, world_to_odom, speed = self._where(frame)
        state = vehicle_state(frame.stamp_ns, pose, speed)
        obstacles, status, plan = None, "follower", None
        if self.follower is not None:
            command = self.follower.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome)
        else:
            obstacles = self.perception.observe(Observation(frame, lidar_pose, world_to_odom))
            if self.delay is not None:
                obstacles, state = self._late(frame.index, obstacles, state)
            self.perceive_ms.append((time.perf_counter() - started) * 1e3)
            step = self.planner.step(state, obstacles)
            self.solve_ms.append(step.solve_ms)
            command, status = VelocityCommand(step.command.linear, step.command.angular), step.status.value
            plan = step.plan
        self.sent.append((frame.stamp_ns, Command(command.linear, command.angular)))
        del self.sent[:-SENT_KEPT]
        started = time.perf_counter()
        before = self.frame.status
        self.frame = self.sim.step(command)
        self.step_ms.append((time.perf_counter() - started) * 1e3)
        self.moving.add(self.frame.status.time - before.time, self.frame.status.distance - before.distance)
        self.outcome = _judge(self.sim, self.frame, self.route, self.world_to_odom, self.time_limit, self.progress)
        return Tick(state, pose, obstacles, command, status, plan)

    def _late(self, tick: int, obstacles: Obstacles, state: VehicleState) -> tuple[Obstacles | None, VehicleState]:
        """What the planner has now with perception that late: the newest answer's obstacles, and its pose carried
        forward to now by the commands sent since (before the first answer: no obstacles, the pose of now)."""
        answer = self.delay.through(tick, obstacles, state)
        if answer is None:
            return None, state
        limits = self.planner.config.vehicle
        return answer[0], carried_forward(answer[1], self.sent, state.stamp_ns, limits.max_accel, limits.max_decel)

    def _where(self, frame) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Where the ego believes it is: odom <- base_link, odom <- lidar, odom <- world and its speed, from the
        ground truth (--pose gt) or from SSF odometry (--pose ssf)."""
        true_pose = self.world_to_odom @ frame.base_pose
        if self.ssf_pose is None:
            return true_pose, self.world_to_odom @ frame.pose, self.world_to_odom, frame.ego.speed
        lidar_pose = self.ssf_pose.update(frame.stamp_ns, frame.scan.points, self.sent, frame.scan.time,
                                          frame.measured_sweep)
        pose = self.ssf_pose.base_pose
        self.pose_errors.append(float(np.linalg.norm(pose[:3, 3] - true_pose[:3, 3])))
        return pose, lidar_pose, lidar_pose @ invert(frame.pose), self.ssf_pose.speed

    def record(self, started: float) -> TrialRecord:
        """The trial's record (call when the outcome is set)."""
        spec, status = self.spec, self.frame.status
        stats = self.planner.stats if self.planner else None
        return TrialRecord(
            key=spec.key, perception=spec.perception, agents=spec.agents, seed=spec.seed, scenario=self.scenario.name,
            outcome=self.outcome.value if self.outcome else "running", collided_with=status.collided_with,
            navigation_time_s=round(status.time, 2), average_speed_mps=round(status.average_speed, 3),
            path_length_m=round(status.distance, 2), route_length_m=round(self.route.length, 2),
            min_clearance_m=round(float(status.min_clearance), 3), time_limit_s=round(self.time_limit, 1),
            ticks=stats.total if stats else len(self.step_ms), fallbacks=stats.fallbacks if stats else 0,
            fallback_reasons=dict(stats.reasons) if stats else {}, solve_ms_median=_stat(self.solve_ms, 50),
            solve_ms_p95=_stat(self.solve_ms, 95), solve_ms_max=_stat(self.solve_ms, 100),
            perception_ms_median=_stat(self.perceive_ms, 50), step_ms_median=_stat(self.step_ms, 50),
            wall_s=round(time.perf_counter() - started, 1), pose=spec.pose, latency_s=spec.latency_s,
            answer_every=spec.answer_every,
            pose_error_median_m=_stat(self.pose_errors, 50), pose_error_max_m=_stat(self.pose_errors, 100),
            standing_ahead=standing_ahead(self.sim) if self.outcome in (TrialOutcome.STUCK, TrialOutcome.TIMEOUT)
            else None, moving_speed_mps=self.moving.speed)


def lanes_corridor(sim: Simulator, width: float) -> dict[str, Any]:
    """The planner's corridor on the simulated road: the car's body on the lanes of the route's direction, between the
    centre line and the road edge (right-hand traffic), and the lane beside the route's for passing (none on a road
    with one lane each way); `-p corridor_left:=...` or `-p passing.offset:=...` still overrides them."""
    section = sim.world.section
    lanes = [float(lane) for lane in section.lane_centres]
    route_lane = int(np.argmin([abs(lane - sim.lane_offset) for lane in lanes]))
    beside = route_lane + 1 if route_lane + 1 < len(lanes) else route_lane - 1
    return {"corridor_left": max(-sim.lane_offset - width / 2, 0.1),
            "corridor_right": max(sim.lane_offset + section.road_edge - width / 2, 0.1),
            "passing": {"offset": lanes[beside] - lanes[route_lane] if beside >= 0 else 0.0}}


def run_trial(spec: TrialSpec) -> TrialRecord:
    """Drive one trial to its end: success, collision, timeout or stuck."""
    started = time.perf_counter()
    loop = ClosedLoop(spec)
    film = TrialFilm(spec.video) if spec.video else None
    while loop.outcome is None:
        frame = loop.frame
        tick = loop.tick()
        if film is not None:
            film.add(loop, frame, tick)
    record = loop.record(started)
    if film is not None:
        film.write(f"{spec.key}: {record.outcome}")
    return record


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


def standing_ahead(sim: Simulator, reach: float = QUEUE_REACH_M) -> int:
    """Vehicles standing in the route's lane within `reach` metres ahead of the ego: a queue no planner keeping to
    the road passes (0: the road ahead moves, the car is stuck on its own)."""
    agents = sim.traffic.states()
    ego = sim.ego.state
    line, section = sim.world.centreline, sim.world.section
    ego_s, _ = line.to_frenet(np.array([[ego.x, ego.y]]))
    s, d = line.to_frenet(agents.position[:, :2])
    lane_half = 0.5 * section.road_edge / len(section.lane_centres)
    standing = ((agents.kind == AgentKind.VEHICLE) & (np.linalg.norm(agents.velocity, axis=1) < STANDING_SPEED)
                & (s > ego_s[0]) & (s < ego_s[0] + reach) & (np.abs(d - sim.lane_offset) < lane_half))
    return int(standing.sum())


def _stat(values: list[float], percentile: float) -> float:
    return round(float(np.percentile(values, percentile)), 2) if values else 0.0
