"""ros2 launch ssf_bringup demo.launch.py scenario:=urban_100 — the closed loop of `ssf demo` on ROS 2 Jazzy."""

from importlib import resources
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from ssf_bringup.launcher import load_graph
from ssf_bringup.ros_launch import launch_actions


def _graph(context):
    graph = load_graph(Path(str(resources.files("ssf_bringup") / "graphs" / "demo.yaml")))
    scenario = LaunchConfiguration("scenario").perform(context)
    duration = float(LaunchConfiguration("duration").perform(context))
    nodes = [
        node.model_copy(update={"parameters": {**node.parameters, "scenario": scenario, "duration_s": duration}})
        if node.executable == "sim_bridge" else node
        for node in graph.nodes
    ]
    graph = graph.model_copy(update={"nodes": nodes})
    return launch_actions(graph, LaunchConfiguration("record_dir").perform(context) or None)


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="urban_100", description="sim_bridge scenario"),
        DeclareLaunchArgument("duration", default_value="60.0", description="seconds of simulated driving"),
        DeclareLaunchArgument("record_dir", default_value="", description="ros2 bag output folder"),
        OpaqueFunction(function=_graph),
    ])
