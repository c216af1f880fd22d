"""sim_bridge with --driver none: in lockstep each step waits for its /cmd_vel (a wait that ran out does not stall
the next steps), and in both modes the vehicle stops on its own once the newest command is cmd_vel_timeout old."""

from __future__ import annotations

import threading

import pytest

from sim_bridge.node import SimBridgeNode
from ssf_common import messages
from support import wait_until
from ssf_common.middleware import QOS_LATCHED, QOS_SENSOR_DATA, Node

SMALL = "['route.waypoints=[[0,0],[80,0]]', 'ground.margin=30', 'lidar.columns=128', 'agents.count=0']"


@pytest.fixture
def lockstep_graph():
    def start(timeout_s: float, mode: str = "lockstep"):
        sim = SimBridgeNode(argv=[
            "--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={SMALL}", "-p", "driver:=none",
            "-p", f"mode:={mode}", "-p", f"command_timeout_s:={timeout_s}", "-p", "wait_for_subscribers:=1",
            "-p", "markers:=false", "-p", "exit_when_done:=false",
        ])
        sim.spin_in_thread()
        planner = Node("planner")
        scans: list = []
        planner.create_subscription("sensor_msgs/msg/PointCloud2", "/lidar/points", scans.append, QOS_SENSOR_DATA)
        planner.spin_in_thread()
        cmd = planner.create_publisher("geometry_msgs/msg/Twist", "/cmd_vel")
        started.extend([sim, planner])
        assert wait_until(lambda: len(scans) == 1 and cmd.get_subscription_count() > 0)
        return sim, scans, cmd

    started: list = []
    yield start
    for node in started:
        node.request_shutdown()
        node.destroy_node()


def twist(speed: float):
    vector = messages.msg_type("geometry_msgs/msg/Vector3")
    return messages.msg_type("geometry_msgs/msg/Twist")(linear=vector(x=speed, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0))


def ticks_on_the_node(sim: SimBridgeNode, count: int) -> None:
    """Run the node's step check `count` times on its own executor thread, and wait until it has."""
    done = threading.Event()
    for _ in range(count):
        sim.call_soon(sim.tick)
    sim.call_soon(done.set)
    assert done.wait(20)


def test_each_step_waits_for_its_command(lockstep_graph):
    sim, scans, cmd = lockstep_graph(timeout_s=30.0)
    ticks_on_the_node(sim, 50)
    assert len(scans) == 1 and sim.sim.frame.index == 0  # no command, no step
    for step in range(1, 6):
        cmd.publish(twist(2.0))
        assert wait_until(lambda: len(scans) == step + 1), f"step {step} did not follow its command"
        assert sim.sim.frame.index == step
    stamps = [messages.stamp_ns(scan.header.stamp) for scan in scans]
    assert stamps == [i * 100_000_000 for i in range(6)]
    assert sim.sim.frame.ego.speed > 0.5  # the commanded speed, within the acceleration limit


def test_a_wait_that_ran_out_does_not_stall_the_next_steps_and_the_vehicle_stops_on_its_own(lockstep_graph):
    """issue 42: with a stage dead each step waited out the whole timeout, then applied the last command. Now one wait
    runs out, the steps go on at the real-time pace, and once the newest command is cmd_vel_timeout (0.5 s of simulated
    time) old the vehicle gets zero velocity."""
    sim, scans, cmd = lockstep_graph(timeout_s=1.0)
    cmd.publish(twist(8.0))
    assert wait_until(lambda: sim.sim.frame.index == 1)
    commanded_at = sim.command_ns
    assert wait_until(lambda: sim.sim.frame.index >= 12, timeout_s=30.0)  # no command since: one wait, then the pace
    assert sim.stats.counts["command_timeouts"] == 1 and sim.commands_missing
    assert sim.sim.frame.ego.speed == 0.0 and sim.stats.counts["cmd_vel_timeouts"] >= 6
    obeyed = round((commanded_at * 1e-9 + 0.5) / 0.1)  # steps that obeyed the command: zero velocity from then on
    assert wait_until(lambda: sim.stats.counts["cmd_vel_timeouts"] == sim.sim.frame.index - obeyed)  # (it steps on)
    cmd.publish(twist(2.0))  # a command again: lockstep again
    assert wait_until(lambda: not sim.commands_missing and sim.sim.frame.ego.speed > 0.0)
    index = sim.sim.frame.index
    ticks_on_the_node(sim, 50)
    assert sim.sim.frame.index == index  # waiting for its command again


def test_in_real_time_the_vehicle_stops_once_the_newest_command_is_too_old(lockstep_graph):
    sim, scans, cmd = lockstep_graph(timeout_s=1.0, mode="realtime")
    cmd.publish(twist(5.0))
    assert wait_until(lambda: sim.command_ns is not None and sim.sim.frame.ego.speed > 1.0, timeout_s=30.0)
    commanded_at = sim.command_ns
    assert wait_until(lambda: sim.sim.frame.ego.speed == 0.0, timeout_s=30.0)
    assert (sim.sim.frame.stamp_ns - commanded_at) * 1e-9 >= 0.5 and sim.stats.counts["cmd_vel_timeouts"] > 0


def test_episodes_back_to_back_restart_the_clock_with_the_next_seed():
    """-p episodes:=2: the second drive starts from stamp zero with the next seed and its own route, then the node is
    done; -p first_episode_s:=0.2 ends the first one early."""
    sim = SimBridgeNode(argv=[
        "--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={SMALL}", "-p", "driver:=follow", "-p", "rate:=0.0",
        "-p", "seed:=7", "-p", "duration_s:=0.3", "-p", "episodes:=2", "-p", "wait_for_subscribers:=1",
        "-p", "first_episode_s:=0.2",
        "-p", "markers:=false", "-p", "exit_when_done:=false",
    ])
    listener = Node("listener")
    scans, routes = [], []
    listener.create_subscription("sensor_msgs/msg/PointCloud2", "/lidar/points", scans.append, QOS_SENSOR_DATA)
    listener.create_subscription("nav_msgs/msg/Path", "/sim/route", routes.append, QOS_LATCHED)
    try:
        listener.spin_in_thread()
        sim.spin_in_thread()
        assert wait_until(lambda: sim.finished, timeout_s=30.0)
        assert wait_until(lambda: len(scans) == 7)  # 0.2 s, then 0.3 s = 2 and 3 steps after each first scan
    finally:
        sim.request_shutdown()
        sim.destroy_node()
        listener.destroy_node()
    stamps = [messages.stamp_ns(scan.header.stamp) // 100_000_000 for scan in scans]
    assert stamps == [0, 1, 2, 0, 1, 2, 3]
    assert sim.sim.seed == 8 and sim.episode == 2
    assert len(routes) == 2
