"""ssf_planner_node: /ssf/obstacles + /odom + a route (A -> B in the odometry frame) -> /cmd_vel and /ssf/plan.

One plan per odometry message (the simulator's 10 Hz), with the newest obstacles moved into the odometry frame by
the pose at their stamp; while odometry is late, one plan per control period from the newest pose carried forward.
Stale obstacles cap the speed, stale odometry brakes, each said once."""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from ssf_common import messages, pose_msgs, topics
from ssf_common.conversions import obstacles_from_msg, odometry_from_msg, plan_from_msg, plan_to_msg
from ssf_common.diagnostics import StageStats, advertise
from ssf_common.errors import ConfigError, MessageError, SsfError
from ssf_common.markers import MarkerSet
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, Node, run
from ssf_common.geometry.se3 import invert, yaw_matrix
from ssf_common.records import Obstacles, OdometryEstimate
from ssf_common.stamps import StampSequence
from ssf_planner_node.core.config import PlannerConfig
from ssf_planner_node.core.frames import PoseHistory, carried_forward, obstacles_in_route_frame, state_of
from ssf_planner_node.core.models import Command
from ssf_planner_node.core.planner import PlanStep, RdaPlanner, TickStatus, VehicleState
from ssf_planner_node.core.route import Route

BASE_FRAME = "base_link"
LATE_ODOMETRY_PERIODS = 2  # odometry older than this many control periods is late: the timer plans in between
SAY_AGAIN_S = 10.0  # a problem that keeps coming back is said again at most this often (counted in between)
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
        self.planner = RdaPlanner(self.config)
        if waypoints:
            self.planner.set_route(self._route_from_parameter(waypoints))
        self.poses = PoseHistory()
        self.mounts: dict[str, np.ndarray] = {BASE_FRAME: np.eye(4)}
        self.obstacles: Obstacles | None = None
        self.odometry: OdometryEstimate | None = None  # the newest (in the route's frame)
        self.last_odometry_s: float | None = None  # when it arrived (the node's clock: stamps may run on another)
        self.last_tick_s: float | None = None
        self.last_command = Command(0.0, 0.0)
        self.sent: deque[tuple[int, Command]] = deque(maxlen=200)  # (clock stamp, command) for latency compensation
        self.said: set[str] = set()  # the problems there are now
        self._announced: set[str] = set()  # ... of which the onset was said (the others came back within SAY_AGAIN_S)
        self._said_at: dict[str, float] = {}  # when each problem was last said (monotonic s)
        self.sequence = StampSequence()
        self.cmd_pub = self.create_publisher("geometry_msgs/msg/Twist", topics.CMD_VEL, QOS_DEFAULT)
        self.plan_pub = self.create_publisher("nav_msgs/msg/Path", topics.PLAN, QOS_DEFAULT)
        self.markers = MarkerSet()
        self.marker_pub = self.create_publisher("visualization_msgs/msg/MarkerArray", topics.SSF_MARKERS, QOS_DEFAULT)
        self.state_pub = self.create_publisher("ssf_interfaces/msg/PlannerState", topics.PLANNER_STATE, QOS_DEFAULT)
        self.stats = StageStats(self.get_name())
        advertise(self, self.stats, refresh=self._refresh)
        self.create_timer(self.config.control_period, self.watchdog)
        self.create_timer(report_period, self._report)
        source = "parameter route_waypoints" if self.planner.route is not None else route_topic
        self.get_logger().info(f"{self.config.model.value} MPC, horizon {self.config.horizon} x {self.config.dt:g} s, "
                               f"K = {self.config.obstacles.max_obstacles}, route from {source}")
        if self.planner.route is None:
            self.create_subscription("nav_msgs/msg/Path", route_topic, self.on_route, QOS_LATCHED)
        self.create_subscription("tf2_msgs/msg/TFMessage", topics.TF, self.on_tf, QOS_DEFAULT)
        self.create_subscription("nav_msgs/msg/Odometry", topics.ODOM, self.on_odometry, QOS_DEFAULT)
        self.create_subscription("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, self.on_obstacles, QOS_DEFAULT)

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

    def on_obstacles(self, msg: Any) -> None:
        """Keep the newest obstacles."""
        try:
            self.obstacles = obstacles_from_msg(msg)
        except MessageError as err:
            self.get_logger().warning(f"dropped a message on {topics.OBSTACLES}: {err}")

    def on_odometry(self, msg: Any) -> None:
        """Plan from this pose with the newest obstacles; publish the command and the plan."""
        try:
            odometry = odometry_from_msg(msg)
        except MessageError as err:
            self.get_logger().warning(f"dropped a message on {topics.ODOM}: {err}")
            return
        if self.sequence.restarted(odometry.stamp_ns):
            self.get_logger().info("odometry stamps jumped back: the stream restarted; the commands sent and the anchor "
                                   "are forgotten")
            self.sent.clear()
            self.anchor = None
        if self.anchor_odometry:
            odometry = self._anchored(odometry)
        self.poses.add(odometry.stamp_ns, odometry.pose)
        self.odometry = odometry
        self.last_odometry_s = self.get_clock().now_s()
        self._said_if(False, "odometry")
        self._tick(odometry)

    @property
    def patience_s(self) -> float:
        """How old odometry and obstacles may get (by the clock) before they no longer count: the latency compensated."""
        return max(self.config.max_latency_s, self.config.stale_after_s)

    def _tick(self, odometry: OdometryEstimate) -> None:
        """One plan from the odometry carried forward to now, with the newest obstacles."""
        self.last_tick_s = self.get_clock().now_s()
        state = self._now(state_of(odometry))
        obstacles, stale = self._obstacles_now(odometry)
        late = self._on_timeline(odometry.stamp_ns) and state.stamp_ns - odometry.stamp_ns > self.patience_s * 1e9
        self._said_if(late, "late odometry", f"odometry is {(state.stamp_ns - odometry.stamp_ns) * 1e-9:.1f} s behind "
                      f"the clock: planned from it carried forward, speed capped at {self.config.stale_speed:g} m/s")
        step = self.planner.step(state, obstacles, stale=stale or late)
        self._publish(step.command)
        self.plan_pub.publish(plan_to_msg(step.plan))
        if self.marker_pub.get_subscription_count():  # markers are for people watching: none are built for nobody
            self.marker_pub.publish(self.markers.plan(step.plan))
        self._publish_state(odometry.stamp_ns, step)
        self.stats.record(step.solve_ms, "ticks")
        if step.status in (TickStatus.SHIFTED, TickStatus.BRAKE):
            self.get_logger().debug(f"fallback ({step.status.value}): {step.reason}")

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

    def _obstacles_now(self, odometry: OdometryEstimate) -> tuple[Obstacles | None, bool]:
        """The newest obstacles in the route's frame (None when there are none or they cannot be placed), and whether
        they are stale: an old picture of the road still holds the parked cars, so it is kept, at a capped speed."""
        odom_frame, stamp_ns = odometry.frame_id, odometry.stamp_ns
        route_frame = self.planner.route.frame_id if self.planner.route is not None else odom_frame
        if route_frame != odom_frame:
            self._said_if(True, "frames", f"route frame '{route_frame}' is not the odometry frame '{odom_frame}': "
                          "obstacles cannot be placed")
            return None, True
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
            self._said_if(True, "obstacles", f"no obstacles ({'none yet' if obstacles is None else 'from before a restart'}"
                          f"): speed capped at {self.config.stale_speed:g} m/s")
            return None, True
        aged = clock_agrees and (now_ns - obstacles.stamp_ns) * 1e-9 > patience
        stale = age > self.config.stale_after_s or aged
        self._said_if(stale, "obstacles", f"obstacles are stale ({age:.1f} s older than the odometry"
                      f"{f', {(now_ns - obstacles.stamp_ns) * 1e-9:.1f} s by the clock' if aged else ''}): the last ones "
                      f"kept, speed capped at {self.config.stale_speed:g} m/s")
        pose = self.poses.at(obstacles.stamp_ns)
        if pose is None and obstacles.stamp_ns > stamp_ns:
            pose = self._carried_pose(odometry, obstacles.stamp_ns)
        placed = obstacles_in_route_frame(obstacles, route_frame, pose, self.mounts.get(obstacles.frame_id))
        if placed is None:
            self._said_if(True, "obstacles", f"obstacles in frame '{obstacles.frame_id}' cannot be placed (no pose at "
                          f"their stamp or no {BASE_FRAME} -> {obstacles.frame_id} transform): speed capped")
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

    def watchdog(self) -> None:
        """Every control period: when odometry is late (a loaded perception chain answers less often than the
        control period), plan again from the newest pose carried forward by the commands sent since; once none has
        come for longer than the latency that can be compensated, slow down to a stop (said once)."""
        arrived, ticked = self.last_odometry_s, self.last_tick_s
        if self.odometry is None or arrived is None or ticked is None:  # none yet, or its first tick is under way
            return
        now = self.get_clock().now_s()
        age = now - arrived
        if abs(age) > self.patience_s:  # negative: from before a restart
            self._said_if(True, "odometry", f"odometry is stale ({age:.1f} s old): braking")
            self._publish(braking_on_the_arc(self.last_command, self.config.vehicle.max_decel * self.config.control_period))
        elif age > LATE_ODOMETRY_PERIODS * self.config.control_period and now - ticked >= self.config.control_period:
            self._tick(self.odometry)  # in lockstep the clock waits for the planner: odometry is never late there

    def _publish(self, command: Command) -> None:
        self.last_command = command
        self.sent.append((self.get_clock().now_ns(), command))
        vector = messages.msg_type("geometry_msgs/msg/Vector3")
        self.cmd_pub.publish(messages.msg_type("geometry_msgs/msg/Twist")(
            linear=vector(x=float(command.linear), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=float(command.angular))))

    def _said_if(self, condition: bool, topic: str, text: str = "") -> None:
        """Say a problem once while it lasts, and once per SAY_AGAIN_S when it keeps coming back (a loaded graph's
        latency hovers around the limits); say when it is over only if it was said."""
        if condition and topic not in self.said:
            self.said.add(topic)
            now = time.monotonic()
            if now - self._said_at.get(topic, -SAY_AGAIN_S) >= SAY_AGAIN_S:
                self._said_at[topic] = now
                self._announced.add(topic)
                self.get_logger().warning(text)
            else:
                self.stats.count(f"{topic.replace(' ', '_')}_again")
        elif not condition and topic in self.said:
            self.said.discard(topic)
            if topic in self._announced:
                self._announced.discard(topic)
                self.get_logger().info(f"{topic} fresh again")

    def _refresh(self) -> None:
        self.stats.set("fallbacks", self.planner.stats.fallbacks)

    def _report(self) -> None:
        stats = self.planner.stats
        if stats.total:
            self.get_logger().info(f"plan: {stats.total} ticks, {stats.fallbacks} fallbacks "
                                   f"({dict(stats.reasons) or 'none'})")


def braking_on_the_arc(last: Command, decrement: float) -> Command:
    """The last command slowed by `decrement`, on the same arc: the car keeps its curvature while it brakes (turning
    straight in a bend would leave the lane)."""
    slowed = max(last.linear - decrement, 0.0)
    curvature = last.angular / last.linear if abs(last.linear) > 1e-3 else 0.0
    return Command(slowed, curvature * slowed)


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_planner_node ssf_planner_node."""
    return run(PlannerNode, argv)
