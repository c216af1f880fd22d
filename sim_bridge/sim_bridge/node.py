"""sim_bridge: the simulator as a node — scans, /clock, the odometer's /vehicle/twist and ground truth out,
/cmd_vel in, the episode scored.

The vehicle stops on its own, as a drive-by-wire should: the newest /cmd_vel older than `cmd_vel_timeout` (simulated
time) gives zero velocity, as ros2_control's diff_drive_controller does. In lockstep a step waits `command_timeout_s`
(wall) for its command; once that wait ran out, the steps go on at the real-time pace, without waiting, until a
command comes again."""

from __future__ import annotations

import collections

import time
from enum import Enum
from typing import Any

from pydantic import Field

from sim_bridge import ros_messages
from sim_bridge.ego import VelocityCommand
from sim_bridge.scenario import Scenario, load_scenario, overrides_from_pairs
from sim_bridge.simulator import Frame, Simulator, episode_summary
from ssf_common.diagnostics import ConditionLog, Level, StageStats, advertise
from ssf_common import topics
from ssf_common.checks import SEED_MAX
from ssf_common.config import Section
from ssf_common.errors import SsfError
from ssf_common.jsonio import dumps_strict, write_json
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, QOS_SENSOR_DATA, Node, run
from ssf_common.paths import check_writable


DISCOVERY_SETTLE_S = 0.5
SCENARIO_SECTIONS = frozenset(name for name, field in Scenario.model_fields.items()
                              if isinstance(field.annotation, type) and issubclass(field.annotation, Section))


class Mode(str, Enum):
    """How simulated time relates to commands and the wall clock."""

    LOCKSTEP = "lockstep"  # each step waits for its /cmd_vel (or the wait's timeout); deterministic
    REALTIME = "realtime"  # steps every dt of wall time with the latest /cmd_vel


class Driver(str, Enum):
    """Who drives the ego vehicle."""

    FOLLOW = "follow"  # the built-in route follower
    NONE = "none"  # /cmd_vel (a planner)


class SimNodeConfig(Section):
    """Parameters of sim_bridge (same names in YAML, --ros-args -p and `ssf sim` flags). Scenario settings are
    parameters too, by their dotted names (-p lidar.model:=vlp16, -p agents.count:=20), over `overrides`."""

    scenario: str = "urban_100"
    overrides: list[str] = Field(default_factory=list, description="scenario settings as NAME=VALUE, e.g. agents.count=20")
    seed: int = Field(-1, ge=-1, le=SEED_MAX, description="-1: the scenario's own seed")
    mode: Mode = Mode.LOCKSTEP
    driver: Driver = Driver.FOLLOW
    command_timeout_s: float = Field(0.5, gt=0, description="lockstep: a step waits this long (wall) for its command; "
                                     "once commands came and stopped, steps then go on at the real-time pace until one "
                                     "comes again")
    cmd_vel_timeout: float = Field(0.5, ge=0, description="the newest /cmd_vel this old (s of simulated time) gives "
                                   "zero velocity, as ros2_control's diff_drive_controller does; 0: the last command "
                                   "holds however old")
    rate: float = Field(10.0, ge=0, description="steps per wall second with the follower in lockstep; 0 = flat out")
    duration_s: float = Field(0.0, ge=0, description="stop after this much sim time; 0 = the scenario's time limit")
    first_episode_s: float = Field(0.0, ge=0, description="the first episode ends after this much sim time (0: as the "
                                   "others): with episodes, a drive whose clock soon starts again")
    summary: str = Field("", description="write the episode summary JSON here when it ends")
    render: str = Field("", description="draw the episode top-down to this PNG when it ends")
    markers: bool = True
    exit_when_done: bool = True
    episodes: int = Field(1, ge=0, description="episodes driven back to back, each with the next seed and its clock "
                          "starting again at zero (the graph sees a restarted stream); 0: until stopped")
    wait_for_subscribers: int = Field(0, ge=0, description="hold the first scan until /lidar/points has this many readers")
    wait_timeout_s: float = Field(20.0, gt=0, description="give up waiting for readers after this long")


class SimBridgeNode(Node):
    """Steps the simulator and translates its frames into messages."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("sim_bridge", argv=argv)
        self.config = self.declare_config(SimNodeConfig)
        for path, what in ((self.config.summary, "episode summary"), (self.config.render, "episode picture")):
            if path:
                check_writable(path, what)  # before the episode, not after it
        overrides = {**overrides_from_pairs(self.config.overrides, "overrides"), **self._scenario_parameters()}
        self.scenario = load_scenario(self.config.scenario, overrides)
        self.episode = 0
        self.outcomes: collections.Counter[str] = collections.Counter()
        self._new_episode(None if self.config.seed < 0 else self.config.seed)
        self.command = VelocityCommand()
        self.command_ns: int | None = None  # when the newest command came (simulated time)
        self.fresh_command = False
        self.commands_missing = False  # lockstep: a wait for a command ran out, and none has come since
        self.published_at = 0.0
        self.step_ms: list[float] = []
        self.stats = StageStats(self.get_name())
        self.finished = False
        self.exit_code = 0
        self.summary: dict[str, Any] | None = None
        self.pub_clock = self.create_publisher("rosgraph_msgs/msg/Clock", topics.CLOCK, QOS_DEFAULT)
        self.pub_points = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.LIDAR_POINTS, QOS_SENSOR_DATA)
        self.pub_truth = self.create_publisher("sensor_msgs/msg/PointCloud2", topics.GT_FLOW, QOS_DEFAULT)
        self.pub_odom = self.create_publisher("nav_msgs/msg/Odometry", topics.GT_ODOM, QOS_DEFAULT)
        self.pub_twist = self.create_publisher("geometry_msgs/msg/TwistStamped", topics.VEHICLE_TWIST, QOS_DEFAULT)
        self.pub_tf = self.create_publisher("tf2_msgs/msg/TFMessage", topics.TF, QOS_DEFAULT)
        self.pub_obstacles = self.create_publisher("ssf_interfaces/msg/ObstacleArray", topics.GT_OBSTACLES, QOS_DEFAULT)
        self.pub_markers = self.create_publisher("visualization_msgs/msg/MarkerArray", topics.MARKERS, QOS_DEFAULT)
        self.pub_episode = self.create_publisher("ssf_interfaces/msg/EpisodeResult", topics.EPISODE, QOS_LATCHED)
        self.pub_route = self.create_publisher("nav_msgs/msg/Path", topics.ROUTE, QOS_LATCHED)
        self.create_subscription("geometry_msgs/msg/Twist", topics.CMD_VEL, self.on_cmd_vel, QOS_DEFAULT)
        self.time_limit = self.config.duration_s or self.scenario.episode.time_limit
        self.started = False
        self.readers_since: float | None = None
        self.created_at = time.monotonic()
        self._publish_route()
        self.create_timer(self._tick_period(), self.tick)
        # in real time /cmd_vel must keep coming; in lockstep each step waits for it (a wait that ran out is said)
        watched = (topics.CMD_VEL,) if self.config.driver is Driver.NONE and self.config.mode is Mode.REALTIME else ()
        diagnostics = advertise(self, self.stats, inputs=watched)
        self.log = ConditionLog(self.get_logger(), diagnostics.repeat_s, diagnostics.lasting_s)
        self.get_logger().info(
            f"scenario '{self.config.scenario}' seed {self.sim.seed}: {self.scenario.agents.count} agents, "
            f"route {self.sim.world.route_length:.0f} m, {self.config.mode.value}, driver {self.config.driver.value}"
        )

    def _new_episode(self, seed: int | None) -> None:
        """A fresh simulator (its clock at zero) and the follower that drives it, if any."""
        self.sim = Simulator(self.scenario, seed)
        self.sim.reset()
        self.follower = self.sim.follower() if self.config.driver is Driver.FOLLOW else None

    def _publish_route(self) -> None:
        first = self.sim.frame
        self.pub_route.publish(ros_messages.route_path(self.sim.route_waypoints(), first.base_pose, first.stamp_ns))

    def _scenario_parameters(self) -> dict[str, Any]:
        """Scenario settings given as parameters by their dotted names (-p lidar.model:=vlp16), over `overrides`."""
        names = [name for name in self.undeclared_overrides() if name.partition(".")[0] in SCENARIO_SECTIONS]
        return {name: self.declare_parameter(name).value for name in names}

    def _tick_period(self) -> float:
        if self.config.mode is Mode.REALTIME:
            return self.sim.dt
        if self.follower is not None and self.config.rate > 0:
            return 1.0 / self.config.rate
        return 0.002  # lockstep: poll for the command or its timeout

    def on_cmd_vel(self, msg: Any) -> None:
        """Take a velocity command; in lockstep it releases the step that waits for it."""
        self.command = VelocityCommand(float(msg.linear.x), float(msg.angular.z))
        self.command_ns = self.sim.frame.stamp_ns
        self.fresh_command = True
        if self.commands_missing:
            self.commands_missing = False
            self.log.update("commands missing", False, over="/cmd_vel came again: each step waits for its command")
            self.stats.report("commands missing", Level.OK, "")
        if self.config.mode is Mode.LOCKSTEP and self.follower is None:
            self.tick()

    def tick(self) -> None:
        """Advance one step when the mode says it is time."""
        if self.finished:
            return
        if not self.started:
            self._start_when_readers_joined()
            return
        if self.config.mode is Mode.LOCKSTEP and self.follower is None and not self._lockstep_due():
            return
        frame = self.sim.frame
        command = self._command_now(frame.stamp_ns)
        if self.follower is not None:
            command = self.follower.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome)
        self.fresh_command = False
        start = time.perf_counter()
        previous = frame
        frame = self.sim.step(command)
        self.step_ms.append((time.perf_counter() - start) * 1e3)
        self.stats.record(self.step_ms[-1], "steps")
        self._publish(frame, previous)
        limit = self.config.first_episode_s if self.episode == 0 and self.config.first_episode_s > 0 else self.time_limit
        if self.sim.done or frame.status.time >= limit - 1e-9:
            self._finish(frame)

    def _lockstep_due(self) -> bool:
        """Lockstep: whether this step may go: its command came, or the wait for it ran out (then, when commands had
        come in this drive, the next steps go on at the real-time pace until one comes again, instead of each waiting
        the whole timeout; before the first command of a drive each step waits, as the graph starts up)."""
        if self.fresh_command:
            return True
        waited = time.monotonic() - self.published_at
        if self.commands_missing:
            return waited >= self.sim.dt
        if waited < self.config.command_timeout_s:
            return False
        self.stats.count("command_timeouts")
        if self.command_ns is not None:  # commands came in this drive and stopped (before the first, each step waits)
            self.commands_missing = True
            said = f"no /cmd_vel for {waited:.1f} s: the simulation goes on at the real-time pace until one comes"
            self.log.update("commands missing", True, said)
            self.stats.report("commands missing", Level.WARN, said)
        return True

    def _command_now(self, stamp_ns: int) -> VelocityCommand:
        """The command the vehicle obeys at this step: none yet in this drive, or the newest once cmd_vel_timeout old,
        is zero velocity; else the newest."""
        if self.command_ns is None:
            return VelocityCommand()
        timeout = self.config.cmd_vel_timeout
        expired = timeout > 0 and (stamp_ns - self.command_ns) * 1e-9 >= timeout - 1e-9
        self.stats.count("cmd_vel_timeouts", int(expired))
        said = f"the newest /cmd_vel is {timeout:g} s old: zero velocity (the vehicle stops on its own)"
        self.log.update("cmd_vel timeout", expired, said, over="/cmd_vel fresh again")
        self.stats.report("cmd_vel timeout", Level.WARN if expired else Level.OK, said)
        return VelocityCommand() if expired else self.command

    def _start_when_readers_joined(self) -> None:
        readers = self.pub_points.get_subscription_count()
        now = time.monotonic()
        waited = now - self.created_at
        if readers < self.config.wait_for_subscribers and waited < self.config.wait_timeout_s:
            self.readers_since = None
            return
        if self.config.wait_for_subscribers and readers >= self.config.wait_for_subscribers:
            # Our writer has seen the readers; give them the moment they need to see our writer,
            # or the first best-effort scans are dropped on their side.
            self.readers_since = self.readers_since or now
            if now - self.readers_since < DISCOVERY_SETTLE_S:
                return
        if readers < self.config.wait_for_subscribers:
            self.get_logger().warning(f"starting with {readers} of {self.config.wait_for_subscribers} scan readers")
        self.started = True
        self._publish(self.sim.frame)

    def _publish(self, frame: Frame, previous: Frame | None = None) -> None:
        stamp = frame.stamp_ns
        self.pub_clock.publish(ros_messages.clock(stamp))
        if frame.measured is not None:  # the sweep's measured motion before the sweep: a car's bus has it by then
            self.pub_twist.publish(ros_messages.vehicle_twist(frame.measured, stamp))
        self.pub_points.publish(ros_messages.scan_cloud(frame.scan, stamp))  # then the scan: the whole graph waits for it
        self.pub_tf.publish(ros_messages.transforms(frame.base_pose, frame.pose, stamp))
        self.pub_odom.publish(ros_messages.odometry(frame.base_pose, frame.ego, stamp))
        # the ground truth and the markers cost a few ms per step: built only when someone listens (a recorder, a view)
        if self.pub_obstacles.get_subscription_count():
            self.pub_obstacles.publish(ros_messages.obstacles(frame.agents, stamp))
        if self.config.markers and self.pub_markers.get_subscription_count():
            self.pub_markers.publish(ros_messages.markers(frame.agents, stamp))
        if previous is not None and self.pub_truth.get_subscription_count() and frame.flow is not None:
            self.pub_truth.publish(ros_messages.truth_cloud(previous.scan, frame.flow, previous.stamp_ns))
        if frame.index % 10 == 0:
            self.pub_episode.publish(self._result(frame))
        self.published_at = time.monotonic()

    def _result(self, frame: Frame) -> Any:
        return ros_messages.episode_result(
            frame.status, self.config.scenario, self.sim.seed, len(frame.agents), frame.stamp_ns
        )

    def _finish(self, frame: Frame) -> None:
        self.episode += 1
        self.outcomes[frame.status.outcome.value] += 1
        self.stats.count(f"episodes_{frame.status.outcome.value}")
        if self.config.episodes == 0 or self.episode < self.config.episodes:
            self.pub_episode.publish(self._result(frame))
            self.get_logger().info(f"episode {self.episode} over ({describe_outcome(frame)}); the next starts with "
                                   f"seed {self.sim.seed + 1}")
            self._new_episode(self.sim.seed + 1)
            self.command_ns = None  # a command of the last drive does not drive this one
            self.step_ms.clear()  # the summary covers the drive it describes
            self._publish_route()
            self._publish(self.sim.frame)
            return
        self.finished = True
        try:
            self.pub_episode.publish(self._result(frame))
            self.summary = episode_summary(self.sim, time.monotonic() - self.created_at, self.step_ms)
            if self.episode > 1:
                self.summary["episodes"] = dict(self.outcomes)
            self.get_logger().info("episode over: " + dumps_strict(self.summary, indent=None))
            self._write_results()
        finally:
            if self.config.exit_when_done:
                self.request_shutdown()

    def _write_results(self) -> None:
        """The summary JSON and the picture, each failure logged once and reflected in the exit code."""
        writers = []
        if self.config.summary:
            writers.append(lambda: write_json(self.config.summary, self.summary))
        if self.config.render:
            from sim_bridge.render import render_episode

            writers.append(lambda: render_episode(self.sim, self.config.render))
        for write in writers:
            try:
                write()
            except SsfError as err:
                self.exit_code = 1
                self.get_logger().error(str(err))
            except Exception as err:  # noqa: BLE001 - the episode is over either way; say what failed
                self.exit_code = 1
                self.get_logger().error(f"writing the episode results failed ({type(err).__name__}: {err})")


def describe_outcome(frame: Frame) -> str:
    """How a drive ended, in words: "collision with vehicle 12 after 21.3 s"."""
    status = frame.status
    what = f" with {status.collided_with}" if status.collided_with else ""
    return f"{status.outcome.name.lower()}{what} after {status.time:.1f} s"


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run sim_bridge sim_bridge."""
    return run(SimBridgeNode, argv)
