"""ssf_planner_node in a running graph: the same commands as the in-process loop for replayed obstacles and
odometry, stale inputs slow the car down (said once), and the simulator's latched route is followed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ssf_common.conversions import obstacles_to_msg, odometry_to_msg, plan_to_msg
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, Node
from ssf_common.records import Obstacles, OdometryEstimate, Plan
from ssf_eval.nav.loop import ClosedLoop, TrialSpec
from ssf_planner_node.node import PlannerNode
from support import wait_until


def odometry(tick) -> OdometryEstimate:
    """The odometry message a tick's state stands for (pose and forward speed)."""
    return OdometryEstimate(tick.state.stamp_ns, tick.pose, np.eye(6) * 1e-4,
                            twist=np.array([tick.state.speed, 0, 0, 0, 0, 0.0]))


def route_message(route) -> object:
    waypoints = route.waypoints
    heading = np.r_[np.arctan2(np.diff(waypoints[:, 1]), np.diff(waypoints[:, 0])), 0.0]
    return plan_to_msg(Plan(0, route.frame_id, np.zeros(len(waypoints)), np.c_[waypoints, heading, np.zeros(len(waypoints))]))


states: list = []  # /ssf/planner_state messages of the running test


def stamps(messages: list) -> list[int]:
    """Header stamps (ns) of messages."""
    return [message.header.stamp.sec * 10**9 + message.header.stamp.nanosec for message in list(messages)]


@pytest.fixture
def graph():
    started: list = []
    states.clear()

    def start(*parameters: str):
        node = PlannerNode(argv=["--ros-args", "-p", "report_period_s:=60.0", *sum((["-p", p] for p in parameters), [])])
        node.spin_in_thread()
        probe = Node("probe")
        commands: list = []
        probe.create_subscription("geometry_msgs/msg/Twist", "/cmd_vel", commands.append)
        probe.create_subscription("ssf_interfaces/msg/PlannerState", "/ssf/planner_state", states.append)
        probe.create_subscription("nav_msgs/msg/Path", "/ssf/plan", lambda _msg: None)
        probe.spin_in_thread()
        publishers = {name: probe.create_publisher(kind, topic, qos) for name, kind, topic, qos in (
            ("odom", "nav_msgs/msg/Odometry", "/odom", QOS_DEFAULT),
            ("obstacles", "ssf_interfaces/msg/ObstacleArray", "/ssf/obstacles", QOS_DEFAULT),
            ("route", "nav_msgs/msg/Path", "/sim/route", QOS_LATCHED))}
        started.extend([node, probe])
        assert wait_until(lambda: all(publishers[name].get_subscription_count() > 0 for name in ("odom", "obstacles")))
        return node, publishers, commands

    yield start
    for node in started:
        node.request_shutdown()
        node.on_shutdown()
        node.destroy_node()


def test_node_gives_the_in_process_loop_commands_for_replayed_obstacles_and_odometry(graph):
    loop = ClosedLoop(TrialSpec("gt", 100, 10, 120.0))
    ticks = [loop.tick() for _ in range(6)]
    assert any(len(tick.obstacles) for tick in ticks) and ticks[-1].command.linear > 0.5
    corridor = loop.planner.config
    node, publishers, commands = graph("solver.deadline_ms:=0.0", f"corridor_left:={corridor.corridor_left}",
                                       f"corridor_right:={corridor.corridor_right}",
                                       f"passing.offset:={corridor.passing.offset}")
    publishers["route"].publish(route_message(loop.planner.route))
    assert wait_until(lambda: node.planner.route is not None)
    assert node.planner.route.length == pytest.approx(loop.planner.route.length)
    for index, tick in enumerate(ticks):
        publishers["obstacles"].publish(obstacles_to_msg(tick.obstacles))
        assert wait_until(lambda: node.obstacles is not None and node.obstacles.stamp_ns == tick.state.stamp_ns)
        publishers["odom"].publish(odometry_to_msg(odometry(tick)))
        # each tick publishes its command and its /ssf/planner_state (stamped with its odometry); on a loaded machine
        # the watchdog may also have planned again from the late previous odometry: the answer is the first with this
        assert wait_until(lambda: tick.state.stamp_ns in stamps(states)), f"no answer to the odometry of tick {index}"
        answer = stamps(states).index(tick.state.stamp_ns)
        assert wait_until(lambda: len(commands) > answer), f"no /cmd_vel for tick {index}"
        command = commands[answer]
        replanned = answer > index  # a replan in between warm-starts this tick from another plan: close, not equal
        assert command.linear.x == pytest.approx(tick.command.linear, abs=2e-3 if replanned else 1e-4)
        assert command.angular.z == pytest.approx(tick.command.angular, abs=2e-3 if replanned else 1e-4)
    assert node.planner.stats.total == len(commands) and node.planner.stats.fallbacks == 0
    assert wait_until(lambda: len(states) == len(commands))  # one /ssf/planner_state per tick, for the viewer's plots
    assert all(state.status == "solved" and state.solve_ms > 0 and state.rounds >= 1 for state in states), [(s.status, s.solve_ms, s.rounds) for s in states]
    assert sorted(set(stamps(states))) == [tick.state.stamp_ns for tick in ticks]  # replans keep their odometry's stamp
    assert states[-1].fallbacks == 0 and all(state.clearance == -1.0 or state.clearance > 0 for state in states)


def test_stale_obstacles_cap_the_speed_and_stale_odometry_brakes_each_said_once(graph, capfd):
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]", "stale_after_s:=0.3")
    for index in range(3):  # odometry, but never an obstacle: stale
        estimate = OdometryEstimate(index * 100_000_000, np.eye(4), np.eye(6), twist=np.array([1.5, 0, 0, 0, 0, 0.0]))
        publishers["odom"].publish(odometry_to_msg(estimate))
        assert wait_until(lambda: len(commands) >= index + 1)
    assert all(command.linear.x <= node.config.stale_speed + 1e-6 for command in commands)
    count = len(commands)
    assert wait_until(lambda: "odometry" in node.said, timeout_s=5.0)  # none for max_latency_s: the watchdog brakes
    braking = len(commands)
    assert braking > count  # until then, late odometry: the timer planned again every control period
    assert wait_until(lambda: len(commands) >= braking + 3, timeout_s=5.0)
    assert commands[-1].linear.x < commands[braking - 1].linear.x and commands[-1].angular.z == 0.0
    time.sleep(0.3)
    log = capfd.readouterr().err
    assert log.count("no obstacles (none yet)") == 1 and log.count("odometry is stale") == 1


def test_a_bad_route_parameter_is_a_config_error():
    from ssf_common.errors import ConfigError

    with pytest.raises(ConfigError, match="route_waypoints"):
        PlannerNode(argv=["--ros-args", "-p", "route_waypoints:=[1.0, 2.0, 3.0]"])


def test_world_frame_odometry_is_anchored_at_its_first_pose(graph):
    from ssf_common.geometry.se3 import make_pose

    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]", "anchor_first_odometry:=true")
    start = make_pose(250.0, -40.0, 3.0, yaw=2.0)  # where the ego stands in the world
    for index in range(3):
        ahead = start @ make_pose(0.5 * index)
        estimate = OdometryEstimate(index * 100_000_000, ahead, np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]),
                                    frame_id="world")
        publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(index * 100_000_000, "world")))
        assert wait_until(lambda: node.obstacles is not None and node.obstacles.stamp_ns == index * 100_000_000)
        publishers["odom"].publish(odometry_to_msg(estimate))
        assert wait_until(lambda: len(commands) == index + 1)
    state = node.poses.at(200_000_000)
    assert state[:3, 3] == pytest.approx([1.0, 0.0, 0.0], abs=1e-9)  # 1 m along the route from its origin
    assert all(command.linear.x > 5.0 and abs(command.angular.z) < 0.05 for command in commands)  # on its way
    assert "obstacles" not in node.said and "frames" not in node.said


def test_a_restarted_stream_anchors_again_and_forgets_the_commands_sent(graph):
    """Stamps jumping back (the simulator's next drive) start over: the new first pose is the origin, and commands sent
    in the last drive no longer carry the pose forward."""
    from ssf_common.geometry.se3 import make_pose

    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]", "anchor_first_odometry:=true")

    def drive(stamps, start):
        for count, stamp in enumerate(stamps, start=len(commands) + 1):
            publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(stamp, "world")))
            assert wait_until(lambda: node.obstacles is not None and node.obstacles.stamp_ns == stamp)
            estimate = OdometryEstimate(stamp, start @ make_pose(5e-9 * (stamp % 10**9)), np.eye(6),
                                        twist=np.array([5.0, 0, 0, 0, 0, 0.0]), frame_id="world")
            publishers["odom"].publish(odometry_to_msg(estimate))
            assert wait_until(lambda: len(commands) == count)

    drive([3_000_000_000, 3_100_000_000], make_pose(250.0, -40.0, 3.0, yaw=2.0))
    assert len(node.sent) == 2
    drive([0, 100_000_000], make_pose(-80.0, 10.0, 0.0, yaw=-1.0))
    assert node.sequence.restarts == 1
    assert node.poses.at(0)[:3, 3] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert node.poses.at(100_000_000)[:3, 3] == pytest.approx([0.5, 0.0, 0.0], abs=1e-9)
    assert len(node.sent) == 2  # the last drive's commands are gone
    assert "obstacles" not in node.said  # the new drive's obstacles were fresh all along


def test_braking_without_odometry_keeps_the_arc():
    from ssf_planner_node.core.models import Command
    from ssf_planner_node.node import braking_on_the_arc

    slowed = braking_on_the_arc(Command(8.0, 0.4), 0.6)
    assert slowed.linear == pytest.approx(7.4) and slowed.angular / slowed.linear == pytest.approx(0.05)
    assert braking_on_the_arc(Command(0.3, 0.1), 0.6) == Command(0.0, 0.0)


def test_obstacles_newer_than_the_odometry_are_placed_by_it_carried_forward(graph):
    """In real time perception answers before odometry, which waits for the next scan's flow: such obstacles are not
    stale, and go where the car is by then (the odometry driven on by the commands sent since)."""
    from collections import deque
    from dataclasses import replace

    from ssf_planner_node.core.models import Command

    node, _publishers, _commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]")
    node.sent = deque([(0, Command(5.0, 0.0))])
    estimate = OdometryEstimate(0, np.eye(4), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]), frame_id="odom")
    node.obstacles = replace(Obstacles.empty(400_000_000, "base_link"), ids=np.array([1]), kinds=np.array([1]),
                             centres=np.array([[10.0, 0.0, 0.0]]), sizes=np.array([[4.0, 2.0, 1.5]]), yaws=np.zeros(1),
                             velocities=np.zeros((1, 3)), velocity_covariances=np.zeros((1, 3, 3)),
                             yaw_rates=np.zeros(1), point_counts=np.array([50]), confidences=np.ones(1))
    placed, stale = node._obstacles_now(estimate)
    assert placed is not None and not stale and "obstacles" not in node.said
    assert placed.centres[0, 0] == pytest.approx(12.0, abs=0.05)  # 10 m ahead of where the car is 0.4 s on at 5 m/s
    node.obstacles = Obstacles.empty(5_000_000_000, "base_link")  # far in the future: from before a restart
    assert node._obstacles_now(estimate) == (None, True) and "obstacles" in node.said


def test_obstacles_older_than_the_compensated_latency_are_stale_when_planning_again(graph):
    """While odometry is late the timer plans again from it; the obstacles age with the clock, and once older than
    the latency the planner compensates (max_latency_s) they are stale: the speed is capped, and they are kept (an old
    picture still holds the parked cars; planning as if the road were empty drove into them)."""
    node, _publishers, _commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]")
    now = node.get_clock().now_ns()
    estimate = OdometryEstimate(now - 900_000_000, np.eye(4), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]),
                                frame_id="odom")
    for stamp in (now - 1_200_000_000, now - 950_000_000, estimate.stamp_ns):  # poses to place obstacles with
        node.poses.add(stamp, np.eye(4))
    node.obstacles = Obstacles.empty(now - 950_000_000, "base_link")
    assert node._obstacles_now(estimate)[1] is False  # 0.95 s old: within the compensated latency
    node.obstacles = Obstacles.empty(now - 1_200_000_000, "base_link")  # 0.3 s before the odometry: fine by it ...
    placed, stale = node._obstacles_now(estimate)  # ... but 1.2 s old by the clock: stale, and still there
    assert stale and placed is not None and "obstacles" in node.said


def test_odometry_later_than_the_compensated_latency_is_still_carried_forward_and_caps_the_speed(graph):
    """A loaded graph's odometry can come 1.2 s after its scan: planning from where the car was then (7 m back at
    6 m/s) drove it into a parked car. It is carried forward by the commands sent since, whatever its age on the
    clock, and past max_latency_s the speed is capped; obstacles newer than it by more than that are not taken for
    ones from before a restart (those lie ahead of the clock)."""
    from collections import deque
    from dataclasses import replace

    from ssf_planner_node.core.frames import state_of
    from ssf_planner_node.core.models import Command

    node, _publishers, _commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]")
    now = node.get_clock().now_ns()
    estimate = OdometryEstimate(now - 1_200_000_000, np.eye(4), np.eye(6), twist=np.array([6.0, 0, 0, 0, 0, 0.0]),
                                frame_id="odom")
    node.sent = deque([(now - 1_300_000_000, Command(6.0, 0.0))])
    assert node._now(state_of(estimate)).x == pytest.approx(7.2, abs=0.1)  # where the car is now, not 7 m back
    node.poses.add(estimate.stamp_ns, np.eye(4))
    node.obstacles = replace(Obstacles.empty(now - 100_000_000, "base_link"), ids=np.array([1]), kinds=np.array([1]),
                             centres=np.array([[10.0, 0.0, 0.0]]), sizes=np.array([[4.0, 2.0, 1.5]]), yaws=np.zeros(1),
                             velocities=np.zeros((1, 3)), velocity_covariances=np.zeros((1, 3, 3)),
                             yaw_rates=np.zeros(1), point_counts=np.array([50]), confidences=np.ones(1))
    placed, stale = node._obstacles_now(estimate)  # 1.1 s newer than the odometry, 0.1 s old: fresh, placed
    assert not stale and placed.centres[0, 0] == pytest.approx(16.6, abs=0.1)
    node.odometry = estimate
    node._tick(estimate)
    assert "late odometry" in node.said and node.last_command.linear < 6.0  # slowing down towards the capped speed


def test_a_problem_that_keeps_coming_back_is_said_once_per_window_and_counted(graph, capfd):
    node, _publishers, _commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]")
    for _ in range(5):  # latency hovering around a limit: stale, fresh, stale, ...
        node._said_if(True, "late odometry", "odometry is late")
        node._said_if(False, "late odometry")
    time.sleep(0.2)
    log = capfd.readouterr().err
    assert log.count("odometry is late") == 1 and log.count("late odometry fresh again") == 1
    assert node.stats.counts["late_odometry_again"] == 4
