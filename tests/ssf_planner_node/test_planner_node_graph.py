"""ssf_planner_node in a running graph: the same commands as the in-process loop for replayed obstacles and
odometry, the simulator's latched route is followed, and the fail safe: stale, bad or implausible inputs, a clock gone
back or standing still brake the car to a stop, each tick on /ssf/planner_state and each new condition said once."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ssf_common import messages
from ssf_common.conversions import ego_motion_to_msg, obstacles_to_msg, odometry_to_msg, plan_to_msg
from ssf_common.middleware import QOS_DEFAULT, QOS_LATCHED, Node
from ssf_common.geometry.se3 import invert, make_pose
from ssf_common.records import EgoMotion, Obstacles, OdometryEstimate, Plan
from ssf_eval.nav.loop import ClosedLoop, TrialSpec
from ssf_planner_node.core.failsafe import Source
from ssf_planner_node.core.models import Command
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
plans: list = []  # /ssf/plan messages of the running test


def stamps(messages: list) -> list[int]:
    """Header stamps (ns) of messages."""
    return [message.header.stamp.sec * 10**9 + message.header.stamp.nanosec for message in list(messages)]


@pytest.fixture
def graph():
    started: list = []
    states.clear()
    plans.clear()

    def start(*parameters: str):
        # the tests below that are not about the fail safe feed the node at the pace of a test, not of a sensor
        patient = ["failsafe.stale_periods:=100.0", "failsafe.silent_after_s:=100.0"]
        if any(parameter.startswith("failsafe.") or parameter.startswith("use_sim_time") for parameter in parameters):
            patient = []
        node = PlannerNode(argv=["--ros-args", "-p", "report_period_s:=60.0",
                                 *sum((["-p", p] for p in [*patient, *parameters]), [])])
        node.spin_in_thread()
        probe = Node("probe")
        commands: list = []
        probe.create_subscription("geometry_msgs/msg/Twist", "/cmd_vel", commands.append)
        probe.create_subscription("ssf_interfaces/msg/PlannerState", "/ssf/planner_state", states.append)
        probe.create_subscription("nav_msgs/msg/Path", "/ssf/plan", plans.append)
        probe.spin_in_thread()
        publishers = {name: probe.create_publisher(kind, topic, qos) for name, kind, topic, qos in (
            ("odom", "nav_msgs/msg/Odometry", "/odom", QOS_DEFAULT),
            ("obstacles", "ssf_interfaces/msg/ObstacleArray", "/ssf/obstacles", QOS_DEFAULT),
            ("ego", "ssf_interfaces/msg/EgoMotion", "/ssf/ego_motion", QOS_DEFAULT),
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
    node, publishers, commands = graph("plan_on:=odometry", "solver.deadline_ms:=0.0",
                                       f"corridor_left:={corridor.corridor_left}",
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


def test_each_scan_is_planned_on_its_first_answer_and_a_period_and_a_half_without_one_holds_the_plan(graph):
    """Planning on scans (the default), a scan's obstacles plan at once from the newest odometry carried forward: the
    odometry of that scan, coming after them, plans nothing new (it is off the critical path), and an odometry whose
    obstacles have not come plans itself. While the clock runs, a control period and a half with no command sends the
    last plan's control for now (a scan the chain dropped: nothing new to plan on), one a period."""
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]", "control_period:=1.0", "horizon:=30")
    now = node.get_clock().now_ns()
    scans = [now - 300_000_000, now - 200_000_000, now - 100_000_000]

    def send_odometry(stamp: int) -> None:
        seconds = (stamp - scans[0]) * 1e-9
        publishers["odom"].publish(odometry_to_msg(OdometryEstimate(
            stamp, make_pose(5.0 * seconds), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]), frame_id="odom")))
        assert wait_until(lambda: node.odometry is not None and node.odometry.stamp_ns == stamp)

    send_odometry(scans[0])  # an odometry first (no obstacles yet): no plan while they are missing
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(scans[0], "odom")))
    assert wait_until(lambda: stamps(states) == scans[:1])  # its obstacles come: the scan is planned on
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(scans[1], "odom")))
    assert wait_until(lambda: stamps(states) == scans[:2])  # the next scan's obstacles plan at once ...
    assert node.odometry.stamp_ns == scans[0]  # ... from the odometry before it
    send_odometry(scans[1])  # its own odometry afterwards: nothing new to answer
    send_odometry(scans[2])  # an odometry ahead of its obstacles plans
    assert wait_until(lambda: stamps(states) == scans)
    assert len(commands) == 3 and node.planner.stats.total == 3
    assert wait_until(lambda: len(stamps(states)) >= 4, timeout_s=5.0)  # 1.5 control periods (1.5 s) pass: held
    assert stamps(states)[3] == scans[2] and states[3].status == "held" and len(commands) >= 4
    assert all(state.status == "solved" for state in states[:3]) and node.planner.stats.total >= 4
    assert node.stats.counts["held"] >= 1  # counted apart from the ticks (which solve)


def test_a_pairs_obstacles_plan_its_second_scan_from_the_flows_ego_motion_before_its_odometry_comes(graph):
    """The obstacles of the pair (t, t+1) come before the odometry of t+1: the planner plans scan t+1 at once, its
    pose the odometry of t moved by the flow's ego motion over the pair (through the lidar's mount)."""
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]")
    assert wait_until(lambda: publishers["ego"].get_subscription_count() > 0)
    node.mounts["lidar"] = make_pose(1.2, 0.0, 1.9)
    now = node.get_clock().now_ns()
    before, first, second = now - 300_000_000, now - 200_000_000, now - 100_000_000
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(before, "lidar")))
    assert wait_until(lambda: node.obstacles is not None)
    publishers["odom"].publish(odometry_to_msg(OdometryEstimate(
        first, make_pose(10.0, 0.0, 0.0), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]), frame_id="odom")))
    assert wait_until(lambda: stamps(states) == [first])
    moved = make_pose(3.0, 0.0, 0.0)  # the lidar 3 m on over the pair (far more than the odometry's speed says)
    publishers["ego"].publish(ego_motion_to_msg(EgoMotion(first, second, "lidar", invert(moved))))
    assert wait_until(lambda: first in node.egos)
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(first, "lidar")))
    assert wait_until(lambda: stamps(states) == [first, second])  # scan t+1 planned ...
    assert node.odometry.stamp_ns == first  # ... before its odometry came
    assert wait_until(lambda: len(plans) == 2)
    assert plans[-1].poses[0].pose.position.x > 12.9  # from 13 m (carried forward from t+1), not 10 m
    assert len(commands) == 2


def test_stale_obstacles_and_then_stale_odometry_brake_every_tick_down_to_zero_each_said_once(graph, capfd):
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 100.0, 0.0]", "failsafe.stale_periods:=2.0")
    node.planner.last_command = Command(6.0, 0.3)  # driving on an arc at 6 m/s when the obstacles stop coming
    for index in range(3):  # odometry, but never an obstacle: every tick brakes
        estimate = OdometryEstimate(index * 100_000_000, np.eye(4), np.eye(6), twist=np.array([6.5, 0, 0, 0, 0, 0.0]))
        publishers["odom"].publish(odometry_to_msg(estimate))
        assert wait_until(lambda: len(commands) >= index + 1)
    # then the odometry stops too: the watchdog brakes every control period until the car stands
    assert wait_until(lambda: len(commands) >= 12 and commands[-1].linear.x == 0.0, timeout_s=10.0)
    speeds = [command.linear.x for command in commands]
    assert speeds[0] == pytest.approx(5.4)  # from the lower of the last command (6.0) and the measured 6.5
    assert all(later < earlier for earlier, later in zip(speeds, speeds[1:]) if earlier > 0.0)
    assert all(command.angular.z == pytest.approx(0.05 * command.linear.x) for command in commands)  # on the arc
    assert wait_until(lambda: len(states) >= len(commands))  # a /ssf/planner_state for every brake, ticks and watchdog
    assert all(state.status == "brake" for state in states)
    assert states[0].reason.startswith("stale_obstacles (no obstacles yet")
    assert any(state.reason.startswith("stale_odometry (odometry") for state in states)
    assert states[-1].fallbacks == node.planner.stats.fallbacks >= 12
    time.sleep(0.3)
    log = capfd.readouterr().err
    assert log.count("braking to a stop: stale_obstacles") == 1 and log.count("braking to a stop: stale_odometry") == 1


def test_a_clock_gone_back_does_not_silence_the_watchdog(graph):
    """issue 42: in a second episode (/clock back to zero) the watchdog stayed silent and the car drove on with its
    last command. The watchdog runs on the steady clock too, and inputs from before the jump are stale at once."""
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]", "use_sim_time:=true")
    clock = node.get_clock()
    clock.set_sim_time(30_000_000_000)  # 30 s into the first episode, cruising
    node.planner.last_command = Command(8.0, 0.0)
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(29_900_000_000, "odom")))
    assert wait_until(lambda: node.obstacles is not None)
    estimate = OdometryEstimate(30_000_000_000, np.eye(4), np.eye(6), twist=np.array([8.0, 0, 0, 0, 0, 0.0]))
    publishers["odom"].publish(odometry_to_msg(estimate))
    assert wait_until(lambda: len(states) == 1) and states[0].status == "solved"
    for step in range(1, 40):  # the next episode starts at zero; its perception has not answered yet
        clock.set_sim_time(step * 100_000_000)
        time.sleep(0.1)
        if len(commands) >= 8:
            break
    assert len(commands) >= 8 and commands[-1].linear.x < commands[1].linear.x - 3.0
    assert wait_until(lambda: len(states) >= 8)
    assert states[1].status == "brake" and "before the clock went back" in states[1].reason
    assert messages.stamp_ns(states[1].header.stamp) < 1_000_000_000  # stamped on the new time line


def test_a_clock_standing_still_brakes_on_the_steady_clock_once_an_input_falls_silent(graph):
    """Lockstep with a dead stage: simulated time waits for an answer that never comes; after failsafe.silent_after_s
    of steady time the watchdog brakes, one command per two control periods, each releasing the simulator's step."""
    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]", "use_sim_time:=true",
                                       "failsafe.silent_after_s:=0.5")
    node.get_clock().set_sim_time(5_000_000_000)
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(5_000_000_000, "odom")))
    assert wait_until(lambda: node.obstacles is not None)
    publishers["odom"].publish(odometry_to_msg(OdometryEstimate(5_000_000_000, np.eye(4), np.eye(6),
                                                                twist=np.array([4.0, 0, 0, 0, 0, 0.0]))))
    assert wait_until(lambda: len(states) >= 4, timeout_s=10.0)
    assert states[0].status == "solved" and all(state.status == "brake" for state in states[1:])
    assert "steady time" in states[1].reason and node.get_clock().now_ns() == 5_000_000_000
    assert commands[3].linear.x < commands[2].linear.x < commands[1].linear.x


def test_bad_and_implausible_obstacle_arrays_are_dropped_in_one_line_and_the_picture_ages(graph, capfd):
    from dataclasses import replace as with_fields

    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]")
    near = with_fields(Obstacles.empty(0, "base_link"), ids=np.array([1]), kinds=np.array([1], np.uint8),
                       centres=np.array([[12.0, 4.0, 0.0]]), sizes=np.array([[4.0, 2.0, 1.5]]), yaws=np.zeros(1),
                       velocities=np.zeros((1, 3)), velocity_covariances=np.zeros((1, 3, 3)), yaw_rates=np.zeros(1),
                       point_counts=np.array([50]), confidences=np.ones(1))
    publishers["obstacles"].publish(obstacles_to_msg(near))
    assert wait_until(lambda: node.obstacles is not None)
    for stamp in (100_000_000, 200_000_000):  # a car 12 m away cannot be gone a scan later
        publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(stamp, "base_link")))
    nan = with_fields(near, stamp_ns=300_000_000, centres=np.array([[np.nan, 4.0, 0.0]]))
    publishers["obstacles"].publish(obstacles_to_msg(nan))
    assert wait_until(lambda: node.stats.counts["obstacles_dropped_bad"] == 3)
    assert node.obstacles.stamp_ns == 0  # the last believed picture stays, and ages
    time.sleep(0.2)
    log = capfd.readouterr().err
    assert log.count("dropped a message on /ssf/obstacles: an empty obstacle array right after one with an obstacle "
                     "12.6 m away") == 1  # said once while it lasts
    good = with_fields(near, stamp_ns=400_000_000)
    publishers["obstacles"].publish(obstacles_to_msg(good))
    assert wait_until(lambda: node.obstacles is not None and node.obstacles.stamp_ns == 400_000_000)
    time.sleep(0.2)
    assert "/ssf/obstacles good again" in capfd.readouterr().err


def test_a_flood_of_obstacles_is_read_in_no_time_cut_to_the_nearest_and_said_once(graph, capfd):
    from ssf_common.conversions import obstacles_to_cdr

    node, publishers, commands = graph("route_waypoints:=[0.0, 0.0, 500.0, 0.0]")
    rng = np.random.default_rng(0)
    count = 10_000
    angles, radii = rng.uniform(0, 2 * np.pi, count), rng.uniform(50.0, 2000.0, count)
    flood = Obstacles(0, "odom", ids=np.arange(count), kinds=np.ones(count, np.uint8),
                      centres=np.c_[radii * np.cos(angles), radii * np.sin(angles), np.zeros(count)],
                      sizes=np.full((count, 3), 0.5), yaws=np.zeros(count), velocities=np.zeros((count, 3)))
    publishers["obstacles"]._transport.publish_raw(obstacles_to_cdr(flood))
    assert wait_until(lambda: node.obstacles is not None and len(node.obstacles) == count)
    publishers["odom"].publish(odometry_to_msg(OdometryEstimate(0, np.eye(4), np.eye(6), twist=np.zeros(6))))
    assert wait_until(lambda: len(states) == 1)
    assert states[0].status == "solved" and commands[0].linear.x > 0.0
    assert node.stats.counts["obstacles_dropped"] == count - node.config.obstacles.max_considered
    time.sleep(0.2)
    assert capfd.readouterr().err.count(f"{count - 200} obstacles dropped: only the 200 nearest are considered") == 1


def test_a_bad_route_parameter_is_a_config_error():
    from ssf_common.errors import ConfigError

    with pytest.raises(ConfigError, match="route_waypoints"):
        PlannerNode(argv=["--ros-args", "-p", "route_waypoints:=[1.0, 2.0, 3.0]"])


def test_world_frame_odometry_is_anchored_at_its_first_pose(graph):

    node, publishers, commands = graph("plan_on:=odometry", "route_waypoints:=[0.0, 0.0, 100.0, 0.0]",
                                       "anchor_first_odometry:=true")
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

    node, publishers, commands = graph("plan_on:=odometry", "route_waypoints:=[0.0, 0.0, 100.0, 0.0]",
                                       "anchor_first_odometry:=true")

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


def test_obstacles_newer_than_the_odometry_are_placed_by_it_carried_forward(graph):
    """In real time perception answers before odometry, which waits for the next scan's flow: such obstacles are not
    stale, and go where the car is by then (the odometry driven on by the commands sent since)."""
    from collections import deque
    from dataclasses import replace


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
    for source in Source:  # both inputs just arrived (the odometry is late by its stamp, not by when it came)
        node.inputs.take(source, estimate.stamp_ns if source is Source.ODOMETRY else now - 100_000_000, *node._clocks())
    node._tick(estimate)
    assert "late odometry" in node.said and node.last_command.linear < 6.0  # slowing down towards the capped speed


def test_a_restarted_odometry_node_keeps_the_routes_frame(graph, capfd):
    """A restarted odometry node starts its frame where the car stands: planning on would follow the route from the
    wrong place. The first pose of the new frame is placed where the commands since the last one drove the car."""

    node, publishers, commands = graph("plan_on:=odometry", "route_waypoints:=[0.0, 0.0, 500.0, 0.0]")
    for index, stamp in enumerate((0, 100_000_000)):
        publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(stamp, "odom")))
        assert wait_until(lambda: node.obstacles is not None and node.obstacles.stamp_ns == stamp)
        estimate = OdometryEstimate(stamp, make_pose(60.0 + 0.5 * index), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]))
        publishers["odom"].publish(odometry_to_msg(estimate))
        assert wait_until(lambda: len(states) == index + 1)
    publishers["obstacles"].publish(obstacles_to_msg(Obstacles.empty(300_000_000, "odom")))
    assert wait_until(lambda: node.obstacles.stamp_ns == 300_000_000)
    restarted = OdometryEstimate(300_000_000, np.eye(4), np.eye(6), twist=np.array([5.0, 0, 0, 0, 0, 0.0]))
    publishers["odom"].publish(odometry_to_msg(restarted))
    assert wait_until(lambda: len(states) == 3)
    assert node.bridge is not None and node.odometry.pose[0, 3] == pytest.approx(61.5, abs=0.3)  # 0.2 s on at ~5 m/s
    time.sleep(0.2)
    assert "odometry jumped 61." in capfd.readouterr().err  # said once
