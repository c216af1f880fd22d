"""The static map's robustness to moving points the segmentation misses: a walker labelled static, ray-cast in a
closed yard, leaves no voxels on the path it has left (free-space clearing, or its own motion in the flow), while
the walls and the ground stay; the evidence bookkeeping stays within the voxel cap."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry
from ssf_odom_node.core.static_map import MapConfig, RangeImage, VoxelMap, voxel_codes

GROUND = -1.8  # m, below the sensor
YARD = (-30.0, 30.0, -14.0, 14.0)  # x min, x max, y min, y max of the walls
WALKER = np.array([0.6, 0.6, 1.8])  # m, box size
WALKER_Y = 6.0
EGO_SPEED, WALKER_SPEED, PERIOD = 1.0, 1.2, 0.1  # m/s, m/s, s


def rays(beams: int = 64, columns: int = 720) -> np.ndarray:
    """Unit directions of a spinning sensor: `beams` elevations from -25 to +5 deg, `columns` azimuths."""
    elevation = np.radians(np.linspace(-25.0, 5.0, beams))[:, None]
    azimuth = np.linspace(-np.pi, np.pi, columns, endpoint=False)[None, :]
    return np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                     np.sin(elevation) * np.ones_like(azimuth)], axis=-1).reshape(-1, 3)


def box_hit(origin: np.ndarray, directions: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Distance along each ray to an axis-aligned box (inf where it misses): the slab method."""
    with np.errstate(divide="ignore", invalid="ignore"):
        near, far = (low - origin) / directions, (high - origin) / directions
    enter = np.nanmax(np.minimum(near, far), axis=1)
    leave = np.nanmin(np.maximum(near, far), axis=1)
    return np.where((leave >= enter) & (enter > 0), enter, np.inf)


def cast(ego_x: float, walker_x: float) -> tuple[np.ndarray, np.ndarray]:
    """One scan (sensor frame) of the yard from (ego_x, 0, 0) with the walker at (walker_x, WALKER_Y); which
    points lie on the walker."""
    directions = rays()
    origin = np.array([ego_x, 0.0, 0.0])
    with np.errstate(divide="ignore"):
        ground = np.where(directions[:, 2] < 0, (GROUND - origin[2]) / directions[:, 2], np.inf)
        walls = np.min(np.stack([
            np.where(directions[:, 0] < 0, (YARD[0] - origin[0]) / directions[:, 0], np.inf),
            np.where(directions[:, 0] > 0, (YARD[1] - origin[0]) / directions[:, 0], np.inf),
            np.where(directions[:, 1] < 0, (YARD[2] - origin[1]) / directions[:, 1], np.inf),
            np.where(directions[:, 1] > 0, (YARD[3] - origin[1]) / directions[:, 1], np.inf)]), axis=0)
    centre = np.array([walker_x, WALKER_Y, GROUND + WALKER[2] / 2])
    walker = box_hit(origin, directions, centre - WALKER / 2, centre + WALKER / 2)
    distance = np.minimum(np.minimum(ground, walls), walker)
    return directions * distance[:, None], walker <= distance


def on_walked_path(points: np.ndarray, start: float, end: float) -> np.ndarray:
    """(N,) bool: world points inside the walker's footprint between walker positions start and end, 0.3 m above
    the ground (lower, a beam through the walker's feet lands on the ground just behind: no free space to see)."""
    half = WALKER[:2] / 2 + 0.1
    return ((points[:, 0] >= start - half[0]) & (points[:, 0] <= end + half[0])
            & (np.abs(points[:, 1] - WALKER_Y) <= half[1]) & (points[:, 2] > GROUND + 0.3))


def walk(config: OdomConfig, scans: int = 60, flow_sees_walker: bool = False):
    """The ego drives along x while the walker, labelled static, walks along x beside it; returns the odometry and
    where the walker started and ended. The flow is exact for the yard; for the walker it is the ego's alone
    (flow and segmentation both missed it) unless flow_sees_walker."""
    odometry = make_odometry("ssf", config)
    walker_start = -8.0
    for index in range(scans):
        ego, walker = EGO_SPEED * PERIOD * index, walker_start + WALKER_SPEED * PERIOD * index
        points, on_walker = cast(ego, walker)
        following = points + [-EGO_SPEED * PERIOD, 0.0, 0.0]  # the yard seen from the next pose
        if flow_sees_walker:
            following[on_walker, 0] += WALKER_SPEED * PERIOD
        odometry.step(OdomInput(index * 100_000_000, points, following - points, np.zeros(len(points), np.float32)))
        assert abs(odometry.pose[0, 3] - ego) < 0.05  # the odometry itself follows the ego
    return odometry, walker_start, walker - 2 * (WALKER[0] + config.map.voxel)  # the path it has left behind


def wall_voxels(points: np.ndarray) -> int:
    """Map points on the far wall (y = YARD max), above the ground."""
    return int(((points[:, 1] > YARD[3] - 0.5) & (points[:, 2] > GROUND + 0.3)).sum())


@pytest.mark.parametrize("flow_sees_walker", [False, True])
def test_a_walker_labelled_static_leaves_no_trail_and_the_walls_stay(flow_sees_walker):
    """Without the new rules the walker's trail is in the map; free-space clearing (flow blind too) or its own
    motion in the flow keeps the walked path empty, and the walls and the ground stay mapped."""
    legacy = OdomConfig(map=MapConfig(max_speed=0.0, clear_cell=0.0, confirm=1))
    robust = OdomConfig(map=MapConfig(clear_cell=1.0 if not flow_sees_walker else 0.0, confirm=1))  # one rule each
    before, start, left = walk(legacy, flow_sees_walker=flow_sees_walker)
    after, _, _ = walk(robust, flow_sees_walker=flow_sees_walker)
    world = lambda odometry: np.asarray(odometry.map.points, np.float64)  # odometry frame = first scan = world
    assert on_walked_path(world(before), start, left).sum() >= 5  # the trail is there without the rules
    assert on_walked_path(world(after), start, left).sum() == 0
    assert wall_voxels(world(after)) >= 0.9 * wall_voxels(world(before)) > 50
    ground = lambda cloud: int((np.abs(cloud[:, 2] - GROUND) < 0.3).sum())
    assert ground(world(after)) >= 0.9 * ground(world(before)) > 200


def test_confirmation_keeps_once_seen_voxels_out_and_the_bookkeeping_bounded():
    """Voxels seen in one scan only never join the map (and are forgotten after the window); voxels seen in every
    scan do; unconfirmed voxels count against the cap."""
    config = MapConfig(voxel=0.5, max_voxels=3000, confirm=3, confirm_window=5, clear_cell=0.0)
    voxel_map = VoxelMap(config)
    rng = np.random.default_rng(0)
    wall = np.c_[rng.uniform(-10, 10, 2000), np.full(2000, 5.0), rng.uniform(0, 3, 2000)]
    for step in range(30):
        noise = rng.uniform(-50, 50, (2000, 3)) * [1, 1, 0.1]  # a new cloud every scan: never seen twice
        points = np.vstack([wall, noise])
        new = voxel_map.observe(points)
        voxel_map.insert(points[new], np.tile([0.0, 0.0, 1.0], (len(new), 1)), np.zeros(3))
        voxel_map.clear(np.zeros((0, 3)), np.eye(4))
        assert len(voxel_map.codes) <= config.max_voxels and voxel_map.nbytes <= config.max_bytes
        assert (voxel_map.scans - voxel_map.first[~voxel_map.confirmed] < config.confirm_window).all()
    confirmed = voxel_map.points
    assert len(confirmed) > 100 and np.all(np.abs(confirmed[:, 1] - 5.0) < 0.5)  # only the wall


def test_range_image_sees_through_free_space_only():
    """A point in front of the wall the beams hit is seen through; points on the wall, behind it, or in cells with no
    return are not; a grazing ground point is protected by its incidence."""
    directions = rays()
    hits = directions[directions[:, 1] > 0.5]
    scan = hits * (10.0 / hits[:, 1])[:, None]  # a wall at y = 10
    image = RangeImage.build(scan, np.radians(1.0))
    probe = np.array([[0.0, 5.0, 0.0], [0.0, 10.0, 0.0], [0.0, 14.0, 0.0], [0.0, -5.0, 0.0]])
    facing = np.tile([0.0, 1.0, 0.0], (4, 1))
    assert image.seen_through(probe, facing, 0.5).tolist() == [True, False, False, False]
    flat = np.array([[0.0, 9.0, -1.8]])  # on a ground plane, 9 m out: 11 deg incidence from grazing
    assert image.seen_through(flat, np.array([[0.0, 1.0, 0.0]]), 0.5)[0]
    assert not image.seen_through(flat, np.array([[0.0, 0.0, 1.0]]), 0.5)[0]


CAR = np.array([4.5, 1.8, 1.5])  # m, box size
CAR_Y, CAR_SPEED = 6.0, 3.0  # m beside the ego's path, m/s


def cast_car(ego_x: float, car_x: float) -> tuple[np.ndarray, np.ndarray]:
    """One scan (sensor frame) of the empty yard from (ego_x, 0, 0) with a car at (car_x, CAR_Y); which points lie
    on the car."""
    directions = rays()
    origin = np.array([ego_x, 0.0, 0.0])
    yard, _ = cast(ego_x, 1e3)  # the walker far outside the yard: walls and ground only
    centre = np.array([car_x, CAR_Y, GROUND + CAR[2] / 2])
    car = box_hit(origin, directions, centre - CAR / 2, centre + CAR / 2)
    distance = np.minimum(np.linalg.norm(yard, axis=1), car)
    return directions * distance[:, None], car <= distance


def in_car_spot(points: np.ndarray, car_x: float) -> np.ndarray:
    """(N,) bool: world points inside the car's box at car_x (grown by 0.2 m), 0.3 m above the ground."""
    half = CAR / 2 + 0.2
    return ((np.abs(points[:, 0] - car_x) <= half[0]) & (np.abs(points[:, 1] - CAR_Y) <= half[1])
            & (points[:, 2] > GROUND + 0.3) & (points[:, 2] <= GROUND + CAR[2] + 0.2))


def drive_car(config: OdomConfig, plan: list[tuple[float, bool]], check=None):
    """The ego drives along x; the car follows `plan`, one (car x, labelled moving) per scan: its points carry a
    dynamic probability of 1 and their own motion in the flow where labelled moving, 0 and the ego's flow alone where
    not (the segmentation missed it or it stands). `check(index, odometry)` runs after every scan."""
    odometry = make_odometry("ssf", config)
    for index, (car_x, moving) in enumerate(plan):
        points, on_car = cast_car(EGO_SPEED * PERIOD * index, car_x)
        flow = np.tile([-EGO_SPEED * PERIOD, 0.0, 0.0], (len(points), 1))
        dynamic = np.zeros(len(points), np.float32)
        if moving:
            following = plan[min(index + 1, len(plan) - 1)][0]
            flow[on_car, 0] += following - car_x
            dynamic[on_car] = 1.0
        odometry.step(OdomInput(index * 100_000_000, points, flow, dynamic))
        assert abs(odometry.pose[0, 3] - EGO_SPEED * PERIOD * index) < 0.05
        if check is not None:
            check(index, odometry)
    return odometry


def test_a_car_that_drove_in_and_stops_stays_out_of_the_map():
    """A car seen moving that stops for 4 s (the segmentation then calls it static) stays out of the published map
    while it stands (the voxels its moving points held, or their flow led into, are remembered) and after it drove
    off; without the memory of moving voxels it is confirmed within a second of stopping. The walls and the ground
    stay."""
    stop_x = 2.0
    plan = ([(stop_x - CAR_SPEED * PERIOD * (20 - i), True) for i in range(20)] + [(stop_x, False)] * 40
            + [(stop_x + CAR_SPEED * PERIOD * (i + 1), True) for i in range(20)])
    standing: dict[str, list[int]] = {"before": [], "after": []}

    def count(label):
        def check(index, odometry):
            if 30 <= index < 60:
                standing[label].append(int(in_car_spot(np.asarray(odometry.map.points), stop_x).sum()))
        return check

    before = drive_car(OdomConfig(map=MapConfig(moving_memory=0.0, miss_weight=1)), plan, count("before"))
    after = drive_car(OdomConfig(), plan, count("after"))
    assert max(standing["before"]) >= 10, standing  # the stopped car was in the map
    # a roof voxel or two at the far edge, which no beam saw while the car moved, may remain
    assert max(standing["after"]) <= max(standing["before"]) / 3, standing
    world = lambda odometry: np.asarray(odometry.map.points, np.float64)
    assert in_car_spot(world(after), stop_x).sum() == 0
    assert wall_voxels(world(after)) >= 0.9 * wall_voxels(world(before)) > 50
    ground = lambda cloud: int((np.abs(cloud[:, 2] - GROUND) < 0.3).sum())
    assert ground(world(after)) >= 0.9 * ground(world(before)) > 200


def test_a_parked_car_the_segmentation_misses_leaves_the_map_soon_after_it_drives_off():
    """A car parked from the start is rightly mapped; it then drives off unseen by the segmentation (labelled static,
    no motion in the flow). Two scans whose beams pass through its spot take its voxels out of the map; with one
    unit of evidence per scan seen through, some stay for most of a second."""
    spot = 4.0
    leave = [(spot + CAR_SPEED * PERIOD * (i + 1), False) for i in range(40)]
    gone = next(i for i, (x, _) in enumerate(leave) if x - CAR[0] / 2 > spot + CAR[0] / 2 + 1.0)  # clear of its spot
    plan = [(spot, False)] * 40 + leave[: gone + 3]
    left: dict[str, int] = {}

    def parked(label):
        def check(index, odometry):
            if index == 39:
                left[label + " parked"] = int(in_car_spot(np.asarray(odometry.map.points), spot).sum())
        return check

    before = drive_car(OdomConfig(map=MapConfig(moving_memory=0.0, miss_weight=1)), plan, parked("before"))
    after = drive_car(OdomConfig(), plan, parked("after"))
    assert left["before parked"] >= 5 and left["after parked"] >= 5  # a parked car is static: mapped
    assert in_car_spot(np.asarray(before.map.points), spot).sum() >= 2
    assert in_car_spot(np.asarray(after.map.points), spot).sum() == 0


def test_the_ground_under_a_walker_seen_moving_and_the_wall_behind_it_stay():
    """A walker labelled moving passes between the ego and the far wall: the voxels of its body are remembered, the
    ground it walks on and the wall its body hides are not (no clearing through an occluder either)."""
    config = OdomConfig()
    odometry = make_odometry("ssf", config)
    for index in range(60):
        ego, walker = EGO_SPEED * PERIOD * index, -8.0 + WALKER_SPEED * PERIOD * index
        points, on_walker = cast(ego, walker)
        flow = np.tile([-EGO_SPEED * PERIOD, 0.0, 0.0], (len(points), 1))
        flow[on_walker, 0] += WALKER_SPEED * PERIOD
        odometry.step(OdomInput(index * 100_000_000, points, flow, on_walker.astype(np.float32)))
    world = np.asarray(odometry.map.points, np.float64)
    remembered = odometry.map.holds_moving(voxel_codes(world, config.map.voxel))
    path = (np.abs(world[:, 1] - WALKER_Y) <= 1.0) & (world[:, 0] > -8.0) & (world[:, 0] < walker - 1.0)
    assert (path & (np.abs(world[:, 2] - GROUND) < 0.3)).sum() >= 10  # the walked-on ground is mapped
    assert not remembered[np.abs(world[:, 2] - GROUND) < 0.3].any()
    assert len(odometry.map.moving_codes) > 0
    legacy = make_odometry("ssf", OdomConfig(map=MapConfig(moving_memory=0.0)))
    for index in range(60):
        points, on_walker = cast(EGO_SPEED * PERIOD * index, -8.0 + WALKER_SPEED * PERIOD * index)
        flow = np.tile([-EGO_SPEED * PERIOD, 0.0, 0.0], (len(points), 1))
        flow[on_walker, 0] += WALKER_SPEED * PERIOD
        legacy.step(OdomInput(index * 100_000_000, points, flow, on_walker.astype(np.float32)))
    assert wall_voxels(world) >= 0.95 * wall_voxels(np.asarray(legacy.map.points, np.float64)) > 50
