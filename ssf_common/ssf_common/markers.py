"""`/ssf/markers`: the perceived obstacles (boxes), their velocity arrows and the planned trajectory as
visualization_msgs/MarkerArray, so that RViz2 and Foxglove show them without plug-ins.

Each node that owns data keeps one `MarkerSet` (the fusion node its obstacles, the planner its plan) and publishes
what `MarkerSet.update` returns: the new markers, plus a DELETE for every marker of those namespaces that the
previous update had and this one has not. Markers also expire after `lifetime_s`, so that a node that stops leaves
nothing behind."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np

from ssf_common import messages, pose_msgs
from ssf_common.geometry.se3 import make_pose
from ssf_common.records import ObstacleKind, Obstacles, Plan

# visualization_msgs/Marker types and actions
ARROW, CUBE, CYLINDER, LINE_STRIP, SPHERE_LIST = 0, 1, 3, 4, 7
ADD, DELETE = 0, 2

OBSTACLES_NS = "obstacles"
VELOCITIES_NS = "obstacle_velocities"
PLAN_NS = "plan"
PLAN_STATES_NS = "plan_states"
ARROW_HORIZON_S = 1.0  # a velocity arrow ends where its obstacle will be after this long
MIN_ARROW_SPEED = 0.2  # m/s; slower obstacles get no arrow
DEFAULT_LIFETIME_S = 2.0


class Rgba(NamedTuple):
    """A colour with alpha, each in [0, 1]."""

    r: float
    g: float
    b: float
    a: float = 1.0


KIND_COLOURS = {
    ObstacleKind.VEHICLE: Rgba(0.95, 0.25, 0.2, 0.55),
    ObstacleKind.PEDESTRIAN: Rgba(0.85, 0.3, 0.85, 0.65),
    ObstacleKind.UNKNOWN: Rgba(0.95, 0.75, 0.1, 0.55),
}
ARROW_COLOUR = Rgba(1.0, 0.9, 0.1, 1.0)
PLAN_COLOUR = Rgba(0.1, 0.9, 0.35, 1.0)


def marker(header: Any, ns: str, marker_id: int, kind: int, *, pose: np.ndarray | Any | None = None,
           scale: Sequence[float] = (1.0, 1.0, 1.0), colour: Rgba = Rgba(1.0, 1.0, 1.0),
           points: np.ndarray | None = None, lifetime_s: float = DEFAULT_LIFETIME_S, action: int = ADD) -> Any:
    """One visualization_msgs/Marker with every field ROS 2 Jazzy defines (pose: 4x4, a geometry_msgs/Pose as it is,
    identity when None)."""
    make = messages.msg_type
    sec, nanosec = divmod(int(round(lifetime_s * 1e9)), 1_000_000_000)
    point_list = [pose_msgs.point_msg(p) for p in np.asarray(points if points is not None else np.zeros((0, 3)))]
    return make("visualization_msgs/msg/Marker")(
        header=header, ns=ns, id=int(marker_id), type=kind, action=action,
        pose=pose if pose is not None and not isinstance(pose, np.ndarray) else pose_msgs.pose_msg(
            np.eye(4) if pose is None else pose),
        scale=pose_msgs.vector3_msg(np.asarray(scale, dtype=np.float64)),
        color=make("std_msgs/msg/ColorRGBA")(r=colour.r, g=colour.g, b=colour.b, a=colour.a),
        lifetime=make("builtin_interfaces/msg/Duration")(sec=sec, nanosec=nanosec),
        frame_locked=False, points=point_list, colors=[], texture_resource="",
        texture=make("sensor_msgs/msg/CompressedImage")(header=messages.header(0, ""), format="",
                                                        data=np.zeros(0, np.uint8)),
        uv_coordinates=[], text="", mesh_resource="",
        mesh_file=make("visualization_msgs/msg/MeshFile")(filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def obstacle_markers(obstacles: Obstacles, lifetime_s: float = DEFAULT_LIFETIME_S) -> list[Any]:
    """A box per obstacle (coloured by kind) and an arrow per moving one, to where it will be in ARROW_HORIZON_S."""
    header = messages.header(obstacles.stamp_ns, obstacles.frame_id)
    boxes = [
        marker(header, OBSTACLES_NS, i, CUBE, pose=_yaw_pose(obstacles.centres[i], obstacles.yaws[i]),
               scale=np.maximum(obstacles.sizes[i], 0.05), lifetime_s=lifetime_s,
               colour=KIND_COLOURS.get(ObstacleKind(int(obstacles.kinds[i])), KIND_COLOURS[ObstacleKind.UNKNOWN]))
        for i in range(len(obstacles))
    ]
    speeds = np.linalg.norm(obstacles.velocities, axis=1)
    arrows = [
        marker(header, VELOCITIES_NS, i, ARROW, scale=(0.15, 0.4, 0.4), colour=ARROW_COLOUR, lifetime_s=lifetime_s,
               points=np.stack([obstacles.centres[i], obstacles.centres[i] + ARROW_HORIZON_S * obstacles.velocities[i]]))
        for i in np.flatnonzero(speeds >= MIN_ARROW_SPEED)
    ]
    return boxes + arrows


def plan_markers(plan: Plan, lifetime_s: float = DEFAULT_LIFETIME_S, height: float = 0.2) -> list[Any]:
    """The planned positions as a line and as spheres, a little above the ground."""
    if len(plan) == 0:
        return []
    header = messages.header(plan.stamp_ns, plan.frame_id)
    xyz = np.column_stack([plan.states[:, :2], np.full(len(plan), height)])
    return [
        marker(header, PLAN_NS, 0, LINE_STRIP, scale=(0.25, 0.0, 0.0), colour=PLAN_COLOUR, points=xyz,
               lifetime_s=lifetime_s),
        marker(header, PLAN_STATES_NS, 0, SPHERE_LIST, scale=(0.4, 0.4, 0.4), colour=PLAN_COLOUR, points=xyz,
               lifetime_s=lifetime_s),
    ]


class MarkerSet:
    """The markers one publisher keeps on a topic: each update replaces what it showed before in its namespaces."""

    def __init__(self) -> None:
        self._shown: dict[str, set[int]] = {}
        self._header: dict[str, Any] = {}

    def update(self, markers: Iterable[Any], namespaces: Iterable[str]) -> Any:
        """A MarkerArray of `markers` plus a DELETE for each marker of `namespaces` shown before and gone now."""
        markers = list(markers)
        now: dict[str, set[int]] = {ns: set() for ns in namespaces}
        for item in markers:
            now.setdefault(item.ns, set()).add(item.id)
            self._header[item.ns] = item.header
        deletions = [
            marker(self._header[ns], ns, marker_id, CUBE, action=DELETE)
            for ns, ids in now.items() for marker_id in sorted(self._shown.get(ns, set()) - ids)
        ]
        self._shown.update(now)
        return messages.msg_type("visualization_msgs/msg/MarkerArray")(markers=deletions + markers)

    def obstacles(self, obstacles: Obstacles, lifetime_s: float = DEFAULT_LIFETIME_S) -> Any:
        """The MarkerArray that shows these obstacles instead of the previous ones."""
        return self.update(obstacle_markers(obstacles, lifetime_s), (OBSTACLES_NS, VELOCITIES_NS))

    def plan(self, plan: Plan, lifetime_s: float = DEFAULT_LIFETIME_S) -> Any:
        """The MarkerArray that shows this plan instead of the previous one."""
        return self.update(plan_markers(plan, lifetime_s), (PLAN_NS, PLAN_STATES_NS))


def _yaw_pose(centre: np.ndarray, yaw: float) -> np.ndarray:
    return make_pose(*(float(v) for v in centre), yaw=float(yaw))
