"""The RDA-style MPC core: path tracking, stopping, moving obstacles by their predicted position, fallbacks, config."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ssf_common.config import build
from ssf_common.errors import ConfigError
from ssf_common.geometry.boxes import box_corners
from ssf_common.records import ObstacleKind, Obstacles
from ssf_planner_node.core.avoidance import hyperplanes, in_path, separation
from ssf_planner_node.core.config import PassingConfig, PlannerConfig, VehicleConfig
from ssf_planner_node.core.passing import LaneChooser
from ssf_planner_node.core.planner import HARD_MARGIN, RdaPlanner, TickStatus, VehicleState
from ssf_planner_node.core.route import Route

TICK = 0.1


def boxes(centres, sizes, velocities=None, stamp_ns: int = 0) -> Obstacles:
    """Upright boxes (x, y centres; length, width) in the odometry frame."""
    centres, sizes = np.asarray(centres, float).reshape(-1, 2), np.asarray(sizes, float).reshape(-1, 2)
    count = len(centres)
    velocities = np.zeros((count, 2)) if velocities is None else np.asarray(velocities, float).reshape(-1, 2)
    return Obstacles(stamp_ns, "odom", ids=np.arange(1, count + 1), kinds=np.full(count, ObstacleKind.VEHICLE),
                     centres=np.c_[centres, np.ones(count)], sizes=np.c_[sizes, np.full(count, 1.5)],
                     yaws=np.zeros(count), velocities=np.c_[velocities, np.zeros(count)])


def drive(planner: RdaPlanner, start: tuple[float, float, float, float], ticks: int, world=None, seen=None):
    """Closed loop with an exact unicycle that follows /cmd_vel under the vehicle's limits; world(t) gives the true
    obstacles, seen(t) what the planner is told (default: the truth). Returns states (T, 4) and the true clearances."""
    cfg = planner.config.vehicle
    x, y, yaw, speed = start
    states, clearances, steps = [], [], []
    for tick in range(ticks):
        t = tick * TICK
        truth = world(t) if world else None
        step = planner.step(VehicleState(int(round(t * 1e9)), x, y, yaw, speed), (seen or world)(t) if world else None)
        steps.append(step)
        change = np.clip(step.command.linear - speed, -cfg.max_decel * TICK, cfg.max_accel * TICK)
        speed_next, rate = speed + change, np.clip(step.command.angular, -cfg.max_yaw_rate, cfg.max_yaw_rate)
        heading = yaw + rate * TICK / 2
        x, y = x + speed_next * TICK * np.cos(heading), y + speed_next * TICK * np.sin(heading)
        yaw, speed = yaw + rate * TICK, speed_next
        states.append((x, y, yaw, speed))
        if truth is not None and len(truth):
            ego = box_corners(np.array([x, y]), cfg.length, cfg.width, yaw)
            later = world(t + TICK)
            clearances.append(min(separation(ego, corner)[1] for corner in later.corners()))
    return np.array(states), np.array(clearances), steps


def planner_for(waypoints, **overrides) -> RdaPlanner:
    return RdaPlanner(build(PlannerConfig, {"solver": {"deadline_ms": 0.0}}, overrides), Route(np.array(waypoints)))


def test_tracks_a_straight_and_a_curved_path_at_the_reference_speed():
    straight, _, steps = drive(planner_for([[0, 0], [400, 0]]), (0.0, 1.5, 0.2, 0.0), 120)
    assert abs(straight[-1, 1]) < 0.1 and abs(straight[-1, 2]) < 0.02  # back on the line, heading along it
    assert straight[-1, 3] == pytest.approx(10.0, abs=0.3)
    assert all(step.status is TickStatus.SOLVED for step in steps)
    radius = 60.0
    angles = np.linspace(-np.pi / 2, np.pi, 200)
    arc = np.c_[radius * np.cos(angles), radius * (1 + np.sin(angles))]  # a circle of 60 m from (0, 0), heading +x
    curved, _, steps = drive(planner_for(arc), (0.0, 0.0, 0.0, 5.0), 150)
    distance_to_arc = np.abs(np.hypot(curved[:, 0], curved[:, 1] - radius) - radius)
    assert distance_to_arc.max() < 0.5 and distance_to_arc[-50:].mean() < 0.2
    assert curved[-1, 3] > 8.5  # 10 m/s needs 1.7 m/s^2 sideways on this curve, within the limits
    assert all(step.status is TickStatus.SOLVED for step in steps)


def test_a_car_outside_the_corridor_steers_back_instead_of_braking():
    """The corridor is soft: 8 m off the route (a pose jump, a swerve round a parked car) the plan exists and leads back."""
    states, _, steps = drive(planner_for([[0, 0], [400, 0]]), (0.0, 8.0, 0.0, 5.0), 100)
    assert all(step.status is TickStatus.SOLVED for step in steps)
    assert abs(states[-1, 1]) < 0.2 and states[-1, 3] > 9.0


def test_pressed_by_a_long_vehicle_on_the_right_the_car_keeps_off_the_oncoming_lane():
    """issue 11: swerves into the oncoming lane ended nose to nose with oncoming traffic (dead ends at 1000 agents); the
    default corridor keeps the body right of the centre line; a symmetric one lets the car swing over it."""
    bus = boxes([[40.0, -2.0]], [[30.0, 1.9]])  # 0.1 m closer than the comfort distance to the lane's car
    kept, clearance, _ = drive(planner_for([[0, 0], [300, 0]]), (0.0, 0.0, 0.0, 8.0), 100, lambda t: bus)
    assert kept[:, 1].max() < PlannerConfig().corridor_left + 0.05 and kept[-1, 0] > 35.0 and clearance.min() > 0.1
    swung, _, _ = drive(planner_for([[0, 0], [300, 0]], corridor_left=3.5), (0.0, 0.0, 0.0, 8.0), 100, lambda t: bus)
    assert swung[:, 1].max() > PlannerConfig().corridor_left + 0.2


def test_a_turn_never_swings_the_rear_into_someone_standing_beside_it():
    """issue 11: ground truth hit a pedestrian at 1000 agents (world 310): standing 1-10 cm beside the rear, the hard
    bound's slack let the car creep closer tick by tick, and a turn swung the rear into the person between two of the
    plan's steps (0.2 s apart). Each plan is now checked where its first command puts the car at the next tick."""
    person = replace(boxes([[-2.0, 0.925 + 0.35 + 0.012]], [[0.7, 0.7]]), kinds=np.array([ObstacleKind.PEDESTRIAN]))
    states, clearance, _ = drive(planner_for([[0, 0], [2, 0], [12, -10], [40, -38]]), (0.0, 0.0, 0.0, 0.0), 30,
                                 lambda t: person)  # a sharp right turn from rest: the rear swings left
    assert clearance.min() > 0.012 - 1e-3  # never closer than it stood (the old planner: 3.4 cm into the person)
    assert states[-1, 0] > 5.0 and states[-1, 3] > 5.0  # and still drove off round the turn


@pytest.mark.parametrize("yaw, speed", [(2.5, 3.0), (3.0, 0.0)])
def test_turned_round_it_turns_back_instead_of_driving_the_route_backwards(yaw, speed):
    # issue 11: swung round while waiting behind traffic, the car drove the route backwards at the reference speed
    states, _, _ = drive(planner_for([[-300, 0], [300, 0]]), (0.0, 0.0, yaw, speed), 200)
    assert states[:, 0].min() > -5.0  # never more than a few metres the wrong way
    assert states[-1, 0] > 100.0 and abs(np.angle(np.exp(1j * states[-1, 2]))) < 0.05  # on its way along the route
    assert states[-1, 3] == pytest.approx(10.0, abs=0.3)


def test_stops_for_a_static_box_across_the_road():
    wall = boxes([[30.0, 0.0]], [[2.0, 30.0]])
    states, clearance, steps = drive(planner_for([[0, 0], [200, 0]]), (0.0, 0.0, 0.0, 8.0), 80, lambda t: wall)
    assert states[-1, 3] < 0.2  # standing
    assert clearance.min() > 0.1  # never closer than the safety distance
    assert states[:, 0].max() < 30.0 - 1.0 - 2.35  # stopped before the wall (comfort distance kept)
    assert max(step.obstacles for step in steps) == 1


def test_an_old_picture_is_given_a_wider_berth():
    """The same wall, seen 1 s before each tick (a loaded real-time graph): with a latency margin of 1 m per second
    of age the planner stops 1 m farther from it."""
    def stopped_at(age_s: float) -> float:
        wall = lambda t: boxes([[30.0, 0.0]], [[2.0, 30.0]], stamp_ns=int(round((t - age_s) * 1e9)))
        planner = planner_for([[0, 0], [200, 0]], obstacles={"latency_margin": 1.0})
        states, _clearance, _steps = drive(planner, (0.0, 0.0, 0.0, 8.0), 80, wall)
        assert states[-1, 3] < 0.2
        return float(states[-1, 0])

    fresh, old = stopped_at(0.0), stopped_at(1.0)
    assert fresh - old == pytest.approx(1.0, abs=0.35)


def test_passes_a_crossing_agent_by_its_predicted_position():
    def crossing(t: float) -> Obstacles:  # a car crossing the route from the right at 4 m/s
        return boxes([[30.0, -14.0 + 4.0 * t]], [[2.0, 4.5]], [[0.0, 4.0]], int(round(t * 1e9)))

    def standing(t: float) -> Obstacles:  # the same car told without its velocity
        seen = crossing(t)
        return Obstacles(seen.stamp_ns, seen.frame_id, seen.ids, seen.kinds, seen.centres, seen.sizes, seen.yaws,
                         np.zeros((1, 3)))

    start = (0.0, 0.0, 0.0, 10.0)
    states, clearance, _ = drive(planner_for([[0, 0], [300, 0]]), start, 90, crossing)
    assert clearance.min() > 0.1 and states[-1, 0] > 45.0  # got past, clear of the car
    _, blind, _ = drive(planner_for([[0, 0], [300, 0]]), start, 90, crossing, seen=standing)
    assert blind.min() <= 0.0  # ignoring the velocity runs into it


def test_fallbacks_on_an_infeasible_or_late_solve_are_counted():
    planner = planner_for([[0, 0], [200, 0]])
    planner.step(VehicleState(0, 0.0, 0.0, 0.0, 5.0))
    overlapping = boxes([[2.5, 0.0]], [[3.0, 3.0]], stamp_ns=100_000_000)  # already touching the front bumper
    step = planner.step(VehicleState(100_000_000, 0.5, 0.0, 0.0, 5.0), overlapping)
    assert step.status is TickStatus.BRAKE and step.reason.startswith("solver_failed") and "infeasible" in step.reason
    assert step.command.linear == pytest.approx(5.0 - 6.0 * 0.1) and step.command.angular == 0.0
    assert planner.stats.ticks[TickStatus.BRAKE] == 1 and planner.stats.fallbacks == 1
    assert planner.stats.reasons["solver_failed"] == 1

    late = planner_for([[0, 0], [200, 0]])
    first = late.step(VehicleState(0, 0.0, 0.0, 0.0, 5.0))
    assert first.status is TickStatus.SOLVED and first.command.linear > 5.0  # speeding up to 10 m/s
    late.config = late.config.model_copy(update={"solver": late.config.solver.model_copy(update={"deadline_ms": 1e-6})})
    braked = late.step(VehicleState(100_000_000, 0.5, 0.0, 0.0, 4.9))  # a tick past its deadline brakes blind ...
    assert braked.status is TickStatus.BRAKE and braked.reason.startswith("deadline (")
    assert braked.command.linear == pytest.approx(4.9 - 6.0 * 0.1)  # ... from the lower of commanded and measured
    assert late.stats.fallbacks == 1 and late.stats.reasons["deadline"] == 1


def inside(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which points lie inside a counter-clockwise convex polygon."""
    edge = np.roll(polygon, -1, 0) - polygon
    offset = points[:, None, :] - polygon[None]
    return (edge[None, :, 0] * offset[..., 1] - edge[None, :, 1] * offset[..., 0] >= 0).all(axis=1)


def test_separation_is_the_signed_distance_between_rectangles():
    rng = np.random.default_rng(3)
    for _ in range(40):
        a = box_corners(rng.uniform(-3, 3, 2), *rng.uniform(0.5, 5, 2), rng.uniform(-np.pi, np.pi))
        b = box_corners(rng.uniform(-3, 3, 2), *rng.uniform(0.5, 5, 2), rng.uniform(-np.pi, np.pi))
        normal, distance = separation(a, b)
        edges_a = np.concatenate([np.linspace(p, q, 200) for p, q in zip(a, np.roll(a, -1, 0))])
        edges_b = np.concatenate([np.linspace(p, q, 200) for p, q in zip(b, np.roll(b, -1, 0))])
        brute = np.linalg.norm(edges_a[:, None] - edges_b[None], axis=2).min()
        assert np.linalg.norm(normal) == pytest.approx(1.0)
        if distance > 0:  # separated: the true distance (sampled boundaries are 1-2 cm coarse)
            assert distance == pytest.approx(brute, abs=0.03)
        else:  # overlapping: the boundaries touch or cross, or one holds the other
            assert brute < 0.03 or inside(a, edges_b).any() or inside(b, edges_a).any()


@pytest.mark.parametrize("overrides, field", [
    ({"horizon": 1}, "horizon"),
    ({"dt": 0.0}, "dt"),
    ({"obstacles": {"safety_distance": 1.5, "comfort_distance": 1.0}}, "comfort_distance"),
    ({"reference_speed": 20.0}, "reference_speed"),
    ({"model": "tricycle"}, "model"),
    ({"weights": {"lateral": -1.0}}, "weights.lateral"),
    ({"obstacles": {"max_obstacles": 10, "radius": 3}}, "obstacles.radius"),
])
def test_config_validation(overrides, field):
    with pytest.raises(ConfigError, match=field.split(".")[-1]):
        build(PlannerConfig, overrides)


def test_unknown_qp_solver_is_a_config_error():
    with pytest.raises(ConfigError, match="solver.qp"):
        RdaPlanner(build(PlannerConfig, {"solver": {"qp": "ecos"}}))


def test_bicycle_model_tracks_too():
    states, _, steps = drive(planner_for([[0, 0], [300, 0]], model="bicycle"), (0.0, 2.0, 0.0, 6.0), 100)
    assert abs(states[-1, 1]) < 0.15 and states[-1, 3] == pytest.approx(10.0, abs=0.4)
    assert all(step.status is TickStatus.SOLVED for step in steps)


def test_route_projection_and_goal_speed():
    route = Route(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
    point = route.project(np.array([[4.0, 1.0], [12.0, 6.0]]))
    assert point.s == pytest.approx([4.0, 16.0]) and point.heading == pytest.approx([0.0, np.pi / 2])
    assert route.length == 20.0 and route.remaining(np.array([10.0, 9.0])) == pytest.approx(1.0)
    assert route.speed_limit(np.array([0.0, 20.0]), 10.0, 1.5) == pytest.approx([np.sqrt(60.0), 0.0])
    with pytest.raises(ConfigError):
        Route(np.array([[1.0, 1.0], [1.0, 1.0]]))


def test_latency_compensation_carries_the_state_forward_by_the_commands_sent():
    from ssf_planner_node.core.frames import carried_forward
    from ssf_planner_node.core.models import Command
    from ssf_planner_node.core.planner import VehicleState

    second = 1_000_000_000
    start = VehicleState(10 * second, 0.0, 0.0, 0.0, 5.0)
    cruising = carried_forward(start, [(9 * second, Command(5.0, 0.0))], 10 * second + second // 2, 3.0, 6.0)
    assert (cruising.stamp_ns, cruising.x, cruising.y, cruising.speed) == pytest.approx((10.5 * second, 2.5, 0.0, 5.0))
    turning = carried_forward(start, [(9 * second, Command(5.0, 0.2))], 10 * second + second // 2, 3.0, 6.0)
    assert turning.yaw == pytest.approx(0.1) and turning.y > 0.0
    standing = VehicleState(10 * second, 0.0, 0.0, 0.0, 0.0)
    # the old command holds until the new one is sent; speed follows within the acceleration limit
    moving = carried_forward(standing, [(9 * second, Command(0.0, 0.0)), (10 * second + second // 2, Command(10.0, 0.0))],
                             11 * second + second // 2, 3.0, 6.0)
    assert moving.speed == pytest.approx(3.0) and moving.x == pytest.approx(1.5, abs=0.05)
    assert carried_forward(start, [], start.stamp_ns - 1, 3.0, 6.0) == start  # nothing to carry into the past



def test_pose_history_interpolates_across_skipped_scans():
    """Obstacles of a scan whose odometry was never published (the odometry answered the scans around it) are placed
    by the pose between its neighbours'; beyond the history, or across a long silence, there is none."""
    from ssf_common.geometry.se3 import make_pose, yaw_of
    from ssf_planner_node.core.frames import PoseHistory

    poses = PoseHistory()
    poses.add(100_000_000, make_pose(1.0, 0.0, 0.0, yaw=0.0))
    poses.add(400_000_000, make_pose(4.0, 3.0, 0.0, yaw=0.3))
    assert poses.at(130_000_000)[0, 3] == 1.0  # within the tolerance: the pose itself
    between = poses.at(200_000_000)
    assert between[:3, 3] == pytest.approx([2.0, 1.0, 0.0]) and yaw_of(between) == pytest.approx(0.1)
    assert np.allclose(between[:3, :3] @ between[:3, :3].T, np.eye(3))
    assert poses.at(600_000_000) is None and poses.at(0) is None
    poses.add(2_000_000_000, make_pose(20.0, 3.0, 0.0))
    assert poses.at(1_000_000_000) is None  # 1.6 s without odometry: nothing to bridge


def test_the_odometry_of_a_pairs_second_scan_follows_from_the_flows_ego_motion_through_the_mount():
    """The planner plans a scan before its odometry comes: the pose of the first scan moved by the sensor's motion over
    the pair, seen from base_link through the sensor's mount; speed and yaw rate from that step."""
    from ssf_common.geometry.se3 import invert, make_pose
    from ssf_common.records import EgoMotion, OdometryEstimate
    from ssf_planner_node.core.frames import odometry_after

    start = make_pose(30.0, -5.0, 0.0, yaw=0.7)
    driven = make_pose(0.8, 0.02, 0.0, yaw=0.04)  # base_link over 0.1 s: 8 m/s, 0.4 rad/s
    mount = make_pose(1.2, 0.0, 1.9, yaw=0.02)  # base_link <- lidar
    sensor_moved = invert(mount) @ driven @ mount  # the lidar's pose at t+1 in its frame at t
    ego = EgoMotion(1_000_000_000, 1_100_000_000, "lidar", invert(sensor_moved))  # scan-t points -> t+1's frame
    before = OdometryEstimate(1_000_000_000, start, np.eye(6) * 1e-3, twist=np.array([7.0, 0, 0, 0, 0, 0.3]))
    after = odometry_after(before, ego, mount)
    assert after.stamp_ns == 1_100_000_000 and after.frame_id == before.frame_id
    assert np.allclose(after.pose, start @ driven, atol=1e-12)
    assert after.twist[0] == pytest.approx(8.0) and after.twist[5] == pytest.approx(0.4)


def test_a_car_already_closer_than_the_safety_distance_drives_off_without_coming_closer():
    # a car stopped 0.02 m behind the bumper: with a hard bound of 0.1 m from the first step on, every plan would be
    # infeasible (from rest the car gains 0.06 m in the first 0.2 s step), so it would brake there for good
    gap = 0.02
    behind = lambda t: boxes([[-4.69 - gap, 0.0]], [[4.69, 1.85]])  # noqa: E731
    planner = planner_for([[0, 0], [200, 0]])
    states, clearance, steps = drive(planner, (0.0, 0.0, 0.0, 0.0), 40, behind)
    assert steps[0].status is TickStatus.SOLVED and states[-1, 0] > 5.0
    assert clearance.min() >= gap - 1e-6  # it may keep its distance, never lose it


def test_a_box_already_overlapping_the_car_lets_it_drive_out_but_not_deeper():
    # a conservative still box (a parked car seen a little too wide) overlaps the car's side by 0.04 m; the car itself
    # never touched it. A hard bound of at least 0 would ask for more than the car has: every plan infeasible, stuck
    overlap = 0.04
    width = planner_for([[0, 0], [1, 0]]).config.vehicle.width
    beside = lambda t: boxes([[-1.0, 0.5 * width + 0.5 * 1.85 - overlap]], [[4.69, 1.85]])  # noqa: E731
    planner = planner_for([[0, 0], [200, 0]])
    states, clearance, steps = drive(planner, (0.0, 0.0, 0.0, 0.0), 40, beside)
    assert steps[0].status is TickStatus.SOLVED and states[-1, 0] > 5.0
    assert clearance.min() >= -overlap - HARD_MARGIN - 1e-6  # out, never deeper in than the bound allows
    assert planner.stats.fallbacks == 0


def test_the_distance_bound_is_exact_to_first_order_in_position_and_heading():
    rng = np.random.default_rng(4)
    length, width = 4.69, 1.85
    for _ in range(20):
        xy, yaw = rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi)
        box = box_corners(np.array([rng.uniform(4, 6), rng.uniform(-3, 3)]), 4.5, 1.8, rng.uniform(-np.pi, np.pi))
        planes = hyperplanes(xy[None], np.array([yaw]), np.zeros(1), length, width, box[None, None], 1)
        normal = planes.normals[0, 0]
        for step in (1e-2, 1e-3):
            moved_xy, moved_yaw = xy + step * rng.standard_normal(2), yaw + step * rng.standard_normal()
            ego = box_corners(moved_xy, length, width, moved_yaw)
            # the true distance along the fixed normal, against the bound's prediction from the binding corners
            true = (ego @ normal).min() - (box @ normal).max()
            predicted = (normal @ moved_xy + planes.yaw_gains[0, 0] * moved_yaw - planes.offsets[0, 0]).min()
            assert abs(predicted - true) <= 10.0 * step ** 2


def next_lane_pair(t: float) -> Obstacles:
    """Two cars in the next lane at 3.6 m/s, one beside the ego's start and one 10 m ahead of it."""
    return boxes([[3.6 * t, -3.55], [10.0 + 3.6 * t, -3.55]], [[4.4, 2.0], [4.4, 2.0]], [[3.6, 0.0], [3.6, 0.0]],
                 stamp_ns=int(round(t * 1e9)))


def test_with_a_headway_band_the_car_passes_slow_cars_in_the_next_lane():
    """The headway keeps a distance from what lies ahead in the car's path; counted on every obstacle, the car ahead
    in the next lane holds the ego beside its neighbour, with the band (the default) it passes both and keeps its lane."""
    start = (0.0, 0.0, 0.0, 3.6)
    held, _clearance, _steps = drive(planner_for([[0, 0], [400, 0]], obstacles={"headway_band": None}), start, 100,
                                     next_lane_pair)
    passed, clearance, _steps = drive(planner_for([[0, 0], [400, 0]]), start, 100, next_lane_pair)
    assert passed[-1, 0] > 10.0 + 3.6 * 10 + 20.0 > held[-1, 0]  # well past the front car; held: not
    assert passed[-1, 3] == pytest.approx(10.0, abs=0.3)
    assert np.abs(passed[:, 1]).max() < 0.2 and clearance.min() > 1.0  # in its lane, clear of them


def test_the_headway_band_still_keeps_the_headway_behind_a_slow_car_in_the_path():
    lead = lambda t: boxes([[25.0 + 4.0 * t, 0.0]], [[4.4, 2.0]], [[4.0, 0.0]], stamp_ns=int(round(t * 1e9)))  # noqa: E731
    gaps = {}
    for band in (None, 0.5):
        overrides = {"obstacles": {"headway_band": band}, "passing": {"offset": 0.0}}  # behind it, no passing
        states, _clearance, _steps = drive(planner_for([[0, 0], [400, 0]], **overrides), (0.0, 0.0, 0.0, 8.0), 150, lead)
        gaps[band] = 25.0 + 4.0 * 150 * TICK - states[-1, 0]
        assert states[-1, 3] == pytest.approx(4.0, abs=0.3)  # follows at the lead's speed
    assert gaps[0.5] == pytest.approx(gaps[None], abs=0.2)


def test_in_path_counts_a_car_at_the_steps_it_is_predicted_to_cut_in():
    steps = 5
    ego_xy, heading = np.c_[np.arange(steps) * 2.0, np.zeros(steps)], np.tile([1.0, 0.0], (steps, 1))
    cutting_in = np.stack([box_corners(np.array([12.0 + 2.0 * k, -3.55 + 0.9 * k]), 4.4, 2.0, 0.0) for k in range(steps)])
    in_lane = np.stack([box_corners(np.array([15.0, 0.3]), 4.4, 2.0, 0.0)] * steps)
    next_lane = np.stack([box_corners(np.array([15.0, 3.55]), 4.4, 2.0, 0.0)] * steps)
    corners = np.stack([cutting_in, in_lane, next_lane], axis=1)  # (T, M, 4, 2)
    inside = in_path(ego_xy, heading, 1.85, corners, 0.5)
    assert inside[:, 1].all() and not inside[:, 2].any()
    assert not inside[0, 0] and inside[-1, 0]
    assert np.array_equal(inside[:, 0], np.sort(inside[:, 0]))  # once in, it stays in as it comes over


ROUTE = Route(np.array([[0.0, 0.0], [600.0, 0.0]]))
RIGHT_LANE = -3.5


def chooser(**overrides) -> LaneChooser:
    return LaneChooser(PassingConfig(offset=RIGHT_LANE, **overrides), VehicleConfig(), reference_speed=10.0)


def cars(*rows) -> object:
    """Cars (x, y, speed along x) of 4.4 x 2.0 m."""
    rows = np.array(rows, dtype=float).reshape(-1, 3)
    return boxes(rows[:, :2], np.tile([4.4, 2.0], (len(rows), 1)), np.c_[rows[:, 2], np.zeros(len(rows))])


def test_moves_out_only_when_the_other_lane_is_clearly_faster_and_clear_beside():
    def choice(*rows) -> float:  # the ego at x = 100 m on the route; rows relative to it
        return chooser().choose(ROUTE, np.array([100.0, 0.0]), 0, cars(*[(100 + x, y, v) for x, y, v in rows]))

    assert choice((20, 0, 4.0)) == RIGHT_LANE  # a slow car ahead, the lane beside free
    assert choice((20, 0, 9.0)) == 0.0  # not 1.5 m/s faster there
    assert choice((20, 0, 4.0), (30, RIGHT_LANE, 4.5)) == 0.0  # just as slow there
    assert choice((20, 0, 4.0), (-6, RIGHT_LANE, 6.0)) == 0.0  # someone close behind in it
    assert choice((20, 0, 4.0), (-30, RIGHT_LANE, 6.0)) == RIGHT_LANE  # far behind
    assert choice((20, 0, 4.0), (20, 2 * RIGHT_LANE, 0.0)) == RIGHT_LANE  # two lanes off


def test_keeps_a_choice_for_the_hold_time_then_returns_to_the_route_when_it_is_no_slower():
    lanes = chooser(hold_s=3.0)
    assert lanes.choose(ROUTE, np.array([0.0, 0.0]), 0, cars((20, 0, 4.0))) == RIGHT_LANE
    passed = cars((20, 0, 4.0))  # the ego is now 30 m past the slow car, in the right lane
    assert lanes.choose(ROUTE, np.array([50.0, RIGHT_LANE]), int(2.9e9), passed) == RIGHT_LANE  # held
    assert lanes.choose(ROUTE, np.array([50.0, RIGHT_LANE]), int(3.1e9), passed) == 0.0


def test_without_an_offset_the_car_keeps_to_the_route():
    lanes = LaneChooser(PassingConfig(offset=0.0), VehicleConfig(), reference_speed=10.0)
    assert lanes.choose(ROUTE, np.array([0.0, 0.0]), 0, cars((10, 0, 0.0))) == 0.0


def test_the_planner_passes_a_slow_car_in_the_lane_beside_and_comes_back():
    lead = lambda t: boxes([[25.0 + 4.0 * t, 0.0]], [[4.4, 2.0]], [[4.0, 0.0]], stamp_ns=int(round(t * 1e9)))  # noqa: E731
    start, ticks = (0.0, 0.0, 0.0, 8.0), 200
    behind, _clearance, _steps = drive(planner_for([[0, 0], [600, 0]], passing={"offset": 0.0}), start, ticks, lead)
    planner = planner_for([[0, 0], [600, 0]])  # the defaults: the lane to the right, the headway band
    passed, clearance, _steps = drive(planner, start, ticks, lead)
    lead_x = 25.0 + 4.0 * ticks * TICK
    assert behind[-1, 0] < lead_x < passed[-1, 0] - 50.0
    assert passed[:, 1].min() == pytest.approx(RIGHT_LANE, abs=0.4) and abs(passed[-1, 1]) < 0.3  # out and back
    assert passed[-1, 3] == pytest.approx(10.0, abs=0.3) and clearance.min() > 1.0
    assert planner.stats.fallbacks == 0


def test_the_headway_band_leaves_people_beside_the_path_their_headway():
    """A box 10 m ahead in the next lane: a car there keeps its lane (no headway), a person may step out (headway)."""
    box = box_corners(np.array([10.0, -3.55]), 0.6, 0.6, 0.0)[None, None]
    ego_xy, yaw, speed = np.zeros((1, 2)), np.zeros(1), np.full(1, 8.0)
    car = hyperplanes(ego_xy, yaw, speed, 4.69, 1.85, box, 1, band=0.5, lanes_kept=np.array([True]))
    person = hyperplanes(ego_xy, yaw, speed, 4.69, 1.85, box, 1, band=0.5, lanes_kept=np.array([False]))
    unbanded = hyperplanes(ego_xy, yaw, speed, 4.69, 1.85, box, 1)
    assert car.closing[0, 0] == 0.0 and person.closing[0, 0] == unbanded.closing[0, 0] > 4.0


def test_holding_the_plan_commands_its_control_for_now_without_solving_and_only_a_solved_plan_is_held():
    """Between perception answers `hold` sends the last solved plan's control for now (its step 1 after one horizon
    step), not counted as a fallback; there is nothing to hold before a plan, after a brake, or near the plan's end."""
    planner = planner_for([[0, 0], [400, 0]])
    start = VehicleState(0, 0.0, 0.0, 0.0, 5.0)
    assert planner.hold(start) is None  # no plan yet
    solved = planner.step(start)
    assert solved.status is TickStatus.SOLVED
    later = int(planner.config.dt * 1e9)
    states, controls = solved.plan.states, solved.plan.controls
    held = planner.hold(VehicleState(later, *states[1]))
    assert held is not None and held.status is TickStatus.HELD and held.rounds == 0
    np.testing.assert_allclose(held.plan.controls[:-1], controls[1:])  # the same plan, one step on
    np.testing.assert_allclose(held.plan.states[:-1, :2], states[1:, :2], atol=1e-9)
    assert held.command.linear == pytest.approx(states[1, 3] + controls[1, 0] * planner.config.control_period)
    assert planner.stats.fallbacks == 0 and planner.stats.ticks[TickStatus.HELD] == 1 and planner.last_command == held.command
    ending = int((planner.config.horizon * planner.config.dt - 0.5 * planner.config.control_period) * 1e9)
    assert planner.hold(VehicleState(ending, *states[-1])) is None  # the plan ends within the next period
    planner.blind_brake(VehicleState(later, *states[1]), "test")
    assert planner.hold(VehicleState(later, *states[1])) is None  # braking: no plan to hold
