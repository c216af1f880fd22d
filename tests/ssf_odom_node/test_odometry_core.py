"""Odometry core: weighted Kabsch with outliers, the three variants on a static street with a moving convoy, the
static map's memory cap, the covariance, gaps (with and without a motion prior), and known motions of real VLP-16/VLP-32 scans."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common.errors import ConfigError, DataError
from ssf_common.geometry.se3 import invert, make_pose, rotation_angle, transform_points
from ssf_common.scans import read_scan
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, OdomMethod, make_odometry
from ssf_common.geometry.registration import (PlaneTarget, estimate_normals, flow_transform, normals_among,
                                              point_to_plane, steep_support)
from ssf_odom_node.core.static_map import MapConfig, VoxelMap

CONVOY_STEP = 1.0  # m per scan, along x (world)
EGO = make_pose(0.5, 0.05, 0.0, 0.01)  # the ego's motion between the two scans


def faces(rng: np.random.Generator, centre, size, count: int) -> np.ndarray:
    """Points on the four sides and the top of an upright box (centre of its base)."""
    length, width, height = size
    face = rng.integers(0, 5, count)
    u, v = rng.uniform(-0.5, 0.5, count), rng.uniform(0.0, 1.0, count)
    local = np.c_[u * length, (v - 0.5) * width, np.full(count, height)]  # top
    sides = face < 4
    local[sides, 2] = v[sides] * height
    local[face == 0, 0], local[face == 1, 0] = length / 2, -length / 2
    local[face == 0, 1], local[face == 1, 1] = u[face == 0] * width, u[face == 1] * width
    local[face == 2, 1], local[face == 3, 1] = width / 2, -width / 2
    return local + np.asarray(centre)


def street(seed: int, moved: bool) -> tuple[np.ndarray, np.ndarray]:
    """World points of a street (ground, a long wall, a cross wall) and a convoy of trucks; moving flags."""
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-40, 40, (3000, 2)), rng.normal(-1.8, 0.01, 3000)]
    wall = np.c_[rng.uniform(-40, 40, 1500), np.full(1500, 12.0), rng.uniform(-1.8, 3.0, 1500)]
    cross = np.c_[np.full(500, 28.0), rng.uniform(-10, 10, 500), rng.uniform(-1.8, 3.0, 500)]
    shift = CONVOY_STEP if moved else 0.0
    trucks = [faces(rng, (x + shift, y, -1.8), (8.0, 2.5, 3.5), 600)
              for x, y in ((-20, -6), (-8, -6), (4, -6), (14, -6), (-14, 3), (-2, 3), (10, 3), (-26, 3))]
    static = np.vstack([ground, wall, cross])
    points = np.vstack([static, *trucks])
    return points, np.r_[np.zeros(len(static), bool), np.ones(len(points) - len(static), bool)]


def convoy_scans() -> tuple[OdomInput, OdomInput, np.ndarray]:
    """Scan 1 (with its exact flow and motion labels) and scan 2 in their sensor frames, and the true motion."""
    world1, moving = street(1, moved=False)
    world2, _ = street(2, moved=True)
    points1 = transform_points(invert(np.eye(4)), world1)
    target = world1 + np.where(moving[:, None], [CONVOY_STEP, 0.0, 0.0], 0.0)  # where scan-1 points are at t+1
    flow = transform_points(invert(EGO), target) - points1
    points2 = transform_points(invert(EGO), world2)
    return (OdomInput(0, points1, flow, moving.astype(np.float32)), OdomInput(100_000_000, points2), EGO)


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) of estimate^-1 truth."""
    error = invert(estimate) @ truth
    return float(np.linalg.norm(error[:3, 3])), float(np.degrees(rotation_angle(error)))


def test_weighted_kabsch_recovers_the_motion_with_outliers_down_weighted():
    rng = np.random.default_rng(0)
    points = rng.uniform(-20, 20, (2000, 3))
    motion = make_pose(0.8, -0.3, 0.05, 0.03)
    flow = transform_points(motion, points) - points
    outliers = rng.random(len(points)) < 0.3
    flow[outliers] += [1.0, 0.2, 0.0]  # a moving convoy: wrong for the ego motion
    weighted = flow_transform(points, flow, np.where(outliers, 0.0, 1.0))
    plain = flow_transform(points, flow, None)
    assert pose_error(weighted, motion)[0] < 1e-5 and pose_error(weighted, motion)[1] < 1e-4
    assert pose_error(plain, motion)[0] > 0.05  # the outliers pull the unweighted fit


@pytest.mark.parametrize("method", list(OdomMethod))
def test_each_variant_on_a_static_street_with_a_moving_convoy(method):
    scan1, scan2, truth = convoy_scans()
    # which points each variant registers, alike near and far (near weighting has a test of its own)
    odometry = make_odometry(method, OdomConfig(near_range=0.0))
    first = odometry.step(scan1 if method is not OdomMethod.POINTS else OdomInput(0, scan1.points))
    second = odometry.step(scan2)
    np.testing.assert_allclose(first.pose, np.eye(4))
    translation, rotation = pose_error(second.pose, truth)
    if method is OdomMethod.SSF:  # the static points ignore the convoy
        assert translation < 0.02 and rotation < 0.1
        assert second.predicted_by == "flow"
    else:  # whole scans, or every point's flow, are pulled towards the convoy
        assert translation > (0.1 if method is OdomMethod.POINTS else 0.04)


def queue_street() -> tuple[np.ndarray, np.ndarray]:
    """The street's static points and a queue of six cars around the sensor."""
    rng = np.random.default_rng(3)
    world, moving = street(1, moved=False)
    queue = np.vstack([faces(rng, (x, y, -1.8), (4.5, 1.9, 1.6), 300)
                       for x, y in ((-9, -3.5), (-3, -3.5), (3, -3.5), (9, -3.5), (6, 3.5), (-6, 3.5))])
    return world[~moving], queue


def test_near_points_weigh_less_so_a_queue_moving_with_the_ego_does_not_hold_it_still():
    """Cars all around the ego moving with it, labelled static, and the flow's motion taken by them (standing still):
    registered alike, they keep the pose still; weighted by their range, the street beyond them gives the motion."""
    static, queue = queue_street()
    first = np.vstack([static, queue])
    target = PlaneTarget.build(first, estimate_normals(first, 8))
    second = np.vstack([transform_points(invert(EGO), static), queue])  # the queue keeps its place around the sensor
    odometry = make_odometry("ssf")
    weights = odometry.near_weights(second)
    assert weights.min() == pytest.approx(odometry.config.near_weight) and weights.max() == 1.0
    config = odometry.config
    plain = point_to_plane(second, None, target, np.eye(4), config.search_gates, config.kernel)
    near = point_to_plane(second, weights, target, np.eye(4), config.search_gates, config.kernel)
    assert pose_error(plain.transform, EGO)[0] > 0.3  # held still by the queue
    assert pose_error(near.transform, EGO)[0] < 0.02
    off = make_odometry("ssf", OdomConfig(near_range=0.0))
    assert np.all(off.near_weights(second) == 1.0)


def queue_drive(measured: bool) -> tuple[list, np.ndarray]:
    """Two scans of a street with a queue of cars around the ego that moves with it, all labelled static, and a flow
    that (fooled by the queue) says the ego stands still; with or without the vehicle's measured motion."""
    static, queue = queue_street()
    first = np.vstack([static, queue])
    second = np.vstack([transform_points(invert(EGO), static), queue])
    still, labels = np.zeros_like(first), np.zeros(len(first), np.float32)
    odometry = make_odometry("ssf", OdomConfig(near_range=0.0))  # near weighting has a test of its own
    steps = [odometry.step(OdomInput(0, first, still, labels)),
             odometry.step(OdomInput(100_000_000, second, still, labels, measured_motion=EGO if measured else None))]
    return steps, EGO


def test_the_measured_motion_overrules_a_flow_fooled_by_traffic_moving_with_the_ego():
    (_, fooled), truth = queue_drive(measured=False)
    assert pose_error(fooled.pose, truth)[0] > 0.3 and fooled.predicted_by == "flow"  # held still by the queue
    (_, second), truth = queue_drive(measured=True)
    assert second.predicted_by == "measured"
    translation, rotation = pose_error(second.pose, truth)
    assert translation < 0.05 and rotation < 0.2


def test_a_measured_motion_that_agrees_with_the_flow_leaves_the_flow_in_charge():
    scan1, scan2, truth = convoy_scans()
    odometry = make_odometry("ssf", OdomConfig(near_range=0.0))
    odometry.step(scan1)
    nearby = truth @ make_pose(0.02, 0.0, 0.0, 0.0)  # 2 cm off: a wheel-speed error
    second = odometry.step(OdomInput(scan2.stamp_ns, scan2.points, measured_motion=nearby))
    assert second.predicted_by == "flow" and pose_error(second.pose, truth)[0] < 0.02
    with pytest.raises(DataError, match="measured motion"):
        odometry.step(OdomInput(200_000_000, scan2.points, measured_motion=np.eye(3)))


def test_ssf_map_holds_no_convoy_points_and_points_map_does():
    scan1, _, _ = convoy_scans()
    ssf, points = make_odometry("ssf"), make_odometry("points")
    ssf.step(scan1)
    points.step(OdomInput(0, scan1.points))

    def on_trucks(cloud: np.ndarray) -> int:
        lanes = (np.abs(cloud[:, 1] + 6) < 1.3) | (np.abs(cloud[:, 1] - 3) < 1.3)
        return int((lanes & (cloud[:, 2] > -1.5) & (cloud[:, 0] < 25.0)).sum())  # the cross wall stands at x = 28

    assert on_trucks(ssf.map.points) == 0
    assert on_trucks(points.map.points) > 100


@pytest.mark.parametrize("target_range", [35.0, 60.0])
def test_static_points_beyond_the_segmentations_range_join_the_target_never_the_map(target_range):
    rng = np.random.default_rng(4)
    ground = np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.8, 0.01, 3000)]
    near_wall = np.c_[rng.uniform(-30, 30, 1500), np.full(1500, 12.0), rng.uniform(-1.8, 3.0, 1500)]
    far_wall = np.c_[np.full(1500, 50.0), rng.uniform(-15, 15, 1500), rng.uniform(-1.8, 6.0, 1500)]
    points = np.vstack([ground, near_wall, far_wall])
    odometry = make_odometry("ssf", OdomConfig(ssf_range=35.0, target_range=target_range))
    for scan in range(12):  # standing still: every scan observes the same points static
        odometry.step(OdomInput(scan * 100_000_000, points, np.zeros_like(points), np.zeros(len(points), np.float32)))
    held, mapped = odometry.map.stored_points, odometry.map.points
    assert (mapped[:, 0] > 40).sum() == 0  # nothing farther than the segmentation sees is published as static
    assert (mapped[:, 1] > 11).sum() > 50  # the near wall is confirmed
    assert ((held[:, 0] > 40).sum() > 50) == (target_range > 40)  # the far wall is registered against


def test_covariance_grows_and_is_positive_definite():
    scan1, scan2, _ = convoy_scans()
    odometry = make_odometry("ssf")
    odometry.step(scan1)
    second = odometry.step(scan2)
    eigenvalues = np.linalg.eigvalsh(second.covariance)
    assert eigenvalues.min() > 0 and eigenvalues.max() < 1.0
    third = odometry.step(OdomInput(200_000_000, scan2.points))
    assert np.trace(third.covariance) > np.trace(second.covariance)


def test_a_gap_keeps_the_constant_velocity_prediction():
    """Scans 0-2 with flow, scan 3 missing: scan 4 is found only from the flow's motion plus constant velocity."""
    config = OdomConfig(refine_gates=(0.3,), search_gates=(0.3,), ssf_range=100.0)  # no room to search
    odometry = make_odometry("ssf", config)
    world, moving = street(3, moved=False)
    world = world[~moving]
    scan = lambda index: transform_points(invert(make_pose(0.5 * index)), world)
    for index in range(3):
        points = scan(index)
        flow = scan(index + 1) - points
        odometry.step(OdomInput(index * 100_000_000, points, flow, np.zeros(len(points), np.float32)))
    assert odometry.velocity[0] == pytest.approx(5.0, abs=0.05)
    after_gap = odometry.step(OdomInput(400_000_000, scan(4)))
    assert after_gap.pose[0, 3] == pytest.approx(2.0, abs=0.02)  # 0.5 m by the flow, 0.5 m at 5 m/s beyond it
    assert after_gap.predicted_by == "flow"


def test_skipped_scans_follow_the_flows_motion_rate():
    """Only every third scan reaches the odometry (as in a busy graph): from the very first gap, the flow's own
    motion rate carries each scan to the next, not a velocity it has had no chance to measure yet."""
    config = OdomConfig(refine_gates=(0.3,), search_gates=(0.3,), ssf_range=100.0)  # no room to search
    odometry = make_odometry("ssf", config)
    world, moving = street(4, moved=False)
    world = world[~moving]
    scan = lambda index: transform_points(invert(make_pose(0.5 * index)), world)
    for index in (0, 3, 6, 9):
        points = scan(index)
        step = odometry.step(OdomInput(index * 100_000_000, points, scan(index + 1) - points,
                                       np.zeros(len(points), np.float32)))
        assert step.pose[0, 3] == pytest.approx(0.5 * index, abs=0.03)
        assert step.predicted_by in ("start", "flow")


@pytest.mark.parametrize("headings, found", [((3.0, 6.0, 9.0, 12.0, 16.0, 20.0), True), ((), False)])
def test_a_swerve_between_skipped_scans_is_found_by_the_heading_search(headings, found):
    """Every third scan reaches the odometry and the car swerves 14 degrees in between: the flow measured before
    the swerve extrapolates straight on; the heading search finds the turn, without it the pose goes astray."""
    config = OdomConfig(ssf_range=100.0, gap_headings=headings)
    odometry = make_odometry("ssf", config)
    world, moving = street(4, moved=False)
    world = world[~moving]
    poses = {index: make_pose(1.0 * index) for index in (0, 1, 3, 4, 6, 7)}
    poses[9] = poses[6] @ make_pose(3.0, 0.0, 0.0, yaw=0.25)
    poses[10] = poses[9] @ make_pose(1.0, 0.0, 0.0)
    scan = lambda index: transform_points(invert(poses[index]), world)
    for index in (0, 3, 6, 9):
        points = scan(index)
        step = odometry.step(OdomInput(index * 100_000_000, points, scan(index + 1) - points,
                                       np.zeros(len(points), np.float32)))
    translation, rotation = pose_error(step.pose, poses[9])
    assert (translation < 0.1 and rotation < 0.5) == found, (translation, rotation)


@pytest.mark.parametrize("yaw_rate, found", [(40.0, True), (1.0, False)])
def test_a_long_gap_widens_the_heading_search(yaw_rate, found):
    """Seven scans are skipped and the car turns 25 degrees meanwhile, beyond the gap headings' 20: the search
    widens with the gap (gap_yaw_rate x 0.7 s) and finds the turn; held to the configured headings it does not."""
    translation, rotation, _ = turn_across_a_long_gap(OdomConfig(ssf_range=100.0, gap_yaw_rate=yaw_rate), None)
    assert (translation < 0.1 and rotation < 0.5) == found, (translation, rotation)


def test_the_measured_motion_carries_a_turn_across_skipped_scans_without_a_heading_search():
    """The 25 degree turn over seven skipped scans with no heading search at all: the measured motion (a gyro saw the
    turn) starts the refinement where the truth is; without it the pose goes astray."""
    config = OdomConfig(ssf_range=100.0, gap_headings=(), gap_yaw_rate=1.0)
    lost = turn_across_a_long_gap(config, None)
    assert lost[0] > 0.1 or lost[1] > 0.5
    translation, rotation, source = turn_across_a_long_gap(config, 0.3, measured=True)
    assert translation < 0.1 and rotation < 0.5 and source == "measured"


def turn_across_a_long_gap(config: OdomConfig, prior_yaw: float | None,
                           measured: bool = False) -> tuple[float, float, str]:
    """The 25 degree turn over seven skipped scans, the last scan with the true motion turned by `prior_yaw`
    degrees as its prior (None: no prior; `measured`: as the measured motion instead of the commands' prior):
    translation and rotation error at that scan, and what predicted it."""
    odometry = make_odometry("ssf", config)
    world, moving = street(4, moved=False)
    world = world[~moving]
    poses = {index: make_pose(1.0 * index) for index in (0, 1, 7, 8)}
    poses[14] = poses[7] @ make_pose(6.0, 0.0, 0.0, yaw=np.radians(25.0))
    poses[15] = poses[14] @ make_pose(1.0, 0.0, 0.0)
    scan = lambda index: transform_points(invert(poses[index]), world)
    for index in (0, 7, 14):
        points = scan(index)
        prior = None
        if index == 14 and prior_yaw is not None:
            prior = make_pose(0.0, 0.0, 0.0, yaw=np.radians(prior_yaw)) @ invert(poses[7]) @ poses[14]
        step = odometry.step(OdomInput(index * 100_000_000, points, scan(index + 1) - points,
                                       np.zeros(len(points), np.float32), None if measured else prior,
                                       prior if measured else None))
    return *pose_error(step.pose, poses[14]), step.predicted_by


@pytest.mark.parametrize("prior_yaw, found", [(None, False), (0.0, True), (-4.0, True)])
def test_a_motion_prior_finds_a_turn_the_flow_search_cannot_reach(prior_yaw, found):
    """Held to the configured headings, the search from the flow's extrapolation misses the 25 degree turn; the motion
    the commands drove (exact, or 4 degrees off: within the narrow search around it) finds it."""
    translation, rotation, source = turn_across_a_long_gap(OdomConfig(ssf_range=100.0, gap_yaw_rate=1.0), prior_yaw)
    assert (translation < 0.1 and rotation < 0.5) == found, (translation, rotation)
    assert source == ("prior" if found else "flow")


def test_a_wrong_motion_prior_loses_to_the_flow_search():
    """A prior 30 degrees off (commands the vehicle did not follow) lays fewer points on the walls than the widened
    search from the flow, which keeps the turn."""
    translation, rotation, source = turn_across_a_long_gap(OdomConfig(ssf_range=100.0), 30.0)
    assert translation < 0.1 and rotation < 0.5, (translation, rotation)
    assert source == "flow"


def test_where_the_flow_and_the_prior_agree_across_a_gap_the_flow_search_is_skipped(monkeypatch):
    """Straight on over seven skipped scans, the commands' motion exact: the flow's extrapolation already is the
    prior's searched start, so only the prior's five headings are tried (not the flow's wide search) and the pose
    is right."""
    odometry = make_odometry("ssf", OdomConfig(ssf_range=100.0))
    world, moving = street(4, moved=False)
    world = world[~moving]
    poses = {index: make_pose(1.0 * index) for index in (0, 1, 7, 8, 14, 15)}
    scan = lambda index: transform_points(invert(poses[index]), world)
    searched: list[int] = []
    search = type(odometry).best_heading
    monkeypatch.setattr(type(odometry), "best_heading",
                        lambda self, *args: searched.append(len(args[-1])) or search(self, *args))
    for index in (0, 7, 14):
        points = scan(index)
        prior = None if index == 0 else invert(poses[index - 7]) @ poses[index]
        step = odometry.step(OdomInput(index * 100_000_000, points, scan(index + 1) - points,
                                       np.zeros(len(points), np.float32), prior))
    translation, rotation = pose_error(step.pose, poses[14])
    assert translation < 0.05 and rotation < 0.2, (translation, rotation)
    assert step.predicted_by == "prior"
    assert searched[-1] == 5 and len(searched) == 2, searched  # one search per gap: the prior's five headings


@pytest.mark.parametrize("flow_excess, refined, searched", [(0.04, True, False), (0.10, True, True), (0.30, False, True)])
def test_a_flow_motion_no_vehicle_makes_is_checked_from_constant_velocity(monkeypatch, flow_excess, refined, searched):
    """Driving 1 m a scan, a flow that says 4 cm more is a change of speed a car makes in 0.1 s (4 m/s²) and is only
    refined; 10 cm more (10 m/s², past braking at 0.8 g) is checked by a search from constant velocity as well; 30 cm
    more (30 m/s², past the flow gate: traffic taken for the world) is not refined at all. The pose stays right each
    way on a static street."""
    from ssf_odom_node.core import odometry as core

    odometry = make_odometry("ssf", OdomConfig(ssf_range=100.0))
    world, moving = street(5, moved=False)
    world = world[~moving]
    poses = [make_pose(1.0 * index) for index in range(5)]
    scan = lambda index: transform_points(invert(poses[index]), world)
    for index in range(3):
        points = scan(index)
        odometry.step(OdomInput(index * 100_000_000, points, scan(index + 1) - points, np.zeros(len(points), np.float32)))
    gates: list[tuple[float, ...]] = []
    refine = core.point_to_plane
    monkeypatch.setattr(core, "point_to_plane", lambda *args: gates.append(args[4]) or refine(*args))
    points = scan(3)
    overshot = transform_points(invert(make_pose(1.0 + flow_excess)), points) - points  # flow of a 1 m + excess step
    odometry.step(OdomInput(300_000_000, points, overshot, np.zeros(len(points), np.float32)))
    gates.clear()
    step = odometry.step(OdomInput(400_000_000, scan(4)))  # predicted by the overshooting flow
    assert (odometry.config.refine_gates in gates) == refined, gates
    assert (odometry.config.search_gates in gates) == searched, gates
    if not refined:
        assert step.predicted_by == "velocity" and odometry.rejected_flows == 1
    assert pose_error(step.pose, poses[4])[0] < 0.02


def test_the_flow_gate_can_be_switched_off():
    """With flow_gate 0 a flow motion however far from constant velocity is refined (and checked by a search)."""
    odometry = make_odometry("flow", OdomConfig(flow_gate=(0.0, 0.0)))
    far = make_pose(5.0)
    assert odometry.possible(far, np.eye(4))
    assert not make_odometry("flow").possible(far, np.eye(4))


def test_a_motion_prior_must_be_a_finite_transform():
    odometry = make_odometry("points")
    points = np.random.default_rng(0).uniform(-20, 20, (500, 3))
    odometry.step(OdomInput(0, points))
    with pytest.raises(DataError, match="motion prior"):
        odometry.step(OdomInput(100_000_000, points, motion_prior=np.full((4, 4), np.nan)))


def test_steep_support_counts_walls_not_the_ground():
    """Turned about the vertical, the ground still fits and the wall does not: only the wall's points count, and only
    where they lie on it."""
    world, moving = street(5, moved=False)
    world = world[~moving]
    target = PlaneTarget.build(world, estimate_normals(world, 8))
    ground, wall = world[:3000], world[3000:4500]  # the street's ground, then its long wall
    assert steep_support(ground, np.eye(4), target) < 0.05 * len(ground)  # the few by the walls' feet
    assert steep_support(wall, np.eye(4), target) > 0.9 * len(wall)
    turned = make_pose(0.0, 0.0, 0.0, yaw=np.radians(10.0))
    assert steep_support(wall, turned, target) < 0.3 * len(wall)


def test_inputs_are_checked():
    odometry = make_odometry("ssf")
    points = np.zeros((10, 3), np.float32)
    with pytest.raises(DataError, match="NaN"):
        odometry.step(OdomInput(0, np.full((10, 3), np.nan, np.float32)))
    with pytest.raises(DataError, match="flow"):
        odometry.step(OdomInput(0, points, np.zeros((9, 3))))
    with pytest.raises(ConfigError, match="segmentation"):
        odometry.step(OdomInput(0, points, np.zeros((10, 3))))
    with pytest.raises(ConfigError, match="unknown odometry method"):
        make_odometry("lidar")


def test_the_map_stays_under_its_memory_cap_and_window():
    config = MapConfig(voxel=0.5, radius=30.0, max_voxels=2000, confirm=1)
    voxel_map = VoxelMap(config)
    rng = np.random.default_rng(0)
    for step in range(20):
        centre = np.array([5.0 * step, 0.0, 0.0])
        points = centre + rng.uniform(-40, 40, (5000, 3)) * [1, 1, 0.1]
        added = voxel_map.insert(points, np.tile([0, 0, 1.0], (5000, 1)), centre)
        assert added > 0
        assert len(voxel_map) <= config.max_voxels
        assert voxel_map.nbytes <= config.max_bytes
        assert np.linalg.norm(voxel_map.points[:, :2] - centre[:2], axis=1).max() <= config.radius + 1e-3
    assert len(np.unique(voxel_map.codes)) == len(voxel_map)  # one point per voxel


def test_normals_of_a_plane_and_a_wall():
    rng = np.random.default_rng(1)
    plane = np.c_[rng.uniform(-5, 5, (500, 2)), np.zeros(500)]
    wall = np.c_[rng.uniform(-5, 5, 500), np.full(500, 20.0), rng.uniform(0, 3, 500)]
    normals = estimate_normals(np.vstack([plane, wall]), 8)
    assert np.abs(normals[:500, 2]).min() > 0.99 and np.abs(normals[500:, 1]).min() > 0.99


def test_a_far_ring_takes_its_ground_normal_from_the_map_too():
    """One scan's voxelised ground ring 40 m out is nearly a line, so its own neighbours tilt the normal with the range
    noise (median ~8 deg here); among the rings earlier scans left in the map it is within 2.5 deg of vertical."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)

    def ring(radius: float, count: int = 40) -> np.ndarray:
        angle = np.arange(count) * 0.8 / radius  # one point per 0.8 m, as the odometry's voxels leave it
        return np.c_[radius * np.cos(angle), radius * np.sin(angle), 0.03 * rng.standard_normal(count)]

    scan = ring(40.0)
    earlier = np.concatenate([ring(radius) for radius in (38.6, 39.3, 40.7, 41.4)])
    tilt = lambda normals: np.degrees(np.arccos(np.abs(normals[:, 2])))  # noqa: E731
    alone = tilt(estimate_normals(scan, 8, np.arange(10, 30)))
    among = tilt(normals_among(scan[10:30], [(earlier, cKDTree(earlier)), (scan, cKDTree(scan))], 8))
    assert np.median(alone) > 5.0
    assert among.max() < 2.5
    assert len(normals_among(np.zeros((0, 3)), [(scan, cKDTree(scan))])) == 0


@pytest.mark.parametrize("name", ["vlp16_1673400472138016708.pcd", "vlp32_1713492677464078412.pcd"])
@pytest.mark.parametrize("method", ["points", "ssf"])
def test_real_scan_known_motion(shared_data, name, method):
    """Two scans of real geometry (different points, 1 cm noise) a known motion apart: recovered within 0.05 m / 0.2 deg."""
    scan = read_scan(shared_data / "lidar_scans" / name)[:, :3].astype(np.float64)
    scan = scan[np.isfinite(scan).all(axis=1) & (np.linalg.norm(scan[:, :2], axis=1) > 1.0)]
    rng = np.random.default_rng(0)
    motion = make_pose(0.8, 0.25, 0.02, np.radians(2.0))  # scan 2's pose in scan 1's frame
    first = scan[rng.random(len(scan)) < 0.8]
    second = transform_points(invert(motion), scan[rng.random(len(scan)) < 0.8])
    second = second + rng.normal(0.0, 0.01, second.shape)
    flow = transform_points(invert(motion), first) - first + rng.normal(0.0, 0.02, first.shape)  # noisy flow
    odometry = make_odometry(method)
    odometry.step(OdomInput(0, first, flow if method == "ssf" else None,
                            np.zeros(len(first), np.float32) if method == "ssf" else None))
    estimate = odometry.step(OdomInput(100_000_000, second)).pose
    translation, rotation = pose_error(estimate, motion)
    assert translation < 0.05 and rotation < 0.2, (translation, rotation)


def test_next_pose_is_the_last_pose_moved_on_by_the_static_flow():
    odometry = make_odometry("ssf", OdomConfig())
    assert odometry.next_pose() is None  # no scan yet
    odometry.stamp_ns, odometry.pose = 10**9, make_pose(20.0, 5.0, 0.0, yaw=0.3)
    odometry.next_motion = invert(make_pose(0.81, 0.0, 0.0, yaw=0.01))  # static points seem to move back
    np.testing.assert_allclose(odometry.next_pose(), odometry.pose @ make_pose(0.81, 0.0, 0.0, yaw=0.01))
    odometry.next_motion = None
    assert odometry.next_pose() is None


def pitch_fix(far: float) -> tuple[float, float]:
    """Translation (m) and rotation (deg) error of a scan 0.3 deg pitched, registered from level against its street
    map, with the street `far` metres from the odometry frame's origin."""
    from scipy.spatial.transform import Rotation

    world = street(3, moved=False)[0][: 4500] + [far, 0.0, 0.0]  # ground, long wall, cross wall: no trucks
    truth = make_pose(far, 0.0, 0.0, 0.0)
    truth[:3, :3] = Rotation.from_euler("y", 0.3, degrees=True).as_matrix()
    target = PlaneTarget.build(world, estimate_normals(world))
    scan = transform_points(invert(truth), street(4, moved=False)[0][: 4500] + [far, 0.0, 0.0])
    found = point_to_plane(scan, None, target, make_pose(far, 0.0, 0.0, 0.0), (1.0, 0.5, 0.3, 0.3), 0.2)
    return pose_error(found.transform, truth)


def test_a_pitch_is_corrected_as_well_a_kilometre_from_the_start_as_at_it():
    near, far = pitch_fix(0.0), pitch_fix(1500.0)
    assert near[1] < 0.02  # the 0.3 deg are found
    # rotations about the sensor: 1.5 km out the step is the same (about the origin it left the 0.3 deg as they were)
    assert far[1] == pytest.approx(near[1], abs=2e-3) and far[0] == pytest.approx(near[0], abs=5e-3)
