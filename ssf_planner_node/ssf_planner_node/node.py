"""ssf_planner_node: /ssf/obstacles + /odom + a route (A -> B in the odometry frame) -> /cmd_vel and /ssf/plan.

One plan per scan (the simulator's 10 Hz), as soon as its first answer comes: the obstacles of the pair that ends
with it (the fusion node sends them before the odometry has the scan's pose), moved into the odometry frame by the pose
at their stamp, and the scan's pose from the odometry of the one before and the flow's ego motion over the pair (or the
newest odometry), carried forward to now by the commands sent since (`plan_on: odometry`: one plan per odometry). While
the clock runs, a control period and a half without a command sends the last plan's control for now (nothing new came
to plan on; from the newest inputs if something did), so a scan the chain drops or answers late does not cost the car a
command. The fail safe (the core's
`failsafe`): when odometry or obstacles are older than two sensor periods by the node's clock, or silent for
`failsafe.silent_after_s` by the steady clock, every tick and a watchdog on both clocks brake, each command slower than
the last, down to zero, said on /ssf/planner_state (reason stale_odometry, stale_obstacles, deadline, ...) and in one
log line per new condition. Obstacle arrays are read straight from their bytes; bad or implausible ones are dropped."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from ssf_common import messages, pose_msgs, topics
from ssf_common.conversions import (ego_motion_from_msg, obstacles_from_cdr, odometry_from_msg, plan_from_msg,
                                    plan_to_msg)
from ssf_common.diagnostics import ConditionLog, Level, StageStats, advertise
from ssf_common.errors import ConfigError, MessageError, SsfError
from ssf_common.markers import MarkerSet
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, Node, dropped_text, run
from ssf_common.geometry.se3 import invert, yaw_matrix
from ssf_common.records import EgoMotion, Obstacles, OdometryEstimate
from ssf_common.stamps import StampSequence
from ssf_planner_node.core.config import PlannerConfig, PlanTrigger
from ssf_planner_node.core.failsafe import InputWatch, Source, Staleness, implausible_emptiness
from ssf_planner_node.core.frames import (PoseHistory, carried_forward, frame_bridge, obstacles_in_route_frame,
                                         odometry_after, state_of)
from ssf_planner_node.core.models import Command
from ssf_planner_node.core.planner import PlanStep, RdaPlanner, TickStatus, VehicleState
from ssf_planner_node.core.route import Route

BASE_FRAME = "base_link"
EGO_MOTIONS_KEPT = 10
CLOCK_AGREEMENT_S = 10.0  # stamps this close behind the clock are on it (a bag replayed without /clock is not)


class PlannerNode(Node):
    """Translates odometry, obstacles and the route into planner ticks, and their answers into messages."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_planner_node", argv=argv)
        self.config = self.declare_config(PlannerConfig)
        waypoints = self.declare_parameter("route_waypoints", []).value  # x0, y0, x1, y1, ... (odometry frame)
        route_topic = self.declare_parameter("route_topic", topics.ROUTE).value
        report_period = self.declare_parameter("report_period_s", 5.0).value
        # world-frame odometry (e.g. /sim/ground_truth/odom remapped to /odom): its first pose becomes the origin of
        # the route's frame, as an odometry node's frame would start at the first scan
        self.anchor_odometry = self.declare_parameter("anchor_first_odometry", False).value
        self.anchor: np.ndarray | None = None
        self.bridge: np.ndarray | None = None  # route frame <- the frame of a restarted odometry node
        self.planner = RdaPlanner(self.config)
        if waypoints:
            self.planner.set_route(self._route_from_parameter(waypoints))
        self.poses = PoseHistory()
        self.mounts: dict[str, np.ndarray] = {BASE_FRAME: np.eye(4)}
        self.obstacles: Obstacles | None = None  # the newest believed picture (in its own frame)
        self.odometry: OdometryEstimate | None = None  # the newest (in the route's frame)
        self.odometry_position = np.zeros(2)  # ... where it puts the car in its own frame (before any anchor)
        self.inputs = InputWatch(self.config.failsafe, self.config.control_period)
        self.sent: deque[tuple[int, Command]] = deque(maxlen=200)  # (clock stamp, command) for latency compensation
        self.sent_steady_ns: int | None = None  # when the last command went out, by the steady clock
        self.sequence = StampSequence()
        self.cmd_pub = self.create_publisher("geometry_msgs/msg/Twist", topics.CMD_VEL, QOS_DEFAULT)
        self.plan_pub = self.create_publisher("nav_msgs/msg/Path", topics.PLAN, QOS_DEFAULT)
        self.markers = MarkerSet()
        self.marker_pub = self.create_publisher("visualization_msgs/msg/MarkerArray", topics.SSF_MARKERS, QOS_DEFAULT)
        self.state_pub = self.create_publisher("ssf_interfaces/msg/PlannerState", topics.PLANNER_STATE, QOS_DEFAULT)
        self.stats = StageStats(self.get_name())
        diagnostics = advertise(self, self.stats, refresh=self._refresh, inputs=(topics.ODOM, topics.OBSTACLES))
        self.log = ConditionLog(self.get_logger(), diagnostics.repeat_s, diagnostics.lasting_s)
        self.waiting = False  # the newest odometry came while the obstacles were stale: it plans when they come
        self.planned_ns = -1  # the newest scan a plan answered
        self.egos: dict[int, EgoMotion] = {}  # the flow's ego motion of the last few pairs, by their first scan
        self.create_timer(self.config.control_period, self.watchdog)  # behaviour: the node's (simulated) clock ...
        self.create_timer(self.config.control_period / 2, lambda: self.watchdog(steady=True),  # ... and liveness
                          clock=self.get_steady_clock())
        self.create_timer(report_period, self._report)
        source = "parameter route_waypoints" if self.planner.route is not None else route_topic
        self.get_logger().info(f"{self.config.model.value} MPC, horizon {self.config.horizon} x {self.config.dt:g} s, "
                               f"K = {self.config.obstacles.max_obstacles}, route from {source}; brakes when inputs "
                               f"are older than {self.config.failsafe.stale_after_s:g} s")
        if self.planner.route is None:
            self.create_subscription("nav_msgs/msg/Path", route_topic, self.on_route, QOS_LATCHED)
        self.create_subscription("tf2_msgs/msg/TFMessage", topics.TF, self.on_tf, QOS_DEFAULT)
        self.create_subscription("nav_msgs/msg/Odometry", topics.ODOM, self.on_odometry, QOS_DEFAULT)
        self.create_subscription("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, self.on_obstacles, QOS_DEFAULT,
                                 raw=True)
        if self.config.plan_on is PlanTrigger.SCAN:
            self.create_subscription("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION, self.on_ego_motion, QOS_DEFAULT)

    @property
    def said(self) -> set[str]:
        """The conditions there are now (said, or counted while they keep coming back)."""
        return set(self.log.active)

    def _clocks(self) -> tuple[int, int]:
        """Now on the node's clock and on the steady clock (ns)."""
        return self.get_clock().now_ns(), self.get_steady_clock().now_ns()

    def _stale(self, clock_ns: int, steady_ns: int) -> list[Staleness]:
        """The stale inputs now (by the steady clock too while the node's clock runs with it)."""
        running = self.get_clock().running(steady_ns, int(1.5 * self.config.control_period * 1e9))
        return self.inputs.stale(clock_ns, steady_ns, running)

    def _route_from_parameter(self, values: list[float]) -> Route:
        if len(values) % 2 or len(values) < 4:
            raise ConfigError("route_waypoints must be at least two x, y pairs (x0, y0, x1, y1, ...)")
        return Route(np.asarray(values, dtype=np.float64).reshape(-1, 2), "odom")

    def on_route(self, msg: Any) -> None:
        """Follow the route on the route topic (in the odometry frame)."""
        try:
            plan = plan_from_msg(msg)
            self.planner.set_route(Route(plan.states[:, :2], plan.frame_id or "odom"))
        except SsfError as err:
            self.get_logger().warning(f"dropped a route: {err}")
            return
        self.get_logger().info(f"route of {self.planner.route.length:.0f} m in frame '{self.planner.route.frame_id}'")

    def on_tf(self, msg: Any) -> None:
        """Remember how sensors are mounted on base_link (base_link -> sensor transforms)."""
        for item in msg.transforms:
            if item.header.frame_id == BASE_FRAME:
                self.mounts[item.child_frame_id] = pose_msgs.matrix_from_transform(item.transform)

    def on_obstacles(self, cdr: bytes) -> None:
        """Keep the newest obstacles, read straight from their bytes (a flood costs no time); a bad or implausible
        array, a repeat or a late one is not fresh: it is dropped (bad ones said in one line), and the obstacles age."""
        try:
            obstacles = obstacles_from_cdr(cdr)
            problem = implausible_emptiness(self.obstacles, obstacles, self._ego_in(obstacles.frame_id),
                                            self.config.failsafe.vanish_range)
        except MessageError as err:
            problem = str(err)
        if problem:
            self.stats.count("obstacles_dropped_bad")
            self.log.update("bad obstacles", True, dropped_text(topics.OBSTACLES, problem),
                            over=f"{topics.OBSTACLES} good again")
            return
        self.log.update("bad obstacles", False, over=f"{topics.OBSTACLES} good again")
        if self.inputs.take(Source.OBSTACLES, obstacles.stamp_ns, *self._clocks()):
            self.obstacles = obstacles
            if self.odometry is None:
                return
            ahead = self._odometry_after(obstacles.stamp_ns)
            if ahead is not None and ahead.stamp_ns > self.planned_ns:
                self._tick(ahead)  # the pair's second scan, planned before its odometry comes
            elif self.waiting or (self.config.plan_on is PlanTrigger.SCAN and obstacles.stamp_ns > self.planned_ns):
                self._tick(self.odometry)

    def on_ego_motion(self, msg: Any) -> None:
        """Keep the flow's ego motion of each pair for the pose of its second scan (the newest few)."""
        ego = self.decoded(ego_motion_from_msg, msg, topics.EGO_MOTION)
        if ego is not None:
            self.egos[ego.stamp_ns] = ego
            for stamp in sorted(self.egos)[:-EGO_MOTIONS_KEPT]:
                del self.egos[stamp]

    def _odometry_after(self, stamp_ns: int) -> OdometryEstimate | None:
        """The odometry of the scan after `stamp_ns` from the newest odometry, when it is that scan's, and the flow's
        ego motion over the pair (None without either, or without the sensor's mount)."""
        ego = self.egos.get(stamp_ns)
        if ego is None or self.odometry is None:  # (ego motions are kept only when planning on scans)
            return None
        mount = self.mounts.get(ego.frame_id)
        if mount is None or self.odometry.stamp_ns != stamp_ns:
            return None
        return odometry_after(self.odometry, ego, mount)

    def _ego_in(self, frame_id: str) -> np.ndarray:
        """Where the car is (x, y) in a frame obstacles come in: its origin for the car's own frames, else where the
        newest odometry puts it."""
        return np.zeros(2) if frame_id in self.mounts else self.odometry_position

    def on_odometry(self, msg: Any) -> None:
        """Plan from this pose with the newest obstacles; publish the command and the plan."""
        odometry = self.decoded(odometry_from_msg, msg, topics.ODOM)
        if odometry is None:
            return
        if self.sequence.restarted(odometry.stamp_ns):
            self.get_logger().info("odometry stamps jumped back: the stream restarted; the commands sent and the anchor "
                                   "are forgotten")
            self.sent.clear()
            self.anchor = self.bridge = None
            self.odometry = None
            self.planned_ns = -1
            self.egos.clear()
        if not self.inputs.take(Source.ODOMETRY, odometry.stamp_ns, *self._clocks()):
            return  # the same stamp again, or a late one: nothing new to plan from
        self.odometry_position = np.array(odometry.pose[:2, 3], dtype=np.float64)
        if self.anchor_odometry:
            odometry = self._anchored(odometry)
        odometry = self._bridged(odometry)
        self.poses.add(odometry.stamp_ns, odometry.pose)
        self.odometry = odometry
        if self.config.plan_on is PlanTrigger.ODOMETRY or odometry.stamp_ns > self.planned_ns:
            self._tick(odometry)  # (planning on scans, its obstacles usually came first and were planned on)

    @property
    def patience_s(self) -> float:
        """How old odometry and obstacles may get (by the clock) before they no longer count: the latency compensated."""
        return max(self.config.max_latency_s, self.config.stale_after_s)

    def _tick(self, odometry: OdometryEstimate) -> None:
        """One plan from the odometry carried forward to now, with the newest obstacles. While they are stale it
        waits for them (a scan's obstacles may come just after its odometry: braking then would release a lockstep
        simulator's step for nothing); the watchdog brakes if they stay stale."""
        clock_ns, steady_ns = self._clocks()
        self.waiting = bool(self._stale(clock_ns, steady_ns))
        if self.waiting:
            return
        state = self._now(state_of(odometry))
        obstacles, capped = self._obstacles_now(odometry)
        late = self._on_timeline(odometry.stamp_ns) and state.stamp_ns - odometry.stamp_ns > self.patience_s * 1e9
        self.log.update("late odometry", late, f"odometry is {(state.stamp_ns - odometry.stamp_ns) * 1e-9:.1f} s behind "
                        f"the clock: planned from it carried forward, speed capped at {self.config.stale_speed:g} m/s",
                        over="odometry on time again")
        step = self.planner.step(state, obstacles, stale=capped or late)
        answered = max(odometry.stamp_ns, self.obstacles.stamp_ns if self.obstacles is not None else -1)
        self.planned_ns = max(self.planned_ns, answered)
        if step.status is TickStatus.BRAKE and step.reason.startswith("deadline"):
            self.inputs.braked(clock_ns, steady_ns)
            self._say_braking(step.reason)
        else:
            self.inputs.released()
            self._say_braking("")
        if step.dropped:
            self.stats.count("obstacles_dropped", step.dropped)
        self.log.update("obstacles dropped", step.dropped > 0, f"{step.dropped} obstacles dropped: only the "
                        f"{self.config.obstacles.max_considered} nearest are considered", over="no obstacles dropped")
        self._publish_step(step, answered)
        if step.status in (TickStatus.SHIFTED, TickStatus.BRAKE):
            self.get_logger().debug(f"fallback ({step.status.value}): {step.reason}")

    def _blind_brake(self, odometry: OdometryEstimate, stale: list[Staleness]) -> PlanStep:
        """The next braking command (the core's), from the newest odometry carried forward, at its measured speed."""
        first = stale[0]
        state = self._now(state_of(odometry))._replace(speed=float(odometry.twist[0]))
        step = self.planner.blind_brake(state, f"{first.reason} ({first.detail})")
        self._say_braking(step.reason)
        return step

    def _say_braking(self, reason: str) -> None:
        """Say when braking starts (each reason a condition of its own) and when the car may drive again."""
        key = reason.split(" (")[0]
        for other in [name for name in self.log.active if name.startswith("brake ") and name != f"brake {key}"]:
            self.log.update(other, False, over=f"{other[6:]} over" if key else "inputs fresh again: planning resumes")
        if key:
            self.log.update(f"brake {key}", True, f"braking to a stop: {reason}", Level.WARN)
        self.stats.report("braking", Level.WARN if key else Level.OK, f"braking: {reason}")

    def _publish_step(self, step: PlanStep, stamp_ns: int) -> None:
        """A tick's command, plan, markers and /ssf/planner_state (stamped with the newest scan it answers, or the
        clock for a brake the watchdog decided)."""
        self._publish(step.command)
        self.plan_pub.publish(plan_to_msg(step.plan))
        if self.marker_pub.get_subscription_count():  # markers are for people watching: none are built for nobody
            self.marker_pub.publish(self.markers.plan(step.plan))
        self._publish_state(stamp_ns, step)
        if step.status is TickStatus.HELD:
            self.stats.count("held")
        else:
            self.stats.record(step.solve_ms, "ticks")

    def _now(self, state: VehicleState) -> VehicleState:
        """The odometry's state carried forward to now by the commands sent since its stamp: the perception chain's
        latency would otherwise put the plan's start where the car was, not where it is."""
        now_ns = self.get_clock().now_ns()
        if self.config.max_latency_s == 0 or now_ns <= state.stamp_ns or not self._on_timeline(state.stamp_ns):
            return state
        vehicle = self.config.vehicle
        return carried_forward(state, list(self.sent), now_ns, vehicle.max_accel, vehicle.max_decel)

    def _on_timeline(self, stamp_ns: int) -> bool:
        """Whether a stamp is on the clock's time line (not more than CLOCK_AGREEMENT_S behind it, not ahead)."""
        return 0 <= self.get_clock().now_ns() - stamp_ns <= CLOCK_AGREEMENT_S * 1e9

    def _publish_state(self, stamp_ns: int, step: PlanStep) -> None:
        """The tick on /ssf/planner_state (what the viewer plots: solve time, fallbacks, clearance)."""
        self.state_pub.publish(messages.msg_type("ssf_interfaces/msg/PlannerState")(
            header=messages.header(stamp_ns, self.planner.route.frame_id if self.planner.route else "odom"),
            status=step.status.value, reason=step.reason, solve_ms=float(step.solve_ms), rounds=int(step.rounds),
            obstacles=int(step.obstacles), clearance=float(step.clearance) if math.isfinite(step.clearance) else -1.0,
            fallbacks=int(self.planner.stats.fallbacks)))

    def _anchored(self, odometry: OdometryEstimate) -> OdometryEstimate:
        """Odometry re-expressed from its first pose, in the route's frame."""
        if self.anchor is None:
            self.anchor = invert(odometry.pose)
            self.anchor_frame = odometry.frame_id
            self.get_logger().info(f"route frame anchored at the first pose in '{odometry.frame_id}'")
        frame = self.planner.route.frame_id if self.planner.route is not None else "odom"
        return replace(odometry, pose=self.anchor @ odometry.pose, frame_id=frame)

    def _bridged(self, odometry: OdometryEstimate) -> OdometryEstimate:
        """Odometry in the route's frame across a restarted odometry node (a new frame from its first scan, on the same
        clock): a pose far from where the last one, carried forward by the commands sent since, puts the car is placed
        there, and every later one with it."""
        if self.bridge is not None:
            odometry = replace(odometry, pose=self.bridge @ odometry.pose)
        if self.odometry is None or odometry.stamp_ns <= self.odometry.stamp_ns:
            return odometry
        vehicle = self.config.vehicle
        expected = carried_forward(state_of(self.odometry), list(self.sent), odometry.stamp_ns, vehicle.max_accel,
                                   vehicle.max_decel)
        bridge = frame_bridge(expected, odometry.pose, self.config.failsafe.frame_jump_m)
        if bridge is None:
            return odometry
        jump = float(np.hypot(odometry.pose[0, 3] - expected.x, odometry.pose[1, 3] - expected.y))
        self.get_logger().warning(f"odometry jumped {jump:.1f} m from where the car is: a new odometry frame (a restarted "
                                  "odometry node); placed where the commands since its last pose drove the car")
        self.bridge = bridge if self.bridge is None else bridge @ self.bridge
        return replace(odometry, pose=bridge @ odometry.pose)

    def _obstacles_now(self, odometry: OdometryEstimate) -> tuple[Obstacles | None, bool]:
        """The newest obstacles in the route's frame (None when there are none or they cannot be placed), and whether
        they are stale: an old picture of the road still holds the parked cars, so it is kept, at a capped speed."""
        odom_frame, stamp_ns = odometry.frame_id, odometry.stamp_ns
        route_frame = self.planner.route.frame_id if self.planner.route is not None else odom_frame
        if route_frame != odom_frame:
            self.log.update("frames", True, f"route frame '{route_frame}' is not the odometry frame '{odom_frame}': "
                            "obstacles cannot be placed")
            return None, True
        self.log.update("frames", False)
        obstacles = self.obstacles
        if obstacles is not None and self.anchor is not None and obstacles.frame_id == self.anchor_frame:
            obstacles = obstacles.transformed(self.anchor, route_frame)
        # obstacles are placed by the odometry at their stamp, or between the two around it (the odometry node's
        # default gives the pose of the scan after theirs); obstacles newer than the odometry (a node publishing the
        # pose of their own scan answers after them) are placed by it carried forward; from before a restart they lie ahead of the clock (without a clock: more
        # than the compensated latency ahead of the odometry) and are dropped. Planning again while odometry is late,
        # the picture ages with the clock too: older than the latency the planner compensates it is stale (when stamps
        # are on the clock: a bag replayed without /clock is not), and so is one older than the odometry by
        # stale_after_s
        patience, now_ns, clock_agrees = self.patience_s, self.get_clock().now_ns(), self._on_timeline(stamp_ns)
        age = (stamp_ns - obstacles.stamp_ns) * 1e-9 if obstacles is not None else float("inf")
        restarted = obstacles is not None and (obstacles.stamp_ns > now_ns if clock_agrees else -age > patience)
        if obstacles is None or restarted:
            why = "none yet" if obstacles is None else "from before a restart"
            self.log.update("obstacles", True, f"no obstacles ({why}): speed capped at {self.config.stale_speed:g} m/s",
                            over="obstacles fresh again")
            return None, True
        aged = clock_agrees and (now_ns - obstacles.stamp_ns) * 1e-9 > patience
        stale = age > self.config.stale_after_s or aged
        self.log.update("obstacles", stale, f"obstacles are stale ({age:.1f} s older than the odometry"
                        f"{f', {(now_ns - obstacles.stamp_ns) * 1e-9:.1f} s by the clock' if aged else ''}): the last "
                        f"ones kept, speed capped at {self.config.stale_speed:g} m/s", over="obstacles fresh again")
        pose = self.poses.at(obstacles.stamp_ns)
        if pose is None and obstacles.stamp_ns > stamp_ns:
            pose = self._carried_pose(odometry, obstacles.stamp_ns)
        placed = obstacles_in_route_frame(obstacles, route_frame, pose, self.mounts.get(obstacles.frame_id))
        if placed is None:
            self.log.update("obstacles", True, f"obstacles in frame '{obstacles.frame_id}' cannot be placed (no pose "
                            f"at their stamp or no {BASE_FRAME} -> {obstacles.frame_id} transform): speed capped",
                            over="obstacles fresh again")
        return placed, stale or placed is None

    def _carried_pose(self, odometry: OdometryEstimate, stamp_ns: int) -> np.ndarray:
        """The odometry pose (odom <- base_link) carried forward to a later stamp by the commands sent since."""
        vehicle = self.config.vehicle
        before = state_of(odometry)
        after = carried_forward(before, list(self.sent), stamp_ns, vehicle.max_accel, vehicle.max_decel)
        pose = np.array(odometry.pose, dtype=np.float64)
        pose[:3, :3] = yaw_matrix(after.yaw - before.yaw)[:3, :3] @ pose[:3, :3]
        pose[0, 3], pose[1, 3] = after.x, after.y
        return pose

    def watchdog(self, steady: bool = False) -> None:
        """Every control period of the node's clock and every half of one of the steady clock (whatever the node's
        clock does: standing still in lockstep or with a dead simulator, gone back): while an input is stale, the next
        braking command. The steady watchdog judges by the node's clock only while it runs with the steady one (in
        lockstep a brake would release a step and age the inputs itself); else it brakes for silent inputs alone.
        While the clock runs and the inputs are fresh, a control period and a half of steady time with no command
        holds the plan (a scan the chain dropped or answers late; in lockstep the clock waits for the command)."""
        if self.odometry is None:  # nothing commanded yet: the car stands, or its own timeout stops it
            return
        clock_ns, steady_ns = self._clocks()
        running = self.get_clock().running(steady_ns, int(1.5 * self.config.control_period * 1e9))
        stale = self._stale(clock_ns, steady_ns) if not steady or running else self.inputs.silent(steady_ns)
        if stale and self.inputs.brake_due(clock_ns, steady_ns):
            self._publish_step(self._blind_brake(self.odometry, stale), clock_ns)
        elif not stale and steady and running and self._command_overdue(clock_ns, steady_ns):
            self._hold()

    def _command_overdue(self, clock_ns: int, steady_ns: int) -> bool:
        """Whether a control period and a half of steady time went by since the last command (the next scan's answer
        is due within one, give or take the chain's jitter) while the clock went on by as much (in lockstep it goes on
        one step per command), with odometry on the clock's time line (to be carried forward by it)."""
        overdue_ns = 1.5 * self.config.control_period * 1e9
        return (self.sent_steady_ns is not None and steady_ns - self.sent_steady_ns >= overdue_ns
                and clock_ns - self.sent[-1][0] >= overdue_ns and self._on_timeline(self.odometry.stamp_ns))

    def _hold(self) -> None:
        """A command without a new answer: the last plan's control for now where nothing came since it was made (a
        solve would find it again, for a fraction of the CPU the chain needs for the next scan), else a plan from the
        newest inputs."""
        newest = max(self.odometry.stamp_ns, self.obstacles.stamp_ns if self.obstacles is not None else -1)
        held = self.planner.hold(self._now(state_of(self.odometry))) if newest <= self.planned_ns else None
        if held is None:
            self._tick(self.odometry)
        else:
            self._publish_step(held, self.planned_ns)

    def _publish(self, command: Command) -> None:
        self.last_command = command
        self.sent.append((self.get_clock().now_ns(), command))
        self.sent_steady_ns = self.get_steady_clock().now_ns()
        vector = messages.msg_type("geometry_msgs/msg/Vector3")
        self.cmd_pub.publish(messages.msg_type("geometry_msgs/msg/Twist")(
            linear=vector(x=float(command.linear), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=float(command.angular))))

    def _refresh(self) -> None:
        self.stats.set("fallbacks", self.planner.stats.fallbacks)

    def _report(self) -> None:
        stats = self.planner.stats
        if stats.total:
            self.get_logger().info(f"plan: {stats.total} ticks, {stats.fallbacks} fallbacks "
                                   f"({dict(stats.reasons) or 'none'})")


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_planner_node ssf_planner_node."""
    return run(PlannerNode, argv)
