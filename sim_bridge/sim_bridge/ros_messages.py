"""Simulator state as ROS messages: scans, ground-truth flow, odometry, tf, obstacles, markers, episode result."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim_bridge.ego import EgoState
from sim_bridge.ground_truth import FlowTruth
from sim_bridge.lidar import Scan
from sim_bridge.simulator import EpisodeStatus, MeasuredMotion
from sim_bridge.agents import AgentKind, AgentStates
from ssf_common import messages
from ssf_common import pose_msgs
from ssf_common.conversions import obstacles_to_msg, plan_to_msg
from ssf_common.markers import CUBE, CYLINDER, Rgba, marker
from ssf_common.records import ObstacleKind, Obstacles, Plan
from ssf_common.pointcloud import xyz_to_cloud

WORLD_FRAME = "world"
BASE_FRAME = "base_link"
LIDAR_FRAME = "lidar"
ODOM_FRAME = "odom"

VEHICLE_COLOUR = Rgba(0.2, 0.5, 0.9, 0.8)
PEDESTRIAN_COLOUR = Rgba(0.95, 0.6, 0.1, 0.9)
AGENT_LIFETIME_S = 0.3

_OBSTACLE_KIND = {AgentKind.VEHICLE: ObstacleKind.VEHICLE, AgentKind.PEDESTRIAN: ObstacleKind.PEDESTRIAN}


def scan_cloud(scan: Scan, stamp_ns: int) -> Any:
    """/lidar/points: x, y, z, intensity, ring, time in the sensor frame (and sensor, the rig member, for a rig)."""
    extra = {} if scan.sensor is None else {"sensor": scan.sensor}
    return xyz_to_cloud(
        scan.points, messages.header(stamp_ns, LIDAR_FRAME), intensity=scan.intensity, ring=scan.ring, time=scan.time,
        **extra,
    )


def truth_cloud(scan: Scan, truth: FlowTruth, stamp_ns: int) -> Any:
    """/sim/ground_truth/flow: scan t with its exact flow, instance, class and dynamic flag."""
    return xyz_to_cloud(
        scan.points,
        messages.header(stamp_ns, LIDAR_FRAME),
        flow_x=truth.flow[:, 0],
        flow_y=truth.flow[:, 1],
        flow_z=truth.flow[:, 2],
        instance=scan.instance,
        label=scan.label,
        dynamic=truth.dynamic,
    )


def odometry(base_pose: np.ndarray, ego: EgoState, stamp_ns: int) -> Any:
    """nav_msgs/Odometry of base_link in the world frame, twist in base_link."""
    twist = messages.msg_type("geometry_msgs/msg/Twist")(
        linear=pose_msgs.vector3_msg(np.array([ego.speed, 0.0, 0.0])),
        angular=pose_msgs.vector3_msg(np.array([0.0, 0.0, ego.yaw_rate])),
    )
    return messages.msg_type("nav_msgs/msg/Odometry")(
        header=messages.header(stamp_ns, WORLD_FRAME),
        child_frame_id=BASE_FRAME,
        pose=messages.msg_type("geometry_msgs/msg/PoseWithCovariance")(
            pose=pose_msgs.pose_msg(base_pose), covariance=np.zeros(36)
        ),
        twist=messages.msg_type("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)),
    )


def vehicle_twist(measured: MeasuredMotion, stamp_ns: int) -> Any:
    """geometry_msgs/TwistStamped of base_link: the odometer's speed and yaw rate over the step ending at the stamp."""
    return messages.msg_type("geometry_msgs/msg/TwistStamped")(
        header=messages.header(stamp_ns, BASE_FRAME),
        twist=messages.msg_type("geometry_msgs/msg/Twist")(
            linear=pose_msgs.vector3_msg(np.array([measured.speed, 0.0, 0.0])),
            angular=pose_msgs.vector3_msg(np.array([0.0, 0.0, measured.yaw_rate])),
        ),
    )


def transforms(base_pose: np.ndarray, lidar_pose: np.ndarray, stamp_ns: int) -> Any:
    """/tf: world -> base_link -> lidar."""
    mount = np.linalg.inv(base_pose) @ lidar_pose
    return messages.msg_type("tf2_msgs/msg/TFMessage")(
        transforms=[
            pose_msgs.transform_stamped_msg(base_pose, stamp_ns, WORLD_FRAME, BASE_FRAME),
            pose_msgs.transform_stamped_msg(mount, stamp_ns, BASE_FRAME, LIDAR_FRAME),
        ]
    )


def obstacles(agents: AgentStates, stamp_ns: int) -> Any:
    """Every agent as ssf_interfaces/ObstacleArray in the world frame (ground truth standing in for perception)."""
    return obstacles_to_msg(agent_obstacles(agents, stamp_ns))


def agent_obstacles(agents: AgentStates, stamp_ns: int) -> Obstacles:
    """Every agent as an obstacle record in the world frame (boxes centred at half height, exact velocities)."""
    centres = agents.position.astype(np.float64).copy()
    centres[:, 2] += agents.size[:, 2] / 2
    velocities = np.zeros((len(agents), 3))
    velocities[:, :2] = agents.velocity[:, :2]
    kinds = np.array([_OBSTACLE_KIND.get(AgentKind(int(kind)), ObstacleKind.UNKNOWN) for kind in agents.kind], np.uint8)
    return Obstacles(stamp_ns, WORLD_FRAME, ids=agents.ids, kinds=kinds, centres=centres, sizes=agents.size,
                     yaws=agents.yaw, velocities=velocities, yaw_rates=agents.yaw_rate)


def markers(agents: AgentStates, stamp_ns: int) -> Any:
    """visualization_msgs/MarkerArray: a cube per vehicle, a cylinder per pedestrian (Foxglove, RViz)."""
    header = messages.header(stamp_ns, WORLD_FRAME)
    items = []
    for i in range(len(agents)):
        is_vehicle = int(agents.kind[i]) == AgentKind.VEHICLE
        centre = agents.position[i].copy()
        centre[2] += agents.size[i, 2] / 2
        pose = messages.msg_type("geometry_msgs/msg/Pose")(
            position=pose_msgs.point_msg(centre), orientation=pose_msgs.yaw_quaternion_msg(float(agents.yaw[i])))
        items.append(marker(header, "vehicles" if is_vehicle else "pedestrians", int(agents.ids[i]),
                            CUBE if is_vehicle else CYLINDER, pose=pose, scale=agents.size[i],
                            colour=VEHICLE_COLOUR if is_vehicle else PEDESTRIAN_COLOUR, lifetime_s=AGENT_LIFETIME_S))
    return messages.msg_type("visualization_msgs/msg/MarkerArray")(markers=items)


def episode_result(status: EpisodeStatus, scenario: str, seed: int, num_agents: int, stamp_ns: int) -> Any:
    """ssf_interfaces/EpisodeResult."""
    return messages.msg_type("ssf_interfaces/msg/EpisodeResult")(
        header=messages.header(stamp_ns, WORLD_FRAME),
        scenario=scenario,
        seed=seed,
        outcome=int(status.outcome),
        time=float(status.time),
        distance=float(status.distance),
        average_speed=float(status.average_speed),
        min_clearance=float(status.min_clearance) if np.isfinite(status.min_clearance) else -1.0,
        num_agents=num_agents,
    )


def route_path(waypoints: np.ndarray, start_base_pose: np.ndarray, stamp_ns: int) -> Any:
    """/sim/route: the route's world waypoints (N, 3) in the odometry frame, i.e. the frame of the ego's start pose
    (x forward, y left), as nav_msgs/Path with frame_id 'odom' (headings along the route)."""
    local = (waypoints - start_base_pose[:3, 3]) @ start_base_pose[:3, :3]
    heading = np.arctan2(np.diff(local[:, 1]), np.diff(local[:, 0]))
    heading = np.r_[heading, heading[-1:]]
    states = np.c_[local[:, :2], heading, np.zeros(len(local))]
    return plan_to_msg(Plan(stamp_ns, ODOM_FRAME, np.zeros(len(local)), states))


def clock(stamp_ns: int) -> Any:
    """rosgraph_msgs/Clock."""
    return messages.msg_type("rosgraph_msgs/msg/Clock")(clock=messages.stamp(stamp_ns))
