"""4x4 transforms to and from geometry_msgs (Pose, Transform, Quaternion, Point, Vector3)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ssf_common import messages


def quaternion_msg(rotation: np.ndarray) -> Any:
    """geometry_msgs/Quaternion of a 3x3 rotation."""
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return messages.msg_type("geometry_msgs/msg/Quaternion")(x=float(x), y=float(y), z=float(z), w=float(w))


def yaw_quaternion_msg(yaw: float) -> Any:
    """geometry_msgs/Quaternion of a rotation about z."""
    return messages.msg_type("geometry_msgs/msg/Quaternion")(
        x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))
    )


def point_msg(xyz: np.ndarray) -> Any:
    """geometry_msgs/Point."""
    return messages.msg_type("geometry_msgs/msg/Point")(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def vector3_msg(xyz: np.ndarray) -> Any:
    """geometry_msgs/Vector3."""
    return messages.msg_type("geometry_msgs/msg/Vector3")(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def pose_msg(matrix: np.ndarray) -> Any:
    """geometry_msgs/Pose of a 4x4 transform."""
    return messages.msg_type("geometry_msgs/msg/Pose")(
        position=point_msg(matrix[:3, 3]), orientation=quaternion_msg(matrix[:3, :3])
    )


def transform_msg(matrix: np.ndarray) -> Any:
    """geometry_msgs/Transform of a 4x4 transform."""
    return messages.msg_type("geometry_msgs/msg/Transform")(
        translation=vector3_msg(matrix[:3, 3]), rotation=quaternion_msg(matrix[:3, :3])
    )


def transform_stamped_msg(matrix: np.ndarray, stamp_ns: int, parent: str, child: str) -> Any:
    """geometry_msgs/TransformStamped: child frame expressed in parent (parent <- child)."""
    return messages.msg_type("geometry_msgs/msg/TransformStamped")(
        header=messages.header(stamp_ns, parent), child_frame_id=child, transform=transform_msg(matrix)
    )


def matrix_from_pose(pose: Any) -> np.ndarray:
    """4x4 transform of a geometry_msgs/Pose."""
    q = pose.orientation
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    matrix[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return matrix


def matrix_from_transform(transform: Any) -> np.ndarray:
    """4x4 transform of a geometry_msgs/Transform."""
    q, t = transform.rotation, transform.translation
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    matrix[:3, 3] = [t.x, t.y, t.z]
    return matrix


def mount_from_tf(msg: Any, base_frame: str, sensor_frame: str) -> np.ndarray | None:
    """base_link <- sensor from a tf2_msgs/TFMessage that carries it (None where it does not)."""
    for item in msg.transforms:
        if item.header.frame_id == base_frame and item.child_frame_id == sensor_frame:
            return matrix_from_transform(item.transform)
    return None
