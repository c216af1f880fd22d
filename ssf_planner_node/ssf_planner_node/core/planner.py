"""The RDA-style MPC: per tick, warm start from the previous plan, then rounds of (1) the dual step: per obstacle and
horizon step the separating direction between planned footprint and predicted obstacle, in closed form, and
(2) the primal step: the QP in states and controls with the distance bounds those directions make linear,
until the plan stops moving or the rounds run out. A failed solve never stalls the car: the previous plan, shifted to
now, if it is still collision-free; else full braking. A late tick (past the deadline) and a stale input (`brake`,
called by the fail safe) brake blind, on the last command's arc. Every brake starts from the lower of the speed last
commanded and the speed measured, each command slower than the last. Every fallback is counted, by its reason. At
most `obstacles.max_considered` obstacles, the nearest, are considered at all (a linear-time selection)."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import NamedTuple

import numpy as np

from ssf_common.geometry.kinematics import PlanarState, driven
from ssf_common.records import ObstacleKind, Obstacles, Plan
from ssf_planner_node.core import avoidance
from ssf_planner_node.core.config import Model, PlannerConfig
from ssf_planner_node.core.failsafe import brake_command
from ssf_planner_node.core.models import Command, command_of, rollout, trajectory
from ssf_planner_node.core.passing import LaneChooser
from ssf_planner_node.core.problem import Reference, TrackingProblem
from ssf_planner_node.core.route import Route


class VehicleState(NamedTuple):
    """Planar ego state in the route's frame at a stamp: position, heading, forward speed."""

    stamp_ns: int
    x: float
    y: float
    yaw: float
    speed: float

    @property
    def vector(self) -> np.ndarray:
        """(4,) x, y, yaw, speed."""
        return np.array([self.x, self.y, self.yaw, self.speed], dtype=np.float64)


HARD_MARGIN = 0.02  # m: a hard distance below the safety distance is this much under the present one (negative
# when a conservative box already overlaps the car: it may move, but not deeper)


class _Candidate(NamedTuple):
    """A round's plan that keeps clear of the obstacles: states, controls, smallest distance to them."""

    states: np.ndarray
    controls: np.ndarray
    clearance: float


class Reason(str, Enum):
    """Why a tick fell back (PlannerState's reason: the key, then details in parentheses)."""

    NO_ROUTE = "no_route"
    SOLVER_FAILED = "solver_failed"
    PLAN_COLLIDES = "plan_collides"
    DEADLINE = "deadline"
    STALE_ODOMETRY = "stale_odometry"
    STALE_OBSTACLES = "stale_obstacles"

    def because(self, detail: str = "") -> str:
        """The reason as PlannerState carries it: `key` or `key (detail)`."""
        return f"{self.value} ({detail})" if detail else self.value


class TickStatus(str, Enum):
    """How a tick's command came about."""

    SOLVED = "solved"  # the MPC's own plan
    SHIFTED = "shifted"  # fallback: the previous plan shifted to now
    HELD = "held"  # between perception answers: the last plan's control for now (nothing new to plan on)
    BRAKE = "brake"  # fallback: full braking
    NO_ROUTE = "no_route"  # nothing to follow: standing still


class PlanStep(NamedTuple):
    """One tick's answer: the command, the plan behind it, how it came about and what it cost."""

    command: Command
    plan: Plan
    status: TickStatus
    reason: str  # why a fallback was taken ("" when solved)
    solve_ms: float
    rounds: int
    obstacles: int  # obstacles in the problem
    clearance: float  # smallest predicted distance to an obstacle along the plan (m; inf without obstacles)
    done: bool  # the goal is reached
    dropped: int = 0  # obstacles beyond the obstacles.max_considered nearest, left out of this tick


@dataclass
class PlannerStats:
    """Ticks by status and fallbacks by reason, since the start."""

    ticks: Counter = field(default_factory=Counter)
    reasons: Counter = field(default_factory=Counter)

    @property
    def fallbacks(self) -> int:
        """Ticks that used a fallback."""
        return self.ticks[TickStatus.SHIFTED] + self.ticks[TickStatus.BRAKE]

    @property
    def total(self) -> int:
        """All ticks."""
        return sum(self.ticks.values())


@dataclass
class _Memory:
    """The last plan: when it was made, its states and controls (the next tick's warm start and fallback)."""

    stamp_ns: int
    states: np.ndarray
    controls: np.ndarray
    clearance: float


class RdaPlanner:
    """Route tracking at the reference speed around moving obstacles; call `step` once per tick."""

    name = "rda"

    def __init__(self, config: PlannerConfig, route: Route | None = None) -> None:
        self.config = config
        self.problem = TrackingProblem(config)
        self._trajectory = trajectory(self.problem.step, config.horizon)
        self.route = route
        self.stats = PlannerStats()
        self.last_command: Command | None = None  # what the last tick commanded: braking starts from it
        self._memory: _Memory | None = None
        self._applied = np.zeros(2)
        self._ego_radius = 0.5 * float(np.hypot(config.vehicle.length, config.vehicle.width))
        self.lanes = LaneChooser(config.passing, config.vehicle, config.reference_speed)

    def set_route(self, route: Route) -> None:
        """Follow another route from now on."""
        self.route = route
        self._memory = None

    def step(self, state: VehicleState, obstacles: Obstacles | None = None, stale: bool = False) -> PlanStep:
        """The command for this tick; obstacles in the route's frame (None: none known); stale caps the speed."""
        started = time.perf_counter()
        cfg = self.config
        if self.route is None:
            return self._finish(self._brake(state, Reason.NO_ROUTE.because(), status=TickStatus.NO_ROUTE), started)
        done = self._done(state)
        obstacles = obstacles if obstacles is not None else Obstacles.empty(state.stamp_ns, self.route.frame_id)
        obstacles, dropped = avoidance.nearest_first(obstacles, state.vector[:2], cfg.obstacles.max_considered)
        # 1. warm start: the previous plan shifted to now (or coasting), and the reference along it
        controls = self._warm_controls(state)
        nominal = rollout(self._trajectory, state.vector, controls)
        offset = self.lanes.choose(self.route, state.vector[:2], state.stamp_ns, obstacles)
        reference = self._reference(nominal, stale, offset)
        # 2. the obstacles nearest to the planned motion, their footprints predicted over the horizon
        latency = (state.stamp_ns - obstacles.stamp_ns) * 1e-9 if len(obstacles) else 0.0
        times = latency + cfg.dt * np.arange(cfg.horizon + 1)
        obstacles = obstacles.take(avoidance.within_range(obstacles, nominal[0, :2], latency, cfg.obstacles.range,
                                                          cfg.obstacles.static_speed))
        if latency > 0 and cfg.obstacles.latency_margin > 0:  # a picture that old is that much less certain
            grown = 2.0 * cfg.obstacles.latency_margin * latency
            obstacles = replace(obstacles, sizes=obstacles.sizes + np.array([grown, grown, 0.0]))
        corners = avoidance.predicted_corners(obstacles, times, cfg.obstacles.static_speed)
        chosen = avoidance.nearest_obstacles(corners, nominal[:, :2], self._ego_radius, cfg.obstacles.max_obstacles,
                                             cfg.obstacles.range)
        corners = corners[:, chosen]
        lanes_kept = obstacles.kinds[chosen] == ObstacleKind.VEHICLE  # the headway band: vehicles keep their lanes
        # 3. rounds of dual step (separating directions) and primal step (QP), until the plan settles; the QP holds
        # the footprint's orientation at the nominal one, so each round's plan is checked against the true shapes and
        # the last one that keeps clear is taken
        planes = self._hyperplanes(nominal, corners, lanes_kept)
        hard = self._hard_distances(planes.distances[0])  # never more than the car has now: one closer may still move
        rounds, solution, clear = 0, None, None
        for rounds in range(1, cfg.solver.iterations + 1):
            solution = self.problem.solve(state.vector, nominal, controls, reference, self._applied,
                                          planes.normals[1:], planes.yaw_gains[1:], planes.offsets[1:],
                                          cfg.obstacles.headway * planes.closing[1:], hard)
            if not solution.success:
                break
            controls = solution.controls
            settled = rollout(self._trajectory, state.vector, controls)
            moved = float(np.linalg.norm(settled[:, :2] - nominal[:, :2], axis=1).max())
            nominal = settled
            planes = self._hyperplanes(nominal, corners, lanes_kept)  # the next round's dual step, the check of this plan
            clearance, intrusion = self._margins(planes.distances)
            if intrusion >= 0.0 and self._next_tick_margin(state, controls, corners) >= 0.0:
                clear = _Candidate(nominal, controls, clearance)
            reference = self._reference(nominal, stale, offset)
            if moved < cfg.solver.tolerance:
                break
        elapsed_ms = (time.perf_counter() - started) * 1e3
        answered = {"rounds": rounds, "count": len(chosen), "done": done, "dropped": dropped}
        if cfg.solver.deadline_ms and elapsed_ms > cfg.solver.deadline_ms:  # its plan is for a moment already past
            return self._finish(self.blind_brake(state, Reason.DEADLINE.because(f"{elapsed_ms:.0f} ms"), count=False),
                                started, **answered)
        if clear is None and (solution is None or not solution.success):
            reason = Reason.SOLVER_FAILED.because(solution.status if solution else "no solution")
            return self._finish(self._fallback(state, corners, reason), started, **answered)
        if clear is None:
            return self._finish(self._fallback(state, corners, Reason.PLAN_COLLIDES.because(f"{clearance:.2f} m")),
                                started, **answered)
        nominal, controls, clearance = clear
        self._memory = _Memory(state.stamp_ns, nominal, controls, clearance)
        command = command_of(cfg, state.vector, controls[0])
        if done:
            command = Command(0.0, 0.0)
        self._applied = controls[0].copy()
        step = PlanStep(command, self._plan(state, nominal, controls), TickStatus.SOLVED, "", 0.0, rounds,
                        len(chosen), clearance, done, dropped)
        return self._finish(step, started)

    def hold(self, state: VehicleState) -> PlanStep | None:
        """A tick with nothing new to plan on (no perception answer since the last plan): that plan's control for now,
        as a solve on the same inputs would find again; None where there is no solved plan to hold, the goal is
        reached, or the plan ends within the next control period (then `step`)."""
        started = time.perf_counter()
        if not self._plan_lasts(state) or self.route is None or self._done(state):
            return None
        cfg, memory = self.config, self._memory
        controls = self._warm_controls(state)
        states = rollout(self._trajectory, state.vector, controls)
        self._applied = controls[0].copy()
        step = PlanStep(command_of(cfg, state.vector, controls[0]), self._plan(state, states, controls),
                        TickStatus.HELD, "", 0.0, 0, 0, memory.clearance, False)
        return self._finish(step, started)

    def _plan_lasts(self, state: VehicleState) -> bool:
        """Whether the last solved plan reaches at least a control period past `state`'s time (it can be followed)."""
        if self._memory is None:
            return False
        elapsed = (state.stamp_ns - self._memory.stamp_ns) * 1e-9
        return 0.0 <= elapsed < self.config.horizon * self.config.dt - self.config.control_period

    def _done(self, state: VehicleState) -> bool:
        """Whether the goal is reached: the route behind the car, or the car standing at its goal."""
        return self.route.remaining(state.vector[:2]) <= 0.0 or \
            np.linalg.norm(state.vector[:2] - self.route.goal) <= self.config.goal_tolerance and state.speed < 0.5

    def blind_brake(self, state: VehicleState, reason: str, count: bool = True) -> PlanStep:
        """A tick that cannot plan (an input stale, the deadline missed): brake on the arc of the last command, from
        the lower of that command's speed and the measured `state.speed`, each command slower than the last; counted
        as a fallback (`count`: here, else by the caller's `_finish`)."""
        cfg = self.config
        command = brake_command(self.last_command, state.speed, cfg.vehicle.max_decel * cfg.control_period)
        speeds = np.maximum(command.linear - cfg.vehicle.max_decel * cfg.dt * np.arange(cfg.horizon), 0.0)
        curvature = command.angular / command.linear if command.linear > 1e-3 else 0.0
        turns = curvature * speeds if cfg.model is Model.UNICYCLE else np.full(
            cfg.horizon, np.arctan(curvature * cfg.vehicle.wheelbase))
        controls = np.c_[np.diff(np.r_[state.speed, speeds]) / cfg.dt, turns]
        states = rollout(self._trajectory, state.vector, controls)
        self._applied = np.zeros(2)
        self._memory = None
        step = PlanStep(command, self._plan(state, states, controls), TickStatus.BRAKE, reason, 0.0, 0, 0,
                        float("inf"), False)
        return self._finish(step, time.perf_counter()) if count else step

    def _finish(self, step: PlanStep, started: float, rounds: int | None = None, count: int | None = None,
                done: bool | None = None, dropped: int | None = None) -> PlanStep:
        self.stats.ticks[step.status] += 1
        if step.reason and step.status is not TickStatus.NO_ROUTE:
            self.stats.reasons[step.reason.split(" (")[0]] += 1
        self.last_command = step.command
        return step._replace(solve_ms=(time.perf_counter() - started) * 1e3,
                             **({"rounds": rounds} if rounds is not None else {}),
                             **({"obstacles": count} if count is not None else {}),
                             **({"done": done} if done is not None else {}),
                             **({"dropped": dropped} if dropped is not None else {}))

    def _warm_controls(self, state: VehicleState) -> np.ndarray:
        """The previous plan's controls from now on (held piecewise), or coasting when there is none."""
        cfg = self.config
        memory = self._memory
        if memory is None:
            return np.zeros((cfg.horizon, 2))
        elapsed = (state.stamp_ns - memory.stamp_ns) * 1e-9
        if not 0.0 <= elapsed < cfg.horizon * cfg.dt:
            return np.zeros((cfg.horizon, 2))
        index = np.minimum(((elapsed + cfg.dt * np.arange(cfg.horizon)) / cfg.dt + 1e-9).astype(int), cfg.horizon - 1)
        controls = memory.controls[index].copy()
        tail = (elapsed + cfg.dt * np.arange(cfg.horizon)) >= cfg.horizon * cfg.dt
        controls[tail, 0] = 0.0
        return controls

    def _reference(self, nominal: np.ndarray, stale: bool, offset: float = 0.0) -> Reference:
        """Route points nearest the nominal positions (steps 1..H), moved `offset` to the left, headings unwrapped to
        the nominal's, speeds."""
        cfg = self.config
        points = self.route.project(nominal[1:, :2])
        s = np.maximum.accumulate(points.s)
        points = self.route.at(s)
        headings = nominal[1:, 2] + np.angle(np.exp(1j * (points.heading - nominal[1:, 2])))
        speeds = self.route.speed_limit(s, cfg.reference_speed, cfg.goal_decel)
        if stale:
            speeds = np.minimum(speeds, cfg.stale_speed)
        return Reference(points.point + offset * points.normal, points.normal, headings, speeds, offset)

    def _hyperplanes(self, nominal: np.ndarray, corners: np.ndarray,
                     lanes_kept: np.ndarray | None = None) -> avoidance.Hyperplanes:
        """The dual step along the nominal trajectory (`lanes_kept`: the obstacles the headway band applies to)."""
        cfg = self.config
        return avoidance.hyperplanes(nominal[:, :2], nominal[:, 2], nominal[:, 3], cfg.vehicle.length,
                                     cfg.vehicle.width, corners, cfg.obstacles.max_obstacles, cfg.obstacles.headway_band,
                                     lanes_kept)

    def _hard_distances(self, now: np.ndarray) -> np.ndarray:
        """Per obstacle slot, the distance no plan may go under: the safety distance, or a little under the present
        one for an obstacle already closer (negative for a box that already overlaps the car)."""
        return np.minimum(self.config.obstacles.safety_distance, now - HARD_MARGIN)

    def _clearance(self, states: np.ndarray, corners: np.ndarray) -> tuple[float, float]:
        """Smallest distance between the planned footprints (steps 1..H) and the predicted obstacles, and the smallest
        margin to a collision: distance 0, or deeper than the hard distance for a box already overlapping the car
        (negative: the plan collides)."""
        if corners.shape[1] == 0:
            return float("inf"), float("inf")
        return self._margins(self._hyperplanes(states, corners).distances)

    def _next_tick_margin(self, state: VehicleState, controls: np.ndarray, corners: np.ndarray) -> float:
        """The margin to a collision where the first control puts the car at the next tick (one control period on,
        against the obstacles predicted to then): the plan's steps lie dt apart, and between them a turn swings the
        rear into what stands beside it; from there on the next tick plans again."""
        if corners.shape[1] == 0:
            return float("inf")
        cfg = self.config
        command = command_of(cfg, state.vector, controls[0])
        ahead = driven(PlanarState(state.x, state.y, state.yaw, state.speed), [(0, command.linear, command.angular)],
                       0, int(round(cfg.control_period * 1e9)), np.inf, np.inf)  # the command's speed at once
        then = corners[:1] + (cfg.control_period / cfg.dt) * (corners[1:2] - corners[:1])  # constant velocities
        distances = self._hyperplanes(np.array([state.vector, [ahead.x, ahead.y, ahead.yaw, ahead.speed]]),
                                      np.concatenate([corners[:1], then])).distances
        now = distances[0]  # not closer than HARD_MARGIN, nor than now where closer: no creeping in by the bound's slack
        floor = np.where(now < 0.0, now - HARD_MARGIN, np.minimum(HARD_MARGIN, now))
        return float((distances[1] - floor).min())

    def _margins(self, distances: np.ndarray) -> tuple[float, float]:
        """`_clearance` from the distances (T, K) of a plan's footprints (step 0: now) to the obstacles."""
        floor = np.minimum(self._hard_distances(distances[0]), 0.0)
        return float(distances[1:].min()), float((distances[1:] - floor).min())

    def _fallback(self, state: VehicleState, corners: np.ndarray, reason: str) -> PlanStep:
        """The previous plan shifted to now while it stays clear of the obstacles; else brake."""
        if self._plan_lasts(state):
            controls = self._warm_controls(state)
            states = rollout(self._trajectory, state.vector, controls)
            clearance, intrusion = self._clearance(states, corners)
            if intrusion >= 0.0 and self._next_tick_margin(state, controls, corners) >= 0.0:
                command = command_of(self.config, state.vector, controls[0])
                self._applied = controls[0].copy()
                return PlanStep(command, self._plan(state, states, controls), TickStatus.SHIFTED, reason, 0.0, 0,
                                corners.shape[1], clearance, False)
        return self._brake(state, reason, corners)

    def _brake(self, state: VehicleState, reason: str, corners: np.ndarray | None = None,
               status: TickStatus = TickStatus.BRAKE) -> PlanStep:
        """Full braking in a straight line, from the lower of the speed last commanded and the measured one."""
        cfg = self.config
        speeds = np.maximum(state.speed - cfg.vehicle.max_decel * cfg.dt * np.arange(cfg.horizon + 1), 0.0)
        controls = np.zeros((cfg.horizon, 2))
        controls[:, 0] = np.diff(speeds) / cfg.dt
        states = rollout(self._trajectory, state.vector, controls)
        self._applied = np.zeros(2)
        self._memory = None
        last = self.last_command.linear if self.last_command is not None and status is TickStatus.BRAKE else np.inf
        start = min(state.speed, last)
        command = Command(max(start - cfg.vehicle.max_decel * cfg.control_period, 0.0), 0.0)
        clearance = self._clearance(states, corners)[0] if corners is not None else float("inf")
        return PlanStep(command, self._plan(state, states, controls), status, reason, 0.0, 0,
                        0 if corners is None else corners.shape[1], clearance, False)

    def _plan(self, state: VehicleState, states: np.ndarray, controls: np.ndarray) -> Plan:
        cfg = self.config
        frame = self.route.frame_id if self.route is not None else ""
        return Plan(state.stamp_ns, frame, cfg.dt * np.arange(cfg.horizon + 1), states.copy(), controls.copy())
