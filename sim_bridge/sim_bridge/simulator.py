"""The simulator: world, traffic, ego vehicle, LiDAR and exact ground truth, stepped at dt in lockstep."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property, partial
from typing import NamedTuple

import numpy as np

from sim_bridge.driver import RouteFollower
from sim_bridge.ego import EgoState, EgoVehicle, Outcome, VelocityCommand
from sim_bridge.footprints import Rectangles, rectangle_circle_distance, rectangle_distance
from sim_bridge.ground_truth import FlowTruth, scene_flow
from sim_bridge.lidar import Lidar, Scan, empty_scan
from sim_bridge.scenario import OdometerConfig, Scenario
from sim_bridge.sweep import Sweep
from sim_bridge.agents import AgentKind, AgentStates, EgoFootprint, agent_mesh
from sim_bridge.traffic import Traffic
from sim_bridge.world import PointClass, World
from ssf_common.checks import require_seed
from ssf_common.geometry.kinematics import measured_sweep
from ssf_common.geometry.se3 import invert

CLEARANCE_RADIUS = 30.0


class MeasuredMotion(NamedTuple):
    """The ego's motion over one step as its own sensors measured it: forward speed (m/s) and yaw rate (rad/s)."""

    speed: float
    yaw_rate: float


class Odometer:
    """The wheel-speed sensor and yaw-rate gyro of one episode: a scale error and a bias drawn once, noise on every
    sample."""

    def __init__(self, config: OdometerConfig, rng: np.random.Generator) -> None:
        self.config, self.rng = config, rng
        self.scale = 1.0 + config.speed_scale * rng.standard_normal()
        self.bias = config.yaw_rate_bias * rng.standard_normal()

    def measure(self, before: EgoState, after: EgoState, dt: float) -> MeasuredMotion:
        """What the sensors report for a step from `before` to `after`: the distance driven along the heading and the
        turn, each over the step (encoder ticks and an integrating gyro), with their errors."""
        turned = float(np.angle(np.exp(1j * (after.yaw - before.yaw))))
        along = np.array([np.cos(before.yaw + turned / 2), np.sin(before.yaw + turned / 2)])  # the step's chord
        driven = float(np.dot([after.x - before.x, after.y - before.y], along))
        speed = driven / dt * self.scale + self.config.speed_noise * self.rng.standard_normal()
        yaw_rate = turned / dt + self.bias + self.config.yaw_rate_noise * self.rng.standard_normal()
        return MeasuredMotion(float(speed), float(yaw_rate))


@dataclass(frozen=True)
class EpisodeStatus:
    """Where the episode stands: outcome so far, time, distance, average speed, min clearance."""

    outcome: Outcome
    time: float
    distance: float
    average_speed: float
    min_clearance: float
    collided_with: str = ""


@dataclass(frozen=True)
class Frame:
    """Everything the simulator knows at one stamp."""

    index: int
    stamp_ns: int
    scan: Scan
    pose: np.ndarray  # (4, 4) world <- lidar
    base_pose: np.ndarray  # (4, 4) world <- base_link
    ego: EgoState
    agents: AgentStates
    sweep: Sweep  # where the sensor and the agents were while the scan was taken (it ends at the stamp)
    status: EpisodeStatus
    truth: Callable[[], FlowTruth | None] = field(default=lambda: None, repr=False, compare=False)  # makes `flow`
    measured: MeasuredMotion | None = None  # the step that ended here, as the odometer saw it (None on the first)

    def measured_sweep(self, start_ns: int) -> np.ndarray | None:
        """The lidar's motion from start_ns (the step's start) to this frame as the odometer measured it (what
        /vehicle/twist says), points of the lidar frame then into this one's; None on the first frame."""
        if self.measured is None:
            return None
        mount = invert(self.base_pose) @ self.pose  # base_link <- lidar
        return measured_sweep([(self.stamp_ns, self.measured.speed, self.measured.yaw_rate)], start_ns, self.stamp_ns,
                              mount)

    @cached_property
    def flow(self) -> FlowTruth | None:
        """Ground truth for the previous frame's scan (None on the first frame), computed on first use: a drive that
        nobody evaluates does not pay for it."""
        return self.truth()


@dataclass
class EpisodeLog:
    """What the episode did, for summaries and pictures."""

    trajectory: list[tuple[float, float]] = field(default_factory=list)
    collisions: list[tuple[float, float, str]] = field(default_factory=list)


class Simulator:
    """Closed-loop LiDAR traffic simulator: `reset()`, then `step(cmd)` every dt; same seed, same frames."""

    def __init__(self, scenario: Scenario, seed: int | None = None, scans: bool = True):
        self.scenario = scenario
        self.scans = scans  # False: no LiDAR scan (and no flow truth) per step, for drivers that read only the agents
        self.seed = scenario.seed if seed is None else require_seed(seed, "seed")
        self.dt = scenario.episode.dt
        self.world = World(scenario, self.seed)
        self.lidar = Lidar(scenario.lidar, self.world.static_mesh())
        self.mount = np.eye(4)
        self.mount[2, 3] = scenario.lidar.mount_height
        self.lane_offset = self.world.lane_offset(scenario.ego.lane)
        self.goal = self.world.centreline.to_xy(np.array(self.world.route_length), np.array(self.lane_offset))
        self._frame: Frame | None = None

    def reset(self) -> Frame:
        """Start the episode: spawn agents, place the ego at the start, take the first scan."""
        start_xy, heading = self.world.start.xy, self.world.start.yaw
        self.ego = EgoVehicle(
            self.scenario.ego, self.world.ground, EgoState(float(start_xy[0]), float(start_xy[1]), heading, 0.0, 0.0)
        )
        self.traffic = place_traffic(self.world, self.seed)
        self._noise = np.random.default_rng([self.seed, 3])
        self.odometer = Odometer(self.scenario.odometer, np.random.default_rng([self.seed, 4]))
        self.index = 0
        self.distance = 0.0
        self.min_clearance = np.inf
        self.outcome = Outcome.RUNNING
        self.collided_with = ""
        self.log = EpisodeLog()
        self._frame = self._observe(None)
        return self._frame

    @property
    def frame(self) -> Frame:
        """The latest frame."""
        if self._frame is None:
            raise RuntimeError("call reset() first")
        return self._frame

    @property
    def done(self) -> bool:
        """Whether the episode has ended (success, collision or timeout)."""
        return self.outcome != Outcome.RUNNING

    def follower(self) -> RouteFollower:
        """The built-in route follower for this scenario's ego lane and reference speed."""
        cfg = self.scenario.ego
        return RouteFollower(self.world, self.lane_offset, cfg.reference_speed, cfg.length, cfg.width, cfg.lane_changes)

    def route_waypoints(self, length: float | None = None, spacing: float = 2.0) -> np.ndarray:
        """(N, 3) world points of the ego's lane from the start to the goal (or `length` metres along it)."""
        end = self.world.route_length if length is None else min(float(length), self.world.route_length)
        s = np.r_[np.arange(0.0, end, spacing), end]
        xy = self.world.centreline.to_xy(s, np.full(len(s), self.lane_offset))
        return np.c_[xy, self.world.ground.height(xy[:, 0], xy[:, 1])]

    def step(self, cmd: VelocityCommand) -> Frame:
        """Advance dt: ego follows cmd, agents move, check the episode, scan, ground truth for the last scan."""
        previous = self.frame
        before = self.ego.state
        if self.done:
            self.ego.stop()
        else:
            self.ego.apply(cmd, self.dt)
        state = self.ego.state
        self.distance += float(np.hypot(state.x - before.x, state.y - before.y))
        self.traffic.step(self.dt, self._ego_footprint())
        self.index += 1
        self._update_outcome()
        self._frame = self._observe(previous, self.odometer.measure(before, state, self.dt))
        return self._frame

    def _ego_footprint(self) -> EgoFootprint:
        s, cfg = self.ego.state, self.scenario.ego
        velocity = s.speed * np.array([np.cos(s.yaw), np.sin(s.yaw)])
        return EgoFootprint(np.array([s.x, s.y]), s.yaw, cfg.length, cfg.width, velocity)

    def _update_outcome(self) -> None:
        """Score the step: clearance, then collision, goal or time limit (the outcome is final once set)."""
        if self.done:
            return
        clearance, hit = self._clearance()
        self.min_clearance = min(self.min_clearance, clearance)
        elapsed = self.index * self.dt
        if hit:
            self.outcome, self.collided_with = Outcome.COLLISION, hit
            self.log.collisions.append((self.ego.state.x, self.ego.state.y, hit))
            self.ego.stop()
        elif self._at_goal():
            self.outcome = Outcome.SUCCESS
        elif elapsed >= self.scenario.episode.time_limit - 1e-9:
            self.outcome = Outcome.TIMEOUT

    def _at_goal(self) -> bool:
        xy = np.array([self.ego.state.x, self.ego.state.y])
        s, d = self.world.centreline.to_frenet(xy[None])
        reached = np.linalg.norm(xy - self.goal) <= self.scenario.ego.goal_tolerance
        passed = s[0] >= self.world.route_length and abs(d[0]) <= self.world.section.road_edge
        return bool(reached or passed)

    def _clearance(self) -> tuple[float, str]:
        """Smallest distance from the ego footprint to any agent or structure, and what it touches."""
        ego = self.ego.footprint()
        centre = ego.centre[0]
        names: list[str] = []
        distances: list[np.ndarray] = []
        agents = self.traffic.states()
        near = np.flatnonzero(np.linalg.norm(agents.position[:, :2] - centre, axis=1) < CLEARANCE_RADIUS)
        vehicles = near[agents.kind[near] == AgentKind.VEHICLE]
        people = near[agents.kind[near] == AgentKind.PEDESTRIAN]
        if len(vehicles):
            others = Rectangles(
                agents.position[vehicles, :2], agents.yaw[vehicles], agents.size[vehicles, 0], agents.size[vehicles, 1]
            )
            distances.append(rectangle_distance(ego.take(np.zeros(len(vehicles), int)), others))
            names += [f"vehicle {agents.ids[i]}" for i in vehicles]
        if len(people):
            distances.append(
                rectangle_circle_distance(
                    ego.take(np.zeros(len(people), int)), agents.position[people, :2], agents.size[people, 0] / 2
                )
            )
            names += [f"pedestrian {agents.ids[i]}" for i in people]
        structure = self.world.structure
        boxes, cylinders = self.world.structure_near(centre, CLEARANCE_RADIUS)
        if len(boxes):
            b = structure.boxes[boxes]
            distances.append(
                rectangle_distance(ego.take(np.zeros(len(boxes), int)), Rectangles(b[:, :2], b[:, 2], b[:, 3], b[:, 4]))
            )
            names += [f"structure {PointClass(structure.box_classes[i]).name.lower()}" for i in boxes]
        if len(cylinders):
            c = structure.cylinders[cylinders]
            distances.append(rectangle_circle_distance(ego.take(np.zeros(len(cylinders), int)), c[:, :2], c[:, 2]))
            names += [f"structure {PointClass(structure.cylinder_classes[i]).name.lower()}" for i in cylinders]
        if not distances:
            return CLEARANCE_RADIUS, ""
        all_distances = np.concatenate(distances)
        nearest = int(all_distances.argmin())
        return float(all_distances[nearest]), names[nearest] if all_distances[nearest] <= 0.0 else ""

    def _observe(self, previous: Frame | None, measured: MeasuredMotion | None = None) -> Frame:
        """Scan from the current ego pose and, given the previous frame, the flow of its scan (`measured`: the step
        to here as the odometer saw it)."""
        base = self.ego.base_pose()
        pose = base @ self.mount
        agents = self.traffic.states()
        period = self.lidar.spec.period
        sweep = Sweep.still(pose, agents, period) if previous is None else Sweep(period, previous.pose, pose,
                                                                                   previous.agents, agents)
        if not self.scans:  # the scan's noise has a generator of its own: skipping scans changes nothing else
            scan = empty_scan()
        else:
            scan = self.lidar.scan(sweep, self._noise)
        truth = (lambda: None) if previous is None or not self.scans else partial(
            scene_flow, previous.scan.points, previous.scan.instance, previous.scan.time, previous.sweep, sweep)
        state = self.ego.state
        self.log.trajectory.append((state.x, state.y))
        elapsed = self.index * self.dt
        status = EpisodeStatus(
            self.outcome,
            elapsed,
            self.distance,
            self.distance / elapsed if elapsed > 0 else 0.0,
            float(self.min_clearance),
            self.collided_with,
        )
        return Frame(self.index, int(round(self.index * self.dt * 1e9)), scan, pose, base, state, agents, sweep, status,
                     truth, measured)

    def agent_surfaces(self, agents: AgentStates):
        """Triangles of every agent (for checking ground truth against surfaces)."""
        return agent_mesh(agents, np.zeros(2), np.inf)


def place_traffic(world: World, seed: int) -> Traffic:
    """The agents of an episode at their start (a ConfigError when this seed cannot place them all)."""
    return Traffic(world, world.scenario.agents, np.random.default_rng([seed, 2]), world.start.xy)


def episode_summary(sim: Simulator, wall_seconds: float, step_ms: list[float] | None = None) -> dict[str, object]:
    """The JSON summary of an episode (what `ssf sim`, the node and `ssf demo` write)."""
    status = sim.frame.status
    summary: dict[str, object] = {
        "scenario": sim.scenario.name,
        "seed": sim.seed,
        "agents": sim.scenario.agents.count,
        "outcome": status.outcome.name.lower(),
        "time": round(status.time, 3),
        "distance": round(status.distance, 3),
        "average_speed": round(status.average_speed, 4),
        "min_clearance": round(status.min_clearance, 4),
        "collided_with": status.collided_with,
        "route_length": round(sim.world.route_length, 2),
        "wall_seconds": round(wall_seconds, 2),
    }
    if step_ms:
        summary["step_ms_median"] = round(float(np.median(step_ms)), 2)
    return summary
