"""`ssf demo`, the README's first command: a short run of the shipped graph, and honest failure when a part dies."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ssf_common import demo, messages
from ssf_common.bags.reader import open_bag
from ssf_common.cli import main

DURATION_S = 3.0
STEPS = int(DURATION_S * 10)  # the scenario's dt is 0.1 s


def strict_loads(text: str):
    return json.loads(text, parse_constant=lambda name: pytest.fail(f"non-standard JSON constant {name}"))


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    out = tmp_path_factory.mktemp("demo") / "run"
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_common.cli", "demo", "--duration", str(DURATION_S), "--out", str(out),
         "--video", str(out.parent / "episode.gif"), "--foxglove", "0"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    return result, out


def test_demo_exits_zero_and_prints_where_everything_is(demo_run):
    result, out = demo_run
    assert result.returncode == 0, result.stderr[-4000:]
    assert "Traceback" not in result.stderr
    printed = strict_loads(result.stdout)
    assert printed["recording"] == str(out / "recording") and printed["picture"] == str(out / "episode.png")
    episode = strict_loads((out / "episode.json").read_text())
    assert printed["episode"] == episode
    assert episode["scenario"] == "urban_100" and episode["agents"] == 100 and episode["time"] == DURATION_S
    assert episode["outcome"] == "running" and episode["distance"] > 1.0
    assert (out / "episode.png").read_bytes()[:4] == b"\x89PNG"
    assert "sim_bridge" in (out / "graph.yaml").read_text()


def test_demo_serves_the_graph_live_and_animates_the_episode(demo_run):
    from PIL import Image

    result, out = demo_run
    assert result.returncode == 0, result.stderr[-4000:]
    assert "[viewer] view: Foxglove WebSocket server on ws://127.0.0.1:" in result.stderr  # loopback by default
    assert strict_loads(result.stdout)["video"] == str(out.parent / "episode.gif")
    with open_bag(out / "recording") as bag:
        scans = bag.topics["/lidar/points"].message_count
    with Image.open(out.parent / "episode.gif") as gif:
        assert scans - 3 <= gif.n_frames <= scans  # a frame per recorded scan placed by a true pose


def test_demo_recording_holds_the_closed_loop(demo_run):
    _, out = demo_run
    with open_bag(out / "recording") as bag:
        assert not bag.info.damage
        counts = {name: topic.message_count for name, topic in bag.topics.items()}
        assert all(counts.get(name, 0) > 0 for name in demo.RECORDED_TOPICS), counts
        scans = [messages.stamp_ns(bag.decode(m).header.stamp) for m in bag.messages(["/lidar/points"])]
        episode = [bag.decode(m) for m in bag.messages(["/sim/episode"])]
        flow = [bag.decode(m) for m in bag.messages(["/ssf/flow"])]
        semantic = [bag.decode(m) for m in bag.messages(["/ssf/semantic_flow"])]
        commands = [bag.decode(m) for m in bag.messages(["/cmd_vel"])]
        truth = [bag.decode(m) for m in bag.messages(["/sim/ground_truth/odom"])]
        odometry = [bag.decode(m) for m in bag.messages(["/odom"])]
    assert scans == sorted(set(scans)) and all(stamp % 100_000_000 == 0 for stamp in scans)
    # the whole loop closed: each stage answered most scans, and the planner's commands moved the car
    assert len(semantic) >= STEPS // 2 and len(odometry) >= STEPS // 2 and len(commands) >= STEPS // 2
    assert max(command.linear.x for command in commands) > 1.0
    start, end = truth[0].pose.pose.position, truth[-1].pose.pose.position
    driven = ((end.x - start.x) ** 2 + (end.y - start.y) ** 2) ** 0.5
    assert driven > 1.0
    last = odometry[-1].pose.pose.position  # odometry starts at the first scan: it measures the distance driven
    assert abs((last.x ** 2 + last.y ** 2) ** 0.5 - driven) < 0.5 * driven
    assert scans[-1] == STEPS * 100_000_000
    assert episode[-1].scenario == "urban_100" and abs(episode[-1].time - DURATION_S) < 1e-9
    assert {messages.stamp_ns(f.header.stamp) for f in flow} <= set(scans)  # flow answers recorded scans
    assert all({"flow_x", "flow_y", "flow_z"} <= {field.name for field in f.fields} for f in flow)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--duration", "-1"], "--duration must be above 0"),
        (["--duration", "inf"], "--duration must be a finite number"),
        (["--seed", "-7"], "--seed must be an integer from 0 to 4294967295"),
        (["--scenario", "nope"], "unknown scenario 'nope'"),
        (["--out", "/proc/nope/demo"], "/proc/nope/demo: cannot create the folder"),
    ],
)
def test_bad_demo_flags_are_one_line_before_any_process_starts(capsys, tmp_path, args, fragment):
    assert main(["demo", "--out", str(tmp_path / "out"), *args]) == 2
    out, err = capsys.readouterr()
    (line,) = err.strip().splitlines()
    assert line.startswith("ssf: error: ") and fragment in line and out == ""


class DiedLauncher:
    """Stands in for the launcher of a run whose recorder died and whose flow node crashed once."""

    def __init__(self, graph, output) -> None:
        self.graph = graph
        self.failures = [("recorder", "exited with code -9")]
        self.crashes = [("recorder", -9), ("ssf_flow_node", -11)]

    def run(self) -> int:
        return 1


def test_demo_says_which_part_died_and_exits_one(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(demo, "Launcher", DiedLauncher)
    assert demo.run_demo("urban_100", 20.0, tmp_path / "out") == 1
    out, err = capsys.readouterr()
    assert out == ""  # no recording path printed as if all went well
    lines = [line for line in err.splitlines() if line.startswith("demo: ") and "scenario urban_100" not in line]
    assert lines[0] == "demo: graph stopped after 0 s"
    assert lines[1] == "demo: recorder exited with code -9"
    assert lines[2] == "demo: ssf_flow_node crashed (exit code -11) and was restarted"
    assert lines[3] == f"demo: the simulator wrote no episode summary to {tmp_path / 'out' / 'episode.json'}"
    assert lines[4].startswith(f"demo: the recording cannot be read: {tmp_path / 'out' / 'recording'}")
    assert lines[5] == f"demo: failed; what is in {tmp_path / 'out'} is incomplete"


@pytest.mark.parametrize("driver, command_topic", [("planner", "/cmd_vel"), ("follow", "")])
def test_the_odometry_takes_the_commands_as_its_prior_only_when_they_drive(tmp_path, driver, command_topic):
    """With the built-in follower driving, the planner's /cmd_vel does not move the car: the odometry ignores it."""
    graph = demo.demo_graph(demo.DemoPaths(tmp_path), "urban_100", 5.0, 1, driver=driver)
    odometry = next(node for node in graph.nodes if node.executable == "ssf_odom_node")
    assert odometry.parameters.get("command_topic", "/cmd_vel") == command_topic


def test_demo_in_real_time_records_commands(tmp_path):
    """`ssf demo --realtime`: the simulator at wall-clock rate, the planner's commands recorded."""
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-P", "-m", "ssf_common.cli", "demo", "--realtime", "--duration", "3",
                             "--out", str(out)], capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stderr[-4000:]
    assert "in real time" in result.stderr and "mode: realtime" in (out / "graph.yaml").read_text()
    with open_bag(out / "recording") as bag:
        assert bag.topics["/cmd_vel"].message_count > 0 and bag.topics["/ssf/semantic_flow"].message_count > 0


def test_the_real_time_graph_is_the_lockstep_graph_at_wall_clock_rate(tmp_path):
    lockstep = demo.demo_graph(demo.DemoPaths(tmp_path), "urban_100", 5.0, 1)
    realtime = demo.demo_graph(demo.DemoPaths(tmp_path), "urban_100", 5.0, 1, realtime=True)
    assert [node.name for node in lockstep.nodes] == [node.name for node in realtime.nodes]
    sim = [next(n for n in graph.nodes if n.executable == "sim_bridge") for graph in (lockstep, realtime)]
    assert sim[0].parameters["mode"] == "lockstep" and sim[1].parameters["mode"] == "realtime"
    fusion = next(n for n in realtime.nodes if n.executable == "ssf_fusion_node")
    assert fusion.parameters["timeout_s"] == demo.REALTIME_LOOP_TIMEOUT_S
