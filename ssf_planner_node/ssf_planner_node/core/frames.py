"""Frames around the planner: the planar ego state from an odometry pose, obstacles moved into the route's frame
with the pose at their stamp, a short history of poses to look those up, and the odometry of a pair's second scan
from the flow's ego motion."""

from __future__ import annotations

import bisect
from collections import deque
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ssf_common.geometry.kinematics import PlanarState, driven
from ssf_common.geometry.se3 import invert, yaw_matrix, yaw_of
from ssf_common.records import EgoMotion, Obstacles, OdometryEstimate
from ssf_planner_node.core.models import Command
from ssf_planner_node.core.planner import VehicleState


def carried_forward(state: VehicleState, commands: list[tuple[int, Command]], now_ns: int, max_accel: float,
                    max_decel: float) -> VehicleState:
    """The state at now_ns: `state` driven on by the commands sent since its stamp (each holds until the next one;
    the one in force at the stamp first), the speed following each command within the acceleration limits."""
    if now_ns <= state.stamp_ns:
        return state
    end = driven(PlanarState(state.x, state.y, state.yaw, state.speed),
                 [(stamp, command.linear, command.angular) for stamp, command in commands], state.stamp_ns, now_ns,
                 max_accel, max_decel)
    return VehicleState(int(now_ns), end.x, end.y, end.yaw, end.speed)


def vehicle_state(stamp_ns: int, pose: np.ndarray, speed: float) -> VehicleState:
    """The planar state of base_link at pose (odom <- base_link) moving forward at speed."""
    return VehicleState(int(stamp_ns), float(pose[0, 3]), float(pose[1, 3]), yaw_of(pose), float(speed))


def state_of(odometry: OdometryEstimate) -> VehicleState:
    """The planar state an odometry message describes (speed: its forward twist)."""
    return vehicle_state(odometry.stamp_ns, odometry.pose, float(odometry.twist[0]))


def odometry_after(odometry: OdometryEstimate, ego: EgoMotion, mount: np.ndarray) -> OdometryEstimate:
    """The odometry of the pair's second scan from the odometry of its first (stamped as the ego motion's first scan)
    and the sensor's motion over the pair (`mount`: base_link <- the ego's sensor frame): the pose the odometry node
    will refine against its map, known as soon as the flow has aligned the pair; speed and yaw rate from that step."""
    pose = odometry.pose @ mount @ invert(ego.transform) @ invert(mount)
    step = invert(odometry.pose) @ pose
    twist = np.zeros(6)
    twist[0], twist[5] = step[0, 3] / ego.dt, yaw_of(step) / ego.dt
    return replace(odometry, stamp_ns=ego.next_stamp_ns, pose=pose, twist=twist)


class PoseHistory:
    """Recent odometry poses (odom <- base_link) by stamp, for obstacles stamped in the past."""

    def __init__(self, length: int = 100) -> None:
        self._stamps: deque[int] = deque(maxlen=length)
        self._poses: deque[np.ndarray] = deque(maxlen=length)

    def add(self, stamp_ns: int, pose: np.ndarray) -> None:
        """Remember a pose (stamps going backwards start a new history)."""
        if self._stamps and stamp_ns <= self._stamps[-1]:
            self._stamps.clear()
            self._poses.clear()
        self._stamps.append(int(stamp_ns))
        self._poses.append(np.asarray(pose, dtype=np.float64))

    def at(self, stamp_ns: int, tolerance_ns: int = 60_000_000, bridge_ns: int = 1_000_000_000) -> np.ndarray | None:
        """The pose nearest to stamp_ns if one lies within the tolerance, else the pose interpolated between the two
        around it (at most `bridge_ns` apart: scans the odometry skipped), else None."""
        if not self._stamps:
            return None
        stamps = list(self._stamps)
        index = bisect.bisect_left(stamps, stamp_ns)
        nearest = min((i for i in (index - 1, index) if 0 <= i < len(stamps)), key=lambda i: abs(stamps[i] - stamp_ns))
        if abs(stamps[nearest] - stamp_ns) <= tolerance_ns:
            return self._poses[nearest]
        if 0 < index < len(stamps) and stamps[index] - stamps[index - 1] <= bridge_ns:
            share = (stamp_ns - stamps[index - 1]) / (stamps[index] - stamps[index - 1])
            return interpolated(self._poses[index - 1], self._poses[index], share)
        return None


def interpolated(before: np.ndarray, after: np.ndarray, share: float) -> np.ndarray:
    """The pose `share` (0..1) of the way from `before` to `after`: translation linearly, rotation along the shortest
    arc."""
    pose = np.eye(4)
    turn = Rotation.from_matrix(before[:3, :3].T @ after[:3, :3]).as_rotvec()
    pose[:3, :3] = before[:3, :3] @ Rotation.from_rotvec(share * turn).as_matrix()
    pose[:3, 3] = before[:3, 3] + share * (after[:3, 3] - before[:3, 3])
    return pose


def obstacles_in_route_frame(obstacles: Obstacles, route_frame: str, base_pose: np.ndarray | None,
                             sensor_mount: np.ndarray | None) -> Obstacles | None:
    """Obstacles in the route's (odometry) frame: as they are when already there; else through the odometry pose at
    their stamp (odom <- base_link) and the base_link <- sensor mount (identity for base_link itself). None when a
    transform is missing."""
    if obstacles.frame_id == route_frame:
        return obstacles
    if base_pose is None or sensor_mount is None:
        return None
    return obstacles.transformed(base_pose @ sensor_mount, route_frame)


def frame_bridge(expected: VehicleState, pose: np.ndarray, jump_m: float) -> np.ndarray | None:
    """When an odometry pose lies more than `jump_m` from where the car is expected (the last pose carried forward),
    the odometry started a new frame (a restarted odometry node starts at its first scan): the planar transform (route
    frame <- new frame) that puts the pose there; None while the pose is where it should be."""
    if jump_m <= 0 or np.hypot(pose[0, 3] - expected.x, pose[1, 3] - expected.y) <= jump_m:
        return None
    placed = np.array(pose, dtype=np.float64)
    placed[:3, :3] = yaw_matrix(expected.yaw - yaw_of(pose))[:3, :3] @ placed[:3, :3]
    placed[0, 3], placed[1, 3] = expected.x, expected.y
    return placed @ invert(pose)
