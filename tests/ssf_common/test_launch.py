"""Node executables start, join the graph and stop cleanly; `ssf launch` supervises and leaves no orphans."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from ssf_common.launch import command_line, load_graph
from ssf_common.middleware import Node
from ssf_common.errors import ConfigError

# executable -> (input topic it subscribes to, its type)
SHELL_NODES = {
    "ssf_seg_node": ("/ssf/flow", "sensor_msgs/msg/PointCloud2"),
    "ssf_fusion_node": ("/ssf/mask", "sensor_msgs/msg/PointCloud2"),
    "ssf_odom_node": ("/ssf/semantic_flow", "sensor_msgs/msg/PointCloud2"),
    "ssf_planner_node": ("/ssf/obstacles", "ssf_interfaces/msg/ObstacleArray"),
}


def alive(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "State:\tZ" not in status


def start_node(executable: str, *ros_args: str) -> subprocess.Popen:
    argv = command_line(load_node_spec(executable), {})
    if ros_args:
        argv += ["--ros-args", *ros_args]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def load_node_spec(executable: str):
    from ssf_common.launch import NodeSpec

    return NodeSpec(executable=executable)


@pytest.mark.parametrize("executable", sorted(SHELL_NODES))
def test_each_executable_joins_the_graph_and_stops_on_sigint(executable):
    topic, type_name = SHELL_NODES[executable]
    process = start_node(executable)
    probe = Node("probe")
    try:
        publisher = probe.create_publisher(type_name, topic)
        deadline = time.monotonic() + 30
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert publisher.get_subscription_count() == 1, f"{executable} never subscribed to {topic}"
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=20)
        assert process.returncode == 0, output
        assert "started (dds backend)" in output
        assert "Traceback" not in output
    finally:
        if process.poll() is None:
            process.kill()
        probe.destroy_node()


def test_a_bad_parameter_exits_with_one_line():
    process = start_node("ssf_odom_node", "-p", "report_period_s:=soon")
    output, _ = process.communicate(timeout=30)
    assert process.returncode == 2
    assert "report_period_s" in output and "Traceback" not in output


def write_graph(tmp_path: Path, nodes: list[dict]) -> Path:
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": nodes, "stop_timeout_s": 5.0}))
    return path


def test_launch_prefixes_restarts_and_stops_everything(tmp_path):
    graph = write_graph(
        tmp_path,
        [
            {"executable": "ssf_seg_node", "name": "seg", "parameters": {"report_period_s": 0.5}},
            {"executable": "ssf_odom_node", "name": "odom"},
            {"executable": "ssf_planner_node", "name": "crasher", "parameters": {"report_period_s": "never"}, "max_restarts": 1},
        ],
    )
    launcher = subprocess.Popen(
        [sys.executable, "-P", "-m", "ssf_common.cli", "launch", str(graph)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    deadline = time.monotonic() + 60
    assert launcher.stdout is not None
    while time.monotonic() < deadline:
        line = launcher.stdout.readline()
        lines.append(line)
        if "[seg]" in line and "segmented 0 flows" in line and any("not restarted" in l for l in lines):
            break
    launcher.send_signal(signal.SIGINT)
    rest, _ = launcher.communicate(timeout=30)
    output = "".join(lines) + rest
    assert launcher.returncode == 0, output
    assert "[crasher] exited with code 2; restart 1/1" in output
    assert "[crasher] exited with code 2; not restarted" in output
    assert re.search(r"\[seg\] \[INFO\] .*\[seg\]: segmented 0 flows", output)
    pids = [int(pid) for pid in re.findall(r"started \(pid (\d+)\)", output)]
    assert len(pids) == 4  # seg, odom, crasher twice
    assert not any(alive(pid) for pid in pids)


def test_killed_launcher_leaves_no_orphans(tmp_path):
    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node", "name": "seg"}, {"executable": "ssf_odom_node", "name": "odom"}])
    launcher = subprocess.Popen(
        [sys.executable, "-P", "-m", "ssf_common.cli", "launch", str(graph)], stdout=subprocess.PIPE, text=True
    )
    assert launcher.stdout is not None
    pids: list[int] = []
    deadline = time.monotonic() + 30
    while len(pids) < 2 and time.monotonic() < deadline:
        match = re.search(r"started \(pid (\d+)\)", launcher.stdout.readline())
        if match:
            pids.append(int(match.group(1)))
    os.kill(launcher.pid, signal.SIGKILL)
    launcher.wait(timeout=10)
    deadline = time.monotonic() + 20
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert len(pids) == 2 and not any(alive(pid) for pid in pids)


@pytest.mark.parametrize(
    "content, message",
    [
        ("nodes: []", "nodes"),
        ("nodes:\n  - name: x\n", "executable"),
        ("nodes:\n  - executable: ssf_seg_node\n    max_restarts: -1\n", "max_restarts"),
        ("nodes: [unclosed", "not valid YAML"),
    ],
)
def test_bad_graph_files_name_the_problem(tmp_path, content, message):
    path = tmp_path / "graph.yaml"
    path.write_text(content)
    with pytest.raises(ConfigError, match=message):
        load_graph(path)


def test_unknown_executable_is_a_clear_error(tmp_path):
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_common.cli", "launch", str(write_graph(tmp_path, [{"executable": "no_such_node"}]))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "no executable named 'no_such_node'" in result.stderr and "Traceback" not in result.stderr
