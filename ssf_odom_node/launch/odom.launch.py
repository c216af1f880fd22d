"""ros2 launch ssf_odom_node odom.launch.py method:=ssf — odometry from /ssf/semantic_flow (or /ssf/flow + /ssf/mask)."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("method", default_value="ssf", description="ssf | flow | points"),
        DeclareLaunchArgument("input", default_value="semantic_flow", description="semantic_flow | flow_mask"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock (bag play --clock)"),
        Node(
            package="ssf_odom_node",
            executable="ssf_odom_node",
            parameters=[{
                "method": LaunchConfiguration("method"),
                "input": LaunchConfiguration("input"),
                "use_sim_time": LaunchConfiguration("use_sim_time"),
            }],
            output="screen",
        ),
    ])
