"""`ssf bench faults`: the fail-safe campaign. The car must stop when its perception stops.

Each case starts the demo graph (every node its own process, `ssf bench graph`'s machinery), lets the planner drive
until the car is at speed, then breaks one thing: kills a stage (flow, segmentation, fusion, odometry, planner, the
simulator), or replaces the obstacle arrays with stale, NaN, empty or 10 000-obstacle ones. The fault is held until
the car has stood for a second, then ended (the launcher restarts the killed process, the arrays flow again), and the
graph must drive again. Measured from the outside, by simulated time: the braking onset after the last fresh input
(the planner's first stale brake, or the vehicle's own timeout when the planner is dead), the distance from there to
the stop against v * 0.3 s + v^2 / (2 * deceleration), collisions, and the wall seconds until the planner solves
again. Lockstep and real time, in the first drive and in the second (the clock gone back)."""

from __future__ import annotations

import argparse
import fnmatch
import io
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ssf_bringup.bench_graph import Probe, bench_graph_spec, per_node_parameters
from ssf_bringup.launcher import GraphSpec, Launcher
from ssf_common import messages, topics
from ssf_common.diagnostics import Level, read_levels
from ssf_common.errors import ConfigError
from ssf_common.render.frames import header_stamp

ONSET_LIMIT_S = 0.3  # the braking contract: onset at most this long after the last fresh input (simulated time)
DECELERATION = 6.0  # m/s^2: how the planner brakes (its vehicle.max_decel, the simulated car's limit too)
STOPPED_MPS = 0.05  # slower is standing
PERIOD_S = 0.1  # the simulator's step, the period of /clock
ZERO_VELOCITY_DROP = 0.5  # m/s in a step: the simulated car braking at its limit (6 m/s^2), not easing off
STAGES = {"flow": "ssf_flow_node", "seg": "ssf_seg_node", "fusion": "ssf_fusion_node", "odom": "ssf_odom_node",
          "planner": "ssf_planner_node", "sim": "sim_bridge"}
ARRAY_FAULTS = ("stale", "nan", "empty", "flood")
MODES = ("lockstep", "realtime")
FEED = "/ssf/obstacles_feed"  # where the fusion node publishes in the array cases; the injector forwards to /ssf/obstacles
FLOOD_COUNT = 10_000
FLOOD_RADIUS_M = 500.0  # the flood's boxes lie around the car up to this far (a density of ~65 within 40 m)
START_TIMEOUT_S = 600.0  # wall: the graph must bring the car to its fault within this long
RECOVERY_TIMEOUT_S = 120.0  # wall: and solve again within this long after the fault ends


@dataclass(frozen=True)
class Timing:
    """When a case breaks and how long it holds (simulated seconds unless marked wall)."""

    fault_at_s: float = 6.0  # the fault comes this far into its drive once the car is at speed ...
    fault_speed_mps: float = 4.0  # ... this fast
    fault_latest_s: float = 60.0  # ... or then at the latest (a real-time graph on two cores starts slowly)
    first_episode_s: float = 4.0  # second-drive cases: the first drive lasts this long, then the clock starts again
    stood_s: float = 1.0  # a fault is held until the car has stood this long ...
    hold_limit_s: float = 10.0  # ... or this long after the fault
    flood_s: float = 5.0  # a flood of obstacles lasts this long
    sim_down_wall_s: float = 3.0  # a killed simulator stays down this long before the launcher restarts it
    after_s: float = 5.0  # after recovering, the graph drives on this long for a late collision to show


@dataclass(frozen=True)
class FaultCase:
    """One fault: what breaks (kill a stage, or stale / nan / empty / flood obstacle arrays), where, in which drive."""

    fault: str  # kill | stale | nan | empty | flood
    target: str  # a stage of STAGES for kill; obstacles for the arrays
    mode: str  # lockstep | realtime
    episode: int  # 1: the first drive; 2: the second, after the clock went back to zero

    @property
    def name(self) -> str:
        """e.g. kill-flow-realtime-ep2, nan-obstacles-lockstep-ep1."""
        return f"{self.fault}-{self.target}-{self.mode}-ep{self.episode}"


def campaign() -> list[FaultCase]:
    """Every case: each stage killed in both modes and both drives, the arrays in both modes, the simulator killed."""
    cases = [FaultCase("kill", stage, mode, episode) for mode in MODES
             for stage in ("flow", "seg", "fusion", "odom", "planner") for episode in (1, 2)]
    cases += [FaultCase(kind, "obstacles", mode, 1) for mode in MODES for kind in ARRAY_FAULTS]
    return cases + [FaultCase("kill", "sim", mode, 1) for mode in MODES]


def select(cases: list[FaultCase], patterns: str) -> list[FaultCase]:
    """The cases whose names match any of the comma-separated glob patterns (e.g. "kill-flow-*,*-lockstep-ep2")."""
    wanted = [pattern.strip() for pattern in patterns.split(",") if pattern.strip()]
    for pattern in wanted:
        if not any(fnmatch.fnmatchcase(case.name, pattern) for case in cases):
            raise ConfigError(f"--cases: '{pattern}' matches no case; `ssf bench faults --list` names them")
    return [case for case in cases if any(fnmatch.fnmatchcase(case.name, pattern) for pattern in wanted)]


@dataclass
class FaultRecord:
    """What one case did (the JSON record of `ssf bench faults`): times are simulated seconds unless marked wall."""

    case: str
    fault: str
    target: str
    mode: str
    episode: int
    fault_at_s: float | None = None  # when the fault came, in its drive
    speed_at_fault_mps: float | None = None
    last_fresh_s: float | None = None  # the last fresh input (odometry, obstacles, or for a dead planner /cmd_vel)
    onset_s: float | None = None  # braking onset after it (None: nothing went stale: a flood, a dead simulator)
    onset_by: str = ""  # planner (its first stale brake), vehicle (the simulator's cmd_vel_timeout), or standing (a
    # dead planner left the car where it stood)
    stopped: bool = False
    stop_distance_m: float | None = None  # driven from the last fresh input to the stop
    stop_bound_m: float | None = None  # v * 0.3 s + v^2 / (2 * DECELERATION), v: the fastest in between
    collision: bool = False
    recovery_wall_s: float | None = None  # wall seconds from the fault's end to the planner's next solved tick
    brake_reasons: list[str] = field(default_factory=list)  # the planner's reasons while the fault lasted
    tick_ms_p95: float | None = None  # the planner's tick time while the fault lasted
    cmd_vel_hz: float | None = None  # /cmd_vel per wall second while the fault lasted
    diagnostics: dict[str, str] = field(default_factory=dict)  # the worst level each node reported during the fault
    passed: bool = False
    note: str = ""


class TruthSample(NamedTuple):
    """The simulator's ground truth at one step: stamp (ns), position (m), speed (m/s)."""

    stamp_ns: int
    x: float
    y: float
    speed: float


class StateSample(NamedTuple):
    """One /ssf/planner_state: when it came (wall, and the probe's simulated clock, ns), its stamp (the planner's clock,
    ns), status, reason, tick ms."""

    wall: float
    clock_ns: int
    stamp_ns: int
    status: str
    reason: str
    solve_ms: float


class Arrival(NamedTuple):
    """A message seen by the probe: when (wall, and the probe's simulated clock, ns) and its stamp (ns)."""

    wall: float
    clock_ns: int
    stamp_ns: int


class FaultProbe(Probe):
    """`ssf bench graph`'s probe, listening to what a fault campaign measures: the truth of every drive, the planner's
    ticks, the arrivals of its inputs and commands on the simulated clock, every node's diagnostics level."""

    def __init__(self) -> None:
        from ssf_common.middleware import QOS_DEFAULT

        super().__init__(spin=False)
        self.clock_ns = 0
        self.drives: list[list[TruthSample]] = []
        self.states: list[StateSample] = []
        self.arrivals: dict[str, list[Arrival]] = {topics.ODOM: [], topics.OBSTACLES: [], topics.CMD_VEL: []}
        self.levels: list[tuple[float, str, Level, str]] = []  # (wall, node, level, message)
        self.node.create_subscription("ssf_interfaces/msg/PlannerState", topics.PLANNER_STATE, self.on_state,
                                      QOS_DEFAULT)
        self.node.create_subscription("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, self.on_obstacles,
                                      QOS_DEFAULT, raw=True)
        self.node.spin_in_thread()

    def on_clock(self, msg: Any) -> None:
        super().on_clock(msg)
        with self.lock:
            self.clock_ns = messages.stamp_ns(msg.clock)

    def on_truth(self, msg: Any) -> None:
        stamp = messages.stamp_ns(msg.header.stamp)
        position = msg.pose.pose.position
        sample = TruthSample(stamp, float(position.x), float(position.y), float(msg.twist.twist.linear.x))
        with self.lock:
            if not self.drives or stamp < self.drives[-1][-1].stamp_ns:  # the clock went back: the next drive
                self.drives.append([])
            self.drives[-1].append(sample)

    def on_odometry(self, msg: Any) -> None:
        super().on_odometry(msg)
        self._arrived(topics.ODOM, messages.stamp_ns(msg.header.stamp))

    def on_obstacles(self, cdr: bytes) -> None:
        super().on_obstacles(cdr)
        self._arrived(topics.OBSTACLES, header_stamp(cdr))

    def on_command(self, msg: Any) -> None:
        super().on_command(msg)
        self._arrived(topics.CMD_VEL, 0)

    def on_state(self, msg: Any) -> None:
        with self.lock:
            self.states.append(StateSample(time.monotonic(), self.clock_ns, messages.stamp_ns(msg.header.stamp),
                                           msg.status, msg.reason, float(msg.solve_ms)))

    def on_diagnostics(self, msg: Any) -> None:
        super().on_diagnostics(msg)
        now = time.monotonic()
        with self.lock:
            self.levels += [(now, name, level, text) for name, (level, text) in read_levels(msg).items()]

    def _arrived(self, topic: str, stamp_ns: int) -> None:
        with self.lock:
            self.arrivals[topic].append(Arrival(time.monotonic(), self.clock_ns, stamp_ns))

    def now(self) -> tuple[int, TruthSample | None]:
        """The number of drives seen and the newest truth."""
        with self.lock:
            return len(self.drives), (self.drives[-1][-1] if self.drives and self.drives[-1] else None)


class Injector:
    """Forwards the fusion node's obstacle arrays (FEED) to /ssf/obstacles as bytes, or in their place what a fault
    says: the last good array again (stale), NaN centres, an empty array, or 10 000 boxes more (flood)."""

    def __init__(self, probe: FaultProbe, case: FaultCase) -> None:
        from ssf_common.middleware import QOS_DEFAULT, Node

        self.probe, self.case = probe, case
        self.mode = "pass"
        self.last_good: bytes | None = None
        self.last_passed: int | None = None  # the simulated time (ns) of the last array passed
        self.last_before_fault: int | None = None  # ... when the fault began: the planner's last fresh obstacles
        self.node = Node("ssf_bench_fault_injector")
        self.publisher = self.node.create_publisher("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, QOS_DEFAULT)
        self.node.create_subscription("ssf_interfaces/msg/ObstacleArray", FEED, self.on_feed, QOS_DEFAULT, raw=True)
        rng = np.random.default_rng(42)
        radius = np.sqrt(rng.uniform(5.0 ** 2, FLOOD_RADIUS_M ** 2, FLOOD_COUNT))
        angle = rng.uniform(-np.pi, np.pi, FLOOD_COUNT)
        self.clutter = np.c_[radius * np.cos(angle), radius * np.sin(angle), np.zeros(FLOOD_COUNT)]
        self.node.spin_in_thread()

    def on_feed(self, cdr: bytes) -> None:
        from dataclasses import replace

        from ssf_common.conversions import obstacles_from_cdr, obstacles_to_cdr
        from ssf_common.records import Obstacles

        mode = self.mode
        if mode == "pass" or (mode == "stale" and self.last_good is None):
            self.last_good = bytes(cdr)
            self.last_passed = self.when()
            self.publisher.publish_raw(cdr)
            return
        if mode == "stale":
            self.publisher.publish_raw(self.last_good)
            return
        feed = obstacles_from_cdr(cdr)
        if mode == "empty":
            faulty = Obstacles.empty(feed.stamp_ns, feed.frame_id)
        elif mode == "nan":
            faulty = feed if len(feed) else Obstacles(feed.stamp_ns, feed.frame_id, np.array([1]), None,
                                                      np.zeros((1, 3)), np.ones((1, 3)), np.zeros(1), np.zeros((1, 3)))
            faulty = replace(faulty, centres=np.where(np.arange(3) == 0, np.nan, faulty.centres))
        else:
            count = len(self.clutter)
            flood = Obstacles(feed.stamp_ns, feed.frame_id, np.arange(100_000, 100_000 + count), None,
                              self.clutter, np.tile([0.5, 0.5, 1.0], (count, 1)), np.zeros(count), np.zeros((count, 3)))
            faulty = feed.joined(flood)
        self.publisher.publish_raw(obstacles_to_cdr(faulty))

    def inject(self, mode: str) -> None:
        """Put a fault in place of the arrays (or "pass" them again)."""
        if mode != "pass":
            self.last_before_fault = self.last_passed
        self.mode = mode

    def when(self) -> int:
        """Now on the simulated clock, between its ticks in real time (as `_when`)."""
        with self.probe.lock:
            clock = self.probe.clock_ns
        return _when(self.probe, self.case, clock, time.monotonic())

    def close(self) -> None:
        self.node.request_shutdown()
        self.node.destroy_node()


def case_graph(case: FaultCase, scenario: str, parameters: dict[str, dict[str, Any]] | None = None,
               timing: Timing = Timing()) -> GraphSpec:
    """The demo graph for one case: `ssf bench graph`'s spec in the case's mode; the simulator restarted like any node
    (a killed one too) and, for a second-drive case, a short first drive; the fusion node's obstacles through the
    injector for the array cases."""
    graph = bench_graph_spec(scenario, 2 if case.episode == 2 else 1, parameters, mode=case.mode)
    nodes = []
    for node in graph.nodes:
        if node.executable == "sim_bridge":
            extra = {"first_episode_s": timing.first_episode_s} if case.episode == 2 else {}
            node = node.model_copy(update={"required": False, "respawn": True,
                                           "parameters": {**node.parameters, **extra}})
        if node.executable == "ssf_fusion_node" and case.target == "obstacles":
            node = node.model_copy(update={"remappings": {**node.remappings, topics.OBSTACLES: FEED}})
        nodes.append(node)
    return graph.model_copy(update={"nodes": nodes})


class FaultClock:
    """The campaign's view of a running case: the drive, the newest truth, waiting on both with the launcher polled."""

    def __init__(self, launcher: Launcher, probe: FaultProbe, say: Any) -> None:
        self.launcher, self.probe, self.say = launcher, probe, say

    def wait(self, done: Any, timeout_s: float, poll: bool = True) -> bool:
        """Poll the launcher (restarting crashed nodes) until done() or the wall timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if poll:
                self.launcher.poll()
            if done():
                return True
            time.sleep(0.05)
        return done()


def run_case(case: FaultCase, scenario: str, parameters: dict[str, dict[str, Any]] | None = None,
             log: Any = None, say: Any = print, timing: Timing = Timing()) -> FaultRecord:
    """Start the case's graph, bring the car to speed, break it, hold, end the fault, watch it recover; measure."""
    record = FaultRecord(case.name, case.fault, case.target, case.mode, case.episode)
    launcher = Launcher(case_graph(case, scenario, parameters, timing), output=log or io.StringIO())
    probe = FaultProbe()
    injector = Injector(probe, case) if case.target == "obstacles" else None
    clock = FaultClock(launcher, probe, say)
    window: dict[str, float] = {}
    try:
        launcher.start()
        if not clock.wait(lambda: _at_speed(probe, case.episode, timing), START_TIMEOUT_S):
            record.note = f"the car never reached its fault within {START_TIMEOUT_S:g} s"
            return record
        drive, truth = probe.now()
        record.fault_at_s, record.speed_at_fault_mps = round(truth.stamp_ns * 1e-9, 2), round(truth.speed, 2)
        window["fault"] = time.monotonic()
        say(f"  fault at {record.fault_at_s:.1f} s of drive {drive}, {truth.speed:.1f} m/s")
        _inject(case, launcher, injector)
        _hold(case, clock, drive, timing)
        window["end"] = time.monotonic()
        _end(case, launcher, injector)
        say(f"  fault over after {window['end'] - window['fault']:.1f} s (wall); waiting for the graph to drive again")
        recovered = clock.wait(lambda: _solved_since(probe, window["end"]), RECOVERY_TIMEOUT_S)
        if recovered:
            window["recovered"] = next(state.wall for state in list(probe.states)
                                       if state.wall > window["end"] and state.status == "solved")
            _, truth = probe.now()
            after = truth.stamp_ns if truth is not None else 0
            clock.wait(lambda: probe.now()[1] is not None and probe.now()[1].stamp_ns >= after + timing.after_s * 1e9,
                       timing.after_s * 20)
    finally:
        launcher.stop()
        if injector is not None:
            injector.close()
        probe.close()
    return evaluate_fault_case(case, record, probe, window, drive, injector)


def _at_speed(probe: FaultProbe, episode: int, timing: Timing) -> bool:
    """Whether the fault is due: in its drive, with the planner solving (a tick in the last second), fault_at_s in and
    at speed, or fault_latest_s in."""
    drives, truth = probe.now()
    if drives != episode or truth is None or not _solved_since(probe, time.monotonic() - 1.0):
        return False
    seconds = truth.stamp_ns * 1e-9
    return (seconds >= timing.fault_at_s and truth.speed >= timing.fault_speed_mps) or seconds >= timing.fault_latest_s


def _inject(case: FaultCase, launcher: Launcher, injector: Injector | None) -> None:
    if case.fault == "kill":
        launcher.kill(STAGES[case.target])
    else:
        injector.inject(case.fault)


def _hold(case: FaultCase, clock: FaultClock, drive: int, timing: Timing) -> None:
    """Keep the fault (no restart) until the car has stood stood_s, or for the flood flood_s, or the dead simulator
    sim_down_wall_s."""
    probe = clock.probe
    if case.target == "sim":
        time.sleep(timing.sim_down_wall_s)
        return
    start = probe.now()[1].stamp_ns

    def over() -> bool:
        drives, truth = probe.now()
        if drives != drive or truth is None:
            return True
        elapsed = (truth.stamp_ns - start) * 1e-9
        if case.fault == "flood":
            return elapsed >= timing.flood_s
        with probe.lock:
            samples = probe.drives[drive - 1]
            moving = [sample.stamp_ns for sample in samples if sample.speed > STOPPED_MPS]
        stood = (truth.stamp_ns - max(moving[-1], start)) * 1e-9 if moving else elapsed
        return (truth.speed <= STOPPED_MPS and stood >= timing.stood_s) or elapsed >= timing.hold_limit_s

    clock.wait(over, START_TIMEOUT_S, poll=False)


def _end(case: FaultCase, launcher: Launcher, injector: Injector | None) -> None:
    if case.fault == "kill":
        launcher.poll()  # sees the killed process and restarts it, as it would any crash
    else:
        injector.inject("pass")


def _solved_since(probe: FaultProbe, wall: float) -> bool:
    with probe.lock:
        return any(state.wall > wall and state.status == "solved" for state in probe.states)


def evaluate_fault_case(case: FaultCase, record: FaultRecord, probe: FaultProbe, window: dict[str, float], drive: int,
                        injector: Injector | None) -> FaultRecord:
    """The case's figures from what the probe saw (see FaultRecord), and whether it passed."""
    fault, end = window["fault"], window["end"]
    with probe.lock:
        truth = list(probe.drives[drive - 1])
        states = [state for state in probe.states if fault <= state.wall <= end]
        arrivals = {topic: list(items) for topic, items in probe.arrivals.items()}
        levels = [(name, level) for wall, name, level, _ in probe.levels if fault <= wall <= end]
        collision = any(outcome == "collision" for outcome, _ in probe.ended)
    record.collision = collision
    record.brake_reasons = sorted({state.reason.split(" (")[0] for state in states if state.status == "brake"})
    solve = [state.solve_ms for state in states]
    record.tick_ms_p95 = round(float(np.percentile(solve, 95)), 1) if solve else None
    commands = [arrival for arrival in arrivals[topics.CMD_VEL] if fault <= arrival.wall <= end]
    record.cmd_vel_hz = round(len(commands) / max(end - fault, 1e-9), 1)
    for name, level in levels:
        if Level[record.diagnostics.get(name, "OK")] < level:
            record.diagnostics[name] = level.name
    if "recovered" in window:
        record.recovery_wall_s = round(window["recovered"] - end, 2)
    onset_ns, last_ns = _onset(case, states, arrivals, truth, fault, injector, lambda clock, wall: _when(probe, case,
                                                                                                        clock, wall))
    if onset_ns is not None and last_ns is not None:
        record.last_fresh_s, record.onset_s = round(last_ns * 1e-9, 2), round((onset_ns - last_ns) * 1e-9, 2)
        record.onset_by = "vehicle" if case.target == "planner" else "planner"
        _stop(record, truth, last_ns, onset_ns)
    elif last_ns is not None and case.target == "planner":  # the car stood when the planner died, and stays standing
        record.last_fresh_s, record.onset_by = round(last_ns * 1e-9, 2), "standing"
        _stop(record, truth, last_ns, last_ns)
    record.passed, record.note = verdict(case, record)
    return record


def _when(probe: FaultProbe, case: FaultCase, clock_ns: int, wall: float) -> int:
    """The simulated time (ns) of something the probe saw at `wall` while /clock read `clock_ns`. In real time the
    simulated clock runs with the wall clock between its 0.1 s ticks, so the time is taken between them (two processes
    reading a 10 Hz clock see the same moment up to a tick apart); in lockstep it stands still while the graph thinks."""
    shown = probe.shown_at(clock_ns, wall) if case.mode == "realtime" else None
    if shown is None:
        return clock_ns
    return clock_ns + int(round(min(max(wall - shown, 0.0), PERIOD_S) * 1e9))


def _onset(case: FaultCase, states: list[StateSample], arrivals: dict[str, list[Arrival]], truth: list[TruthSample],
           fault: float, injector: Injector | None, when: Any) -> tuple[int | None, int | None]:
    """(when braking began, the last fresh input before it), simulated ns (`when(clock, wall)` of what the probe saw);
    None where nothing went stale."""
    if case.target == "sim" or case.fault == "flood":
        return None, None
    if case.target == "planner":  # the vehicle's own timeout: the first step after the last command braking at its limit
        commands = [when(arrival.clock_ns, arrival.wall) for arrival in arrivals[topics.CMD_VEL] if arrival.wall <= fault]
        if not commands:
            return None, None
        last = commands[-1]
        if any(sample.speed <= STOPPED_MPS for sample in truth if last - PERIOD_S * 1e9 <= sample.stamp_ns <= last):
            return None, last  # standing when its commands stopped: nothing to brake, it stays standing
        for before, after in zip(truth, truth[1:]):
            if before.stamp_ns >= last and (after.speed < before.speed - ZERO_VELOCITY_DROP
                                            or 0.0 == after.speed < before.speed):
                return before.stamp_ns, last
        return None, last
    brake = next((state for state in states if state.status == "brake" and state.reason.startswith("stale_")), None)
    if brake is None:
        return None, None
    braked = when(brake.clock_ns, brake.wall) if case.mode == "realtime" else brake.stamp_ns
    if case.target == "obstacles":
        return braked, injector.last_before_fault
    lasts = [max((when(arrival.clock_ns, arrival.wall) for arrival in arrivals[topic] if arrival.wall <= brake.wall),
                 default=None) for topic in (topics.ODOM, topics.OBSTACLES)]
    return braked, min(last for last in lasts if last is not None)


def _stop(record: FaultRecord, truth: list[TruthSample], last_ns: int, onset_ns: int) -> None:
    """Where the car stopped after the onset: distance driven since the last fresh input (from where the car was
    then, between two steps), and the contract's bound."""
    start = next((index for index, sample in enumerate(truth) if sample.stamp_ns >= last_ns), None)
    if start is None:
        return
    stop = next((index for index in range(start, len(truth))
                 if truth[index].stamp_ns >= onset_ns and truth[index].speed <= STOPPED_MPS), None)
    if stop is None:
        return
    path = np.array([[sample.x, sample.y] for sample in truth[max(start - 1, 0):stop + 1]])
    if start > 0:  # the car's place at last_ns, between the steps around it
        before, after = truth[start - 1], truth[start]
        share = (last_ns - before.stamp_ns) / max(after.stamp_ns - before.stamp_ns, 1)
        path[0] = path[0] + share * (path[1] - path[0])
    speed = max(sample.speed for sample in truth[max(start - 1, 0):stop + 1])
    record.stopped = True
    record.stop_distance_m = round(float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()), 2)
    record.stop_bound_m = round(speed * ONSET_LIMIT_S + speed ** 2 / (2 * DECELERATION), 2)


def verdict(case: FaultCase, record: FaultRecord) -> tuple[bool, str]:
    """Passed: no collision; where an input went stale, braking within ONSET_LIMIT_S and a stop within the bound; a
    flood's ticks within the planner's 100 ms deadline; the graph solving again after the fault."""
    problems = []
    if record.collision:
        problems.append("collision")
    if case.target != "sim" and case.fault != "flood":
        if record.onset_s is None and record.onset_by != "standing":
            problems.append("no braking onset seen")
        elif record.onset_s is not None and record.onset_s > ONSET_LIMIT_S + 1e-6:
            problems.append(f"onset {record.onset_s:.2f} s > {ONSET_LIMIT_S} s")
        if not record.stopped:
            problems.append("did not stop")
        elif record.stop_distance_m > record.stop_bound_m:
            problems.append(f"stopped after {record.stop_distance_m:.1f} m > {record.stop_bound_m:.1f} m")
    if case.fault == "flood" and (record.tick_ms_p95 is None or record.tick_ms_p95 > 100.0):
        problems.append(f"ticks p95 {record.tick_ms_p95} ms over the 100 ms deadline")
    if record.recovery_wall_s is None:
        problems.append("did not recover")
    return not problems, "; ".join(problems)


def format_row(record: FaultRecord) -> str:
    """One markdown row of the README's table."""
    def figure(value: float | None, digits: int = 2) -> str:
        return "–" if value is None else f"{value:.{digits}f}"

    stop = "–" if record.stop_distance_m is None else f"{record.stop_distance_m:.1f} / {record.stop_bound_m:.1f}"
    return (f"| {record.case} | {figure(record.speed_at_fault_mps, 1)} | {figure(record.onset_s)} "
            f"{record.onset_by or ''} | {stop} | {'yes' if record.collision else 'no'} | "
            f"{figure(record.recovery_wall_s, 1)} | {', '.join(record.brake_reasons) or '–'} | "
            f"{'pass' if record.passed else 'FAIL: ' + record.note} |")


TABLE_HEAD = ("| case | speed at fault (m/s) | onset after last fresh input (s) | stop / bound (m) | collision | "
              "recovery (wall s) | planner's brake reasons | verdict |\n| --- | --- | --- | --- | --- | --- | --- | --- |")


def bench_faults_command(args: argparse.Namespace) -> int:
    """ssf bench faults."""
    from ssf_bringup.demo import check_scenario
    from ssf_common.jsonio import write_json
    from ssf_common.paths import check_writable, check_writable_dir

    cases = campaign()
    if args.list:
        print("\n".join(case.name for case in cases))
        return 0
    cases = select(cases, args.cases) if args.cases else cases
    check_scenario(args.scenario)
    if args.json:
        check_writable(args.json, "result file")
    if args.logs:
        check_writable_dir(args.logs, "log folder")
    parameters = per_node_parameters(args.param)
    bench_graph_spec(args.scenario, 1, parameters)  # unknown node names fail here, before any process
    records = []
    say = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731 - progress, beside the table on stdout
    for index, case in enumerate(cases, start=1):
        say(f"[{index}/{len(cases)}] {case.name}")
        log = open(Path(args.logs) / f"{case.name}.log", "w") if args.logs else None  # noqa: SIM115
        try:
            record = run_case(case, args.scenario, parameters, log, say)
        finally:
            if log is not None:
                log.close()
        records.append(record)
        say(f"  {'pass' if record.passed else 'FAIL: ' + record.note}: {format_row(record)}")
        if args.json:
            write_json(args.json, {"scenario": args.scenario, "cases": [asdict(item) for item in records]})
    print(TABLE_HEAD)
    for record in records:
        print(format_row(record))
    failed = [record.case for record in records if not record.passed]
    say(f"{len(records) - len(failed)} of {len(records)} cases passed" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


def add_parser(bench_commands: argparse._SubParsersAction) -> None:
    """`ssf bench faults`."""
    parser = bench_commands.add_parser(
        "faults", help="the fail-safe campaign: kill each stage, corrupt the obstacles, kill the simulator; braking "
        "onset, stopping distance, collisions, recovery",
        description="Runs the demo graph (every node its own process) once per case, drives until the car is at speed, "
        "then breaks one thing: kills flow, segmentation, fusion, odometry or the planner (lockstep and real time, in "
        "the first drive and in the second, after the clock went back), replaces the obstacle arrays with stale, NaN, "
        "empty or 10000-obstacle ones, or kills the simulator. The fault holds until the car has stood for a second; "
        "then the launcher restarts the process (or the arrays flow again) and the graph must drive again. Each case "
        "reports the braking onset after the last fresh input (simulated time; at most 0.3 s), the stopping distance "
        "against v * 0.3 s + v^2 / (2 * 6 m/s^2), collisions and the recovery time; exit 1 when a case fails.")
    parser.add_argument("--cases", default="", metavar="PATTERNS",
                        help="only the cases matching these comma-separated globs, e.g. kill-flow-realtime-ep1 or "
                        "'*-lockstep-*' (default: all; --list names them)")
    parser.add_argument("--list", action="store_true", help="name every case and exit")
    parser.add_argument("--scenario", default="urban_100", help="scenario (default urban_100, the demo's)")
    parser.add_argument("--json", type=Path, help="write one record per case here (rewritten after each case)")
    parser.add_argument("--logs", type=Path, help="write each case's graph output to DIR/CASE.log")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NODE:NAME:=VALUE",
                        help="a node's parameter, e.g. -p ssf_fusion_node:fusion.max_iterations:=1 (repeatable)")
    parser.set_defaults(func=bench_faults_command)
