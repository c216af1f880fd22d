"""The planner's fail safe in its core: inputs stale on the node's clock or silent on the steady clock, braking that
only slows down and stops within v * 0.3 s + v^2 / (2 deceleration), plausible pictures, bounded work."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.records import ObstacleKind, Obstacles
from ssf_planner_node.core.avoidance import nearest_first
from ssf_planner_node.core.config import FailSafeConfig, PlannerConfig
from ssf_planner_node.core.failsafe import InputWatch, Source, brake_command, implausible_emptiness
from ssf_planner_node.core.models import Command
from ssf_planner_node.core.planner import RdaPlanner, TickStatus, VehicleState
from ssf_planner_node.core.route import Route

MS = 1_000_000
PERIOD = 0.1


def watch(**overrides) -> InputWatch:
    return InputWatch(FailSafeConfig(**overrides), PERIOD)


def test_an_input_goes_stale_two_sensor_periods_after_its_last_fresh_message():
    inputs = watch()
    assert [s.reason for s in inputs.stale(0, 0)] == ["stale_odometry", "stale_obstacles"]  # none yet
    assert inputs.take(Source.ODOMETRY, 5_000 * MS, clock_ns=5_000 * MS, steady_ns=0)
    assert inputs.take(Source.OBSTACLES, 4_900 * MS, clock_ns=5_000 * MS, steady_ns=0)
    assert inputs.stale(5_200 * MS, 200 * MS) == []  # exactly two periods old: still fresh
    [late] = inputs.stale(5_300 * MS, 300 * MS, sources=(Source.ODOMETRY,))
    assert late.reason == "stale_odometry" and "0.30 s old" in late.detail
    # a repeat of the same picture (a frozen stage) or a late one is no fresh input
    assert not inputs.take(Source.OBSTACLES, 4_900 * MS, clock_ns=5_300 * MS, steady_ns=300 * MS)
    assert not inputs.take(Source.OBSTACLES, 4_800 * MS, clock_ns=5_300 * MS, steady_ns=300 * MS)
    assert [s.reason for s in inputs.stale(5_300 * MS, 300 * MS)] == ["stale_odometry", "stale_obstacles"]


def test_an_input_silent_on_the_steady_clock_is_stale_while_the_nodes_clock_stands_still():
    inputs = watch(silent_after_s=2.0)
    inputs.take(Source.ODOMETRY, 5_000 * MS, clock_ns=5_000 * MS, steady_ns=1_000 * MS)
    assert inputs.stale(5_000 * MS, 2_900 * MS, sources=(Source.ODOMETRY,)) == []  # lockstep: the graph is thinking
    [silent] = inputs.stale(5_000 * MS, 3_100 * MS, sources=(Source.ODOMETRY,))  # ... or dead: 2.1 s of steady time
    assert "2.1 s of steady time" in silent.detail


def test_a_clock_gone_back_makes_the_last_drives_inputs_stale_and_a_restarted_stream_is_fresh():
    inputs = watch()
    inputs.take(Source.ODOMETRY, 30_000 * MS, clock_ns=30_000 * MS, steady_ns=0)
    [old] = inputs.stale(100 * MS, 100 * MS, sources=(Source.ODOMETRY,))  # the simulator's next episode: clock at 0.1 s
    assert "before the clock went back" in old.detail
    assert inputs.take(Source.ODOMETRY, 100 * MS, clock_ns=100 * MS, steady_ns=100 * MS)  # stamps back by 29.9 s
    assert inputs.stale(200 * MS, 200 * MS, sources=(Source.ODOMETRY,)) == []


def test_one_braking_command_per_control_period_paced_by_the_steady_clock_too():
    inputs = watch()
    assert inputs.brake_due(5_000 * MS, 0)
    assert not inputs.brake_due(5_050 * MS, 50 * MS)  # half a period on either clock
    assert inputs.brake_due(5_100 * MS, 100 * MS)
    # lockstep: the brake released a simulator step at once; the next one waits for most of a period of steady time
    assert not inputs.brake_due(5_200 * MS, 110 * MS)
    assert inputs.brake_due(5_200 * MS, 190 * MS)
    assert inputs.brake_due(5_200 * MS, 280 * MS)  # the node's clock stands still: the steady clock paces alone
    assert inputs.brake_due(200 * MS, 370 * MS)  # the clock went back: a new sequence
    inputs.released()
    assert inputs.brake_due(210 * MS, 380 * MS)


def test_the_steady_watchdog_brakes_only_for_inputs_silent_on_the_steady_clock():
    inputs = watch(silent_after_s=2.0)
    assert inputs.silent(10_000 * MS) == []  # nothing heard yet: nothing fell silent
    inputs.take(Source.ODOMETRY, 5_000 * MS, clock_ns=5_000 * MS, steady_ns=1_000 * MS)
    inputs.take(Source.OBSTACLES, 5_000 * MS, clock_ns=5_000 * MS, steady_ns=2_500 * MS)
    assert [s.reason for s in inputs.silent(3_100 * MS)] == ["stale_odometry"]


def test_braking_starts_from_the_lower_of_commanded_and_measured_speed_on_the_same_arc():
    slowed = brake_command(Command(8.0, 0.4), measured_speed=9.4, decrement=0.6)  # odometry says faster: the command
    assert slowed.linear == pytest.approx(7.4) and slowed.angular / slowed.linear == pytest.approx(0.05)
    assert brake_command(Command(9.4, 0.0), measured_speed=8.0, decrement=0.6).linear == pytest.approx(7.4)
    assert brake_command(Command(0.3, 0.1), 0.3, 0.6) == Command(0.0, 0.0)
    assert brake_command(None, 5.0, 0.6) == Command(pytest.approx(4.4), 0.0)  # a planner started mid-drive


def boxes(centres, sizes, stamp_ns: int = 0) -> Obstacles:
    centres, sizes = np.asarray(centres, float).reshape(-1, 2), np.asarray(sizes, float).reshape(-1, 2)
    count = len(centres)
    return Obstacles(stamp_ns, "odom", ids=np.arange(1, count + 1), kinds=np.full(count, ObstacleKind.VEHICLE),
                     centres=np.c_[centres, np.ones(count)], sizes=np.c_[sizes, np.full(count, 1.5)],
                     yaws=np.zeros(count), velocities=np.zeros((count, 3)))


def test_blind_braking_slows_every_tick_to_a_stop_within_the_contracts_distance():
    """Cruising at 10 m/s, the inputs stop: two periods later (0.2 s) they are stale and each tick brakes; the car
    (following /cmd_vel within its limits) stops within v * 0.3 s + v^2 / (2 * max_decel) of the last fresh input."""
    config = build(PlannerConfig, {"solver": {"deadline_ms": 0.0}})
    planner = RdaPlanner(config, Route(np.array([[0.0, 0.0], [500.0, 0.0]])))
    inputs = InputWatch(config.failsafe, config.control_period)
    x, speed, t = 0.0, 10.0, 0.0
    decel = config.vehicle.max_decel
    commands, statuses, last_fresh = [], [], None
    for tick in range(60):
        t = tick * PERIOD
        stamp = int(round(t * 1e9))
        if t < 2.0:  # perception answers until 2 s
            inputs.take(Source.ODOMETRY, stamp, stamp, stamp)
            inputs.take(Source.OBSTACLES, stamp, stamp, stamp)
            last_fresh = (t, x)
        state = VehicleState(stamp, x, 0.0, 0.0, speed)
        stale = inputs.stale(stamp, stamp)
        step = planner.blind_brake(state, stale[0].reason) if stale else planner.step(state, boxes([[200, 30]], [[4, 2]]))
        commands.append(step.command.linear)
        statuses.append((step.status, step.reason))
        speed += float(np.clip(step.command.linear - speed, -decel * PERIOD, config.vehicle.max_accel * PERIOD))
        x += speed * PERIOD
    onset = next(i for i, (status, _) in enumerate(statuses) if status is TickStatus.BRAKE) * PERIOD
    assert onset - last_fresh[0] == pytest.approx(0.3)  # the first tick older than 0.2 s
    braking = commands[round(onset / PERIOD):]
    assert all(later < earlier for earlier, later in zip(braking, braking[1:]) if earlier > 0)  # each slower
    assert braking[-1] == 0.0 and speed == 0.0
    v = 10.0
    assert x - last_fresh[1] <= v * 0.3 + v * v / (2 * decel) + 1e-9
    assert {reason for status, reason in statuses if status is TickStatus.BRAKE} == {"stale_odometry"}
    assert planner.stats.fallbacks == len(braking) and planner.stats.reasons["stale_odometry"] == len(braking)


def test_an_empty_picture_right_after_a_near_obstacle_is_not_believed():
    near, far, empty = boxes([[12.0, 3.0]], [[4, 2]]), boxes([[35.0, 0.0]], [[4, 2]]), Obstacles.empty(0, "odom")
    assert "cannot all be gone" in implausible_emptiness(near, empty, np.zeros(2), 20.0)
    assert implausible_emptiness(far, empty, np.zeros(2), 20.0) == ""  # the last one was leaving the range
    assert implausible_emptiness(near, empty, np.array([-30.0, 0.0]), 20.0) == ""  # far from where the car is
    assert implausible_emptiness(None, empty, np.zeros(2), 20.0) == ""
    assert implausible_emptiness(near, far, np.zeros(2), 20.0) == ""  # not empty
    assert implausible_emptiness(near, empty, np.zeros(2), 0.0) == ""  # switched off


def test_the_nearest_obstacles_are_chosen_in_linear_time_and_the_rest_counted():
    rng = np.random.default_rng(0)
    centres = rng.uniform(-200, 200, (10_000, 2))
    flood = boxes(centres, np.full((10_000, 2), 0.5))
    kept, dropped = nearest_first(flood, np.zeros(2), 200)
    assert len(kept) == 200 and dropped == 9_800
    reach = np.linalg.norm(centres, axis=1) - 0.5 * np.hypot(0.5, 0.5)
    assert set(kept.ids) == set(flood.ids[np.argsort(reach)[:200]])
    bus = boxes([[30.0, 0.0]], [[40.0, 2.5]])  # a long bus 30 m away reaches within 10 m
    assert nearest_first(bus.joined(boxes([[15.0, 0.0]], [[0.5, 0.5]])), np.zeros(2), 1)[0].ids.tolist() == [1]
    assert nearest_first(flood, np.zeros(2), 20_000) == (flood, 0)


def test_a_flood_of_obstacles_is_cut_to_the_nearest_and_the_car_still_stops_for_the_wall():
    """10 000 boxes scattered up to 2 km away, a wall across the road 30 m ahead: the tick considers
    obstacles.max_considered of them, says how many it dropped, and stops before the wall."""
    rng = np.random.default_rng(1)
    angles, radii = rng.uniform(0, 2 * np.pi, 10_000), rng.uniform(60, 2000, 10_000)
    clutter = boxes(np.c_[radii * np.cos(angles), radii * np.sin(angles)], np.full((10_000, 2), 0.5))
    world = boxes([[30.0, 0.0]], [[2.0, 30.0]]).joined(clutter)
    planner = RdaPlanner(build(PlannerConfig, {"solver": {"deadline_ms": 0.0}}), Route(np.array([[0.0, 0.0], [200.0, 0.0]])))
    x, speed = 0.0, 8.0
    for tick in range(80):
        step = planner.step(VehicleState(int(tick * PERIOD * 1e9), x, 0.0, 0.0, speed), world)
        assert step.dropped == 10_001 - planner.config.obstacles.max_considered
        speed += float(np.clip(step.command.linear - speed, -6.0 * PERIOD, 3.0 * PERIOD))
        x += speed * PERIOD
    assert speed < 0.2 and x < 30.0 - 1.0 - 2.35


def test_the_plan_bench_drives_a_flood_through_the_planners_own_selection():
    from ssf_planner_node.core.bench import run_bench_planner

    config = build(PlannerConfig, {})
    flood, few = run_bench_planner(config, 10_000, ticks=3), run_bench_planner(config, 20, ticks=3)
    assert (flood.obstacles, flood.max_obstacles, flood.max_considered, flood.ticks) == (10_000, 10, 200, 3)
    assert few.max_obstacles == 20  # up to 50 obstacles every one is in the problem, as before


def test_a_restarted_odometry_frame_is_placed_where_the_car_is_expected():
    from ssf_common.geometry.se3 import make_pose, yaw_of
    from ssf_planner_node.core.frames import frame_bridge

    expected = VehicleState(0, 120.0, -30.0, 0.8, 0.0)  # the last pose carried forward by the commands since
    assert frame_bridge(expected, make_pose(121.0, -30.5, 0.0, 0.82), 3.0) is None  # odometry as it should be
    restarted = make_pose(0.0, 0.0, 0.3, 0.0)  # a new odometry node: its frame starts where the car stands
    bridge = frame_bridge(expected, restarted, 3.0)
    placed = bridge @ restarted
    assert placed[:2, 3] == pytest.approx([120.0, -30.0]) and yaw_of(placed) == pytest.approx(0.8)
    later = bridge @ make_pose(5.0, 0.0, 0.3, 0.0)  # 5 m on in the new frame: 5 m on along the car's heading
    assert later[:2, 3] == pytest.approx([120.0 + 5 * np.cos(0.8), -30.0 + 5 * np.sin(0.8)])
    assert frame_bridge(expected, restarted, 0.0) is None  # switched off


def test_while_the_clock_runs_with_the_steady_one_an_input_is_stale_by_the_steady_clock_too():
    """A simulated clock in real time ticks once per scan: odometry that came 0.09 s after the 5.0 s tick reads 0.2 s
    old at the 5.2 s tick though it is 0.11 s old, and at the 5.3 s tick 0.3 s though it is 0.21 s: braking on the
    ticks alone would come up to a tick late. In lockstep (the clock not running) the steady clock does not count."""
    inputs = watch()
    inputs.take(Source.ODOMETRY, 5_000 * MS, clock_ns=5_000 * MS, steady_ns=1_090 * MS)
    assert inputs.stale(5_200 * MS, 1_290 * MS, running=True, sources=(Source.ODOMETRY,)) == []  # 0.20 s: fresh
    [stale] = inputs.stale(5_200 * MS, 1_300 * MS, running=True, sources=(Source.ODOMETRY,))  # 0.21 s
    assert "0.21 s old" in stale.detail
    assert inputs.stale(5_200 * MS, 1_300 * MS, running=False, sources=(Source.ODOMETRY,)) == []
