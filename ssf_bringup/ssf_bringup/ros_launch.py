"""Graph files as ROS 2 launch descriptions, for `ros2 launch` on a Jazzy install (launch_ros needed)."""

from __future__ import annotations

from typing import Any

from ssf_bringup.launcher import GraphSpec, NodeSpec, _console_script

def package_of(executable: str) -> str:
    """The ament package that installs an executable (`pkg/executable`, or the package of its console script)."""
    if "/" in executable:
        return executable.split("/", 1)[0]
    module, _ = _console_script(executable)
    return module.split(".", 1)[0]


def launch_actions(graph: GraphSpec, record_dir: str | None = None) -> list[Any]:
    """launch_ros Node actions for the graph's nodes; `ssf record` becomes `ros2 bag record` (MCAP, every topic, in
    simulated time when the graph's recorder is)."""
    from launch.actions import ExecuteProcess
    from launch_ros.actions import Node

    actions: list[Any] = []
    for spec in graph.nodes:
        if spec.executable == "ssf":
            if spec.arguments[:1] == ["record"]:
                command = ["ros2", "bag", "record", "--all", "--storage", "mcap"]
                command += ["--use-sim-time"] if "--use-sim-time" in spec.arguments else []  # log times on /clock
                actions.append(ExecuteProcess(cmd=command + (["-o", record_dir] if record_dir else []), output="screen"))
            continue
        actions.append(_node_action(Node, spec, graph.global_parameters))
    return actions


def _node_action(node_class: Any, spec: NodeSpec, global_parameters: dict[str, Any]) -> Any:
    parameters: list[Any] = [{**global_parameters, **spec.parameters}]
    if spec.params_file:
        parameters.insert(0, spec.params_file)
    return node_class(
        package=package_of(spec.executable),
        executable=spec.executable.split("/")[-1],
        name=spec.name or spec.executable.split("/")[-1],
        parameters=parameters,
        remappings=list(spec.remappings.items()),
        arguments=list(spec.arguments),
        respawn=spec.respawn,
        prefix=f"nice -n {spec.nice}" if spec.nice else None,
        output="screen",
    )
