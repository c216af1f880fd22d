"""Node executables start, join the graph and stop cleanly; `ssf launch` supervises and leaves no orphans."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml

from ssf_bringup.launcher import command_line, load_graph
from ssf_common.middleware import Node
from ssf_common.errors import ConfigError
from support import wait_until

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
    from ssf_bringup.launcher import NodeSpec

    return NodeSpec(executable=executable)


@pytest.mark.parametrize("executable", sorted(SHELL_NODES))
def test_each_executable_joins_the_graph_and_stops_on_sigint(executable):
    topic, type_name = SHELL_NODES[executable]
    process = start_node(executable)
    lines: list[str] = []
    started = threading.Event()

    def read() -> None:  # the node subscribes while it is built and says "started" after: wait for both
        for line in process.stdout:
            lines.append(line)
            if "started (dds backend)" in line:
                started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    probe = Node("probe")
    try:
        publisher = probe.create_publisher(type_name, topic)
        assert wait_until(lambda: publisher.get_subscription_count() == 1, timeout_s=30), f"{executable} never subscribed"
        assert started.wait(timeout=30), "".join(lines)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=20)
        reader.join(timeout=5)
        output = "".join(lines)
        assert process.returncode == 0, output
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


def write_graph(tmp_path: Path, nodes: list[dict], **graph) -> Path:
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": nodes, "stop_timeout_s": 5.0, **graph}))
    return path


class Output:
    """Collects a process's output lines on a thread, so a test waits on what was said, not on readline()."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(process.stdout,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    def has(self, fragment: str) -> bool:
        return any(fragment in line for line in list(self.lines))

    def text(self) -> str:
        self._thread.join(timeout=30)
        return "".join(self.lines)


def launch(graph: Path, *args: str) -> tuple[subprocess.Popen, Output]:
    process = subprocess.Popen(
        [sys.executable, "-P", "-m", "ssf_bringup.cli", "launch", str(graph), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    return process, Output(process)


def damaged_bag(tmp_path: Path) -> Path:
    """An MCAP file cut in half: `ssf bag info` reads what it can and exits 1."""
    from ssf_common import messages
    from ssf_common.bags.writer import BagWriter, BagWriterConfig

    string = messages.msg_type("std_msgs/msg/String")
    with BagWriter(tmp_path / "bag", BagWriterConfig(chunk_bytes=1024)) as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(200):
            writer.write("/chatter", messages.serialize(string(data=f"message {i}")), 1000 + i)
    (path,) = (tmp_path / "bag").glob("*.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    return cut


def test_launch_restarts_crashes_not_configuration_errors_and_exits_non_zero(tmp_path):
    graph = write_graph(
        tmp_path,
        [
            {"executable": "ssf_seg_node", "name": "seg", "parameters": {"report_period_s": 0.5}},
            {"executable": "ssf", "name": "crasher", "ros_args": False, "max_restarts": 1,
             "arguments": ["bag", "info", str(damaged_bag(tmp_path))]},
            {"executable": "ssf_planner_node", "name": "misconfigured", "parameters": {"report_period_s": "never"}},
        ],
    )
    launcher, output = launch(graph)
    try:
        assert wait_until(
            lambda: output.has("[crasher] exited with code 1; not restarted")
            and output.has("[misconfigured] exited with code 2 (a configuration error); not restarted")
            and output.has("segmented 0 flows"),
            timeout_s=90,
        ), "".join(output.lines)
    finally:
        launcher.send_signal(signal.SIGINT)
        launcher.wait(timeout=60)
    text = output.text()
    assert launcher.returncode == 1, text
    assert "[crasher] exited with code 1; restart 1/1" in text
    assert "[misconfigured] exited with code 2 (a configuration error); restart" not in text
    assert re.search(r"\[seg\] \[INFO\] .*\[seg\]: segmented 0 flows", text)
    assert "[launch] crasher exited with code 1" in text
    assert "[launch] misconfigured exited with code 2 (a configuration error)" in text
    assert "[launch] seg" not in text  # it stopped cleanly
    pids = [int(pid) for pid in re.findall(r"started \(pid (\d+)\)", text)]
    assert len(pids) == 4  # seg, crasher twice, misconfigured once
    assert not any(alive(pid) for pid in pids)


def test_a_finished_required_node_s_last_messages_are_recorded(tmp_path):
    """The graph ends when the required player ends, but the recorder first takes in its last message (drain_s)."""
    from ssf_common import messages
    from ssf_common.bags.reader import open_bag
    from ssf_common.bags.writer import BagWriter

    string = messages.msg_type("std_msgs/msg/String")
    with BagWriter(tmp_path / "played") as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(20):
            writer.write("/chatter", messages.serialize(string(data=f"message {i}")), 1_000_000_000 + i * 10_000_000)
    graph = write_graph(
        tmp_path,
        [
            {"executable": "ssf", "name": "recorder", "ros_args": False,
             "arguments": ["record", "-o", str(tmp_path / "recorded"), "/chatter"]},
            {"executable": "ssf", "name": "player", "ros_args": False, "required": True,
             "arguments": ["bag", "play", str(tmp_path / "played"), "--delay", "6"]},
        ],
        drain_s=2.0,
    )
    launcher, output = launch(graph)
    launcher.wait(timeout=120)
    text = output.text()
    assert launcher.returncode == 0, text
    with open_bag(tmp_path / "recorded") as bag:
        recorded = [bag.decode(m).data for m in bag.messages(["/chatter"])]
    assert recorded[-1] == "message 19", text
    assert recorded == [f"message {i}" for i in range(20)]


def python_started(pid: int) -> bool:
    """Whether the interpreter in `pid` runs Python code yet (it has installed its SIGINT handler)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    caught = int(re.search(r"SigCgt:\s*([0-9a-f]+)", status).group(1), 16)
    return bool(caught & (1 << (signal.SIGINT - 1)))


def test_ctrl_c_right_after_start_stops_every_node_without_a_traceback(tmp_path):
    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node", "name": "seg"}, {"executable": "ssf_odom_node", "name": "odom"}])
    launcher, output = launch(graph)
    assert wait_until(lambda: output.has("[odom] started (pid"), timeout_s=60)
    pids = [int(pid) for pid in re.findall(r"started \(pid (\d+)\)", "".join(output.lines))]
    assert wait_until(lambda: all(python_started(pid) for pid in pids), timeout_s=30)
    launcher.send_signal(signal.SIGINT)  # the nodes are importing their packages: no node has started yet
    assert not output.has("started (dds backend)")
    launcher.wait(timeout=60)
    text = output.text()
    assert launcher.returncode == 0, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text


def test_a_node_runs_at_the_niceness_its_graph_gives_it(tmp_path):
    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node", "name": "seg"},
                                   {"executable": "ssf_odom_node", "name": "odom", "nice": 7}])
    launcher, output = launch(graph)
    try:
        assert wait_until(lambda: len(re.findall(r"started \(pid (\d+)\)", "".join(output.lines))) == 2, timeout_s=30)
        started = dict(re.findall(r"\[(\w+)\] started \(pid (\d+)\)", "".join(output.lines)))
        base = os.getpriority(os.PRIO_PROCESS, launcher.pid)
        assert os.getpriority(os.PRIO_PROCESS, int(started["odom"])) == min(base + 7, 19)
        assert os.getpriority(os.PRIO_PROCESS, int(started["seg"])) == base
    finally:
        launcher.send_signal(signal.SIGINT)
        launcher.wait(timeout=60)


def test_killed_launcher_leaves_no_orphans(tmp_path):
    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node", "name": "seg"}, {"executable": "ssf_odom_node", "name": "odom"}])
    launcher, output = launch(graph)
    assert wait_until(lambda: len(re.findall(r"started \(pid (\d+)\)", "".join(output.lines))) == 2, timeout_s=30)
    pids = [int(pid) for pid in re.findall(r"started \(pid (\d+)\)", "".join(output.lines))]
    os.kill(launcher.pid, signal.SIGKILL)
    launcher.wait(timeout=10)
    assert wait_until(lambda: not any(alive(pid) for pid in pids), timeout_s=20)


@pytest.mark.parametrize("duration", ["-1", "0", "nan", "inf"])
def test_launch_duration_must_be_a_positive_number(tmp_path, capsys, duration):
    from ssf_bringup.cli import main

    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node"}])
    assert main(["launch", str(graph), "--duration", duration]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: --duration must be")


def test_launch_param_overrides_use_the_one_syntax(tmp_path, capsys):
    from ssf_bringup.cli import main

    graph = write_graph(tmp_path, [{"executable": "ssf_seg_node"}])
    assert load_graph(graph, {"report_period_s": 2.0}).global_parameters == {"report_period_s": 2.0}
    assert main(["launch", str(graph), "-p", "report_period_s:=[1,"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: -p report_period_s: not valid YAML")


def test_nested_graph_parameters_reach_the_node_as_dotted_names(tmp_path):
    from pydantic import Field

    from ssf_common.config import Section

    class Lidar(Section):
        rows: int = Field(64, gt=0)
        range_m: float = 100.0

    class Sensor(Section):
        lidar: Lidar = Lidar()
        frame_id: str = "lidar"

    graph = load_graph(write_graph(
        tmp_path,
        [{"executable": "ssf_seg_node", "parameters": {"lidar": {"rows": 32}, "frame_id": "it's: here"}}],
        global_parameters={"lidar": {"range_m": 1e30, "rows": 8}},
    ))
    argv = command_line(graph.nodes[0], graph.global_parameters)
    ros_args = argv[argv.index("--ros-args"):]
    assert ros_args[ros_args.index("lidar.rows:=32") - 1] == "-p"
    node = Node("configured", argv=ros_args)
    try:
        config = node.declare_config(Sensor)
    finally:
        node.destroy_node()
    assert config == Sensor(lidar=Lidar(rows=32, range_m=1e30), frame_id="it's: here")


@pytest.mark.parametrize(
    ("parameters", "fragment"),
    [
        ({"rate": float("nan")}, "parameter 'rate' must be a finite number"),
        ({"points": [{"x": 1}]}, "parameter 'points': {'x': 1} is not a parameter value"),
        ({"empty": None}, "parameter 'empty': None is not a parameter value"),
        ({"bad name": 1}, "is not a parameter name"),
    ],
)
def test_graph_parameters_no_node_can_take_are_refused_with_the_file_and_name(tmp_path, parameters, fragment):
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": [{"executable": "ssf_seg_node", "parameters": parameters}]}))
    with pytest.raises(ConfigError) as caught:
        load_graph(path)
    assert fragment in str(caught.value) and "graph.yaml" in str(caught.value)


@pytest.mark.parametrize(
    "content, message",
    [
        ("nodes: []", "nodes"),
        ("nodes:\n  - name: x\n", "executable"),
        ("nodes:\n  - executable: ssf_seg_node\n    max_restarts: -1\n", "max_restarts"),
        ("nodes:\n  - executable: ssf_seg_node\ndrain_s: -1\n", "drain_s"),
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
        [sys.executable, "-P", "-m", "ssf_bringup.cli", "launch", str(write_graph(tmp_path, [{"executable": "no_such_node"}]))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "no executable named 'no_such_node'" in result.stderr and "Traceback" not in result.stderr
