"""`/ssf/markers`: obstacle boxes coloured by kind, velocity arrows to where each obstacle will be, the plan, and
markers that vanish when their obstacle does."""

from __future__ import annotations

import numpy as np

from ssf_common import markers, messages
from ssf_common.geometry.se3 import yaw_of
from ssf_common.pose_msgs import matrix_from_pose
from ssf_common.records import ObstacleKind, Obstacles, Plan


def obstacles(count: int = 3) -> Obstacles:
    rng = np.random.default_rng(count)
    velocities = np.zeros((count, 3))
    velocities[:-1, :2] = rng.uniform(1.0, 5.0, (count - 1, 2))  # the last one stands still
    kinds = [ObstacleKind.VEHICLE, ObstacleKind.PEDESTRIAN, ObstacleKind.UNKNOWN][:count] + [1] * max(count - 3, 0)
    return Obstacles(7_000_000_000, "lidar", ids=np.arange(count) + 10, kinds=kinds,
                     centres=rng.uniform(-20, 20, (count, 3)), sizes=rng.uniform(0.5, 5, (count, 3)),
                     yaws=rng.uniform(-3, 3, count), velocities=velocities)


def by_ns(array) -> dict[str, list]:
    found: dict[str, list] = {}
    for item in array.markers:
        found.setdefault(item.ns, []).append(item)
    return found


def test_boxes_and_arrows_carry_the_obstacles():
    seen = obstacles()
    array = markers.MarkerSet().obstacles(seen, lifetime_s=1.5)
    groups = by_ns(array)
    boxes, arrows = groups[markers.OBSTACLES_NS], groups[markers.VELOCITIES_NS]
    assert len(boxes) == 3 and len(arrows) == 2  # the obstacle standing still has no arrow
    for i, box in enumerate(boxes):
        assert box.type == markers.CUBE and box.action == markers.ADD and box.header.frame_id == "lidar"
        assert messages.stamp_ns(box.header.stamp) == seen.stamp_ns
        pose = matrix_from_pose(box.pose)
        np.testing.assert_allclose(pose[:3, 3], seen.centres[i])
        assert abs(np.angle(np.exp(1j * (yaw_of(pose) - seen.yaws[i])))) < 1e-9
        np.testing.assert_allclose([box.scale.x, box.scale.y, box.scale.z], seen.sizes[i])
        colour = markers.KIND_COLOURS[ObstacleKind(int(seen.kinds[i]))]
        assert (box.color.r, box.color.g, box.color.b) == (colour.r, colour.g, colour.b)
        assert (box.lifetime.sec, box.lifetime.nanosec) == (1, 500_000_000)
    for i, arrow in enumerate(arrows):
        start, end = ([p.x, p.y, p.z] for p in arrow.points)
        np.testing.assert_allclose(start, seen.centres[i])
        np.testing.assert_allclose(end, seen.centres[i] + markers.ARROW_HORIZON_S * seen.velocities[i])


def test_vanished_obstacles_are_deleted_and_other_namespaces_kept():
    marker_set = markers.MarkerSet()
    marker_set.obstacles(obstacles(3))
    plan = Plan(1, "odom", np.arange(4) * 0.2, np.column_stack([np.arange(4.0), np.zeros(4), np.zeros(4), np.ones(4)]))
    marker_set.plan(plan)
    array = marker_set.obstacles(obstacles(3).take(np.array([0])))
    deleted = sorted((m.ns, m.id) for m in array.markers if m.action == markers.DELETE)
    assert deleted == sorted([(markers.OBSTACLES_NS, 1), (markers.OBSTACLES_NS, 2), (markers.VELOCITIES_NS, 1)])
    assert [m.ns for m in array.markers if m.action == markers.ADD] == [markers.OBSTACLES_NS, markers.VELOCITIES_NS]
    assert not [m for m in marker_set.obstacles(obstacles(3).take(np.array([0]))).markers
                if m.action == markers.DELETE]  # nothing new vanished
    emptied = marker_set.plan(Plan(2, "odom", np.zeros(0), np.zeros((0, 4))))
    assert sorted((m.ns, m.action) for m in emptied.markers) == [(markers.PLAN_NS, markers.DELETE),
                                                                 (markers.PLAN_STATES_NS, markers.DELETE)]


def test_plan_markers_follow_the_plan_and_survive_cdr():
    states = np.column_stack([np.linspace(0, 10, 6), np.linspace(0, 2, 6), np.zeros(6), np.full(6, 5.0)])
    array = markers.MarkerSet().plan(Plan(3_000_000_000, "odom", np.arange(6) * 0.2, states))
    back = messages.deserialize(messages.serialize(array), "visualization_msgs/msg/MarkerArray")
    line, spheres = back.markers
    assert (line.type, spheres.type) == (markers.LINE_STRIP, markers.SPHERE_LIST)
    assert line.header.frame_id == "odom" and messages.stamp_ns(line.header.stamp) == 3_000_000_000
    np.testing.assert_allclose([[p.x, p.y] for p in line.points], states[:, :2])
    np.testing.assert_allclose([[p.x, p.y] for p in spheres.points], states[:, :2])
