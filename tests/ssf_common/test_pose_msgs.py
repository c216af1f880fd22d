"""Pose and transform messages round-trip with 4x4 matrices."""

import numpy as np
from scipy.spatial.transform import Rotation

from ssf_common import messages
from ssf_common.geometry.se3 import yaw_of
from ssf_common import pose_msgs


def test_pose_round_trip_through_cdr():
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("ZYX", [0.7, -0.1, 0.05]).as_matrix()
    matrix[:3, 3] = [12.5, -3.25, 0.8]
    raw = messages.serialize(pose_msgs.pose_msg(matrix), "geometry_msgs/msg/Pose")
    back = pose_msgs.matrix_from_pose(messages.deserialize(raw, "geometry_msgs/msg/Pose"))
    np.testing.assert_allclose(back, matrix, atol=1e-12)
    assert abs(yaw_of(back) - 0.7) < 1e-12


def test_yaw_quaternion_matches_the_general_conversion():
    for yaw in (-3.0, -0.5, 0.0, 1.2, 3.1):
        matrix = np.eye(4)
        matrix[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
        a, b = pose_msgs.yaw_quaternion_msg(yaw), pose_msgs.quaternion_msg(matrix[:3, :3])
        qa, qb = np.array([a.x, a.y, a.z, a.w]), np.array([b.x, b.y, b.z, b.w])
        assert min(np.abs(qa - qb).max(), np.abs(qa + qb).max()) < 1e-12


def test_transform_stamped_names_parent_and_child():
    msg = pose_msgs.transform_stamped_msg(np.eye(4), 1_500_000_000, "map", "base_link")
    assert msg.header.frame_id == "map" and msg.child_frame_id == "base_link"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
