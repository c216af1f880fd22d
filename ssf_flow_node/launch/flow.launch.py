"""ros2 launch ssf_flow_node flow.launch.py estimator:=rigid — scene flow on a live or replayed /lidar/points."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("estimator", default_value="rigid", description="rigid | asf | ego | zero"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock (bag play --clock)"),
        Node(
            package="ssf_flow_node",
            executable="ssf_flow_node",
            parameters=[{
                "estimator": LaunchConfiguration("estimator"),
                "use_sim_time": LaunchConfiguration("use_sim_time"),
            }],
            output="screen",
        ),
    ])
