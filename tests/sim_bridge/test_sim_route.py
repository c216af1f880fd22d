"""sim_bridge publishes its route, latched, in the odometry frame (the ego's start pose): what a planner follows."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.node import SimBridgeNode
from ssf_common.conversions import plan_from_msg
from ssf_common.middleware import QOS_LATCHED, Node
from support import wait_until

SMALL = "['route.waypoints=[[0,0],[80,0],[80,60]]', 'route.corner_radius=20', 'ground.margin=30', 'lidar.columns=128', 'agents.count=0']"


def test_route_is_latched_in_the_start_frame():
    sim = SimBridgeNode(argv=["--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={SMALL}", "-p", "driver:=none",
                              "-p", "markers:=false", "-p", "exit_when_done:=false", "-p", "wait_for_subscribers:=5",
                              "-p", "wait_timeout_s:=60.0"])
    sim.spin_in_thread()
    late = Node("late_reader")  # joins after the route was published: latched, it still gets it
    routes: list = []
    late.create_subscription("nav_msgs/msg/Path", "/sim/route", routes.append, QOS_LATCHED)
    late.spin_in_thread()
    try:
        assert wait_until(lambda: len(routes) == 1)
        route = plan_from_msg(routes[0])
        xy = route.states[:, :2]
        assert route.frame_id == "odom" and np.allclose(xy[0], 0.0, atol=1e-6)  # starts at the ego
        assert np.allclose(xy[:10, 1], 0.0, atol=0.02) and (np.diff(xy[:10, 0]) > 0).all()  # straight ahead first (the start pose is tilted by the slope)
        length = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
        # the centreline's length, plus what the lane to the right of it adds around the left turn
        assert length == pytest.approx(sim.sim.world.route_length - sim.sim.lane_offset * np.pi / 2, abs=0.2)
        # the goal, seen from the start pose (in the lane, right of the centreline): 80 m ahead, then 60 m to the left
        offset = -sim.sim.lane_offset
        assert xy[-1] == pytest.approx([80.0 + offset, 60.0 + offset], abs=0.05)
    finally:
        for node in (sim, late):
            node.request_shutdown()
            node.destroy_node()
