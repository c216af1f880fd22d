"""`ssf demo`, the README's first command: a short run of the shipped graph, and honest failure when a part dies."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ssf_bringup import demo
from ssf_bringup.cli import main
from ssf_common import messages
from ssf_bringup.launcher import command_line
from ssf_common.bags.reader import open_bag
from ssf_common.pointcloud import decode_cloud

DURATION_S = 3.0
STEPS = int(DURATION_S * 10)  # the scenario's dt is 0.1 s


def strict_loads(text: str):
    return json.loads(text, parse_constant=lambda name: pytest.fail(f"non-standard JSON constant {name}"))


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    out = tmp_path_factory.mktemp("demo") / "run"
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_bringup.cli", "demo", "--duration", str(DURATION_S), "--out", str(out),
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


def test_demo_records_by_default_what_a_replay_and_a_person_need_in_simulated_time(demo_run):
    """The scans, the segmentation (every other scan's), obstacles, odometry, plan, commands, tf, clock and the truth
    boxes and poses; not the fusion loop's intermediate clouds nor the per-point truth. Log times are the simulator's
    /clock, so the bag lasts as long as the drive; its size keeps a 20 s demo under 400 MB."""
    result, out = demo_run
    with open_bag(out / "recording") as bag:
        counts = {name: topic.message_count for name, topic in bag.topics.items() if topic.message_count}
        info = bag.info
    assert set(counts) <= set(demo.DEFAULT_TOPICS), set(counts) - set(demo.DEFAULT_TOPICS)
    assert {"/lidar/points", "/ssf/semantic_flow", "/ssf/obstacles", "/odom", "/ssf/plan", "/cmd_vel", "/tf", "/clock",
            "/sim/ground_truth/obstacles", "/sim/ground_truth/odom"} <= set(counts), counts
    scans = counts["/lidar/points"]
    assert scans == STEPS + 1 and counts["/ssf/semantic_flow"] <= (scans + 1) // 2  # every other segmentation
    assert info.start_ns == 0 and info.end_ns == STEPS * 100_000_000  # the simulated drive, not the wall clock
    printed = strict_loads(result.stdout)
    assert printed["recording_bytes"] == demo.folder_bytes(out / "recording")
    assert printed["recording_bytes"] < 400e6 * scans / (20 * 10 + 1)  # at this rate a 20 s demo stays under 400 MB
    assert "demo: recording " in result.stderr and "duration reached after 3.0 s" in result.stderr


def test_demo_recording_holds_the_closed_loop(demo_run):
    _, out = demo_run
    with open_bag(out / "recording") as bag:
        assert not bag.info.damage
        counts = {name: topic.message_count for name, topic in bag.topics.items()}
        assert all(counts.get(name, 0) > 0 for name in demo.RECORDED_TOPICS), counts
        scans = [messages.stamp_ns(bag.decode(m).header.stamp) for m in bag.messages(["/lidar/points"])]
        episode = [bag.decode(m) for m in bag.messages(["/sim/episode"])]
        flow = [bag.decode(m) for m in bag.messages(["/ssf/semantic_flow"])]
        semantic = [bag.decode(m) for m in bag.messages(["/ssf/semantic_flow"])]
        commands = [bag.decode(m) for m in bag.messages(["/cmd_vel"])]
        truth = [bag.decode(m) for m in bag.messages(["/sim/ground_truth/odom"])]
        odometry = [bag.decode(m) for m in bag.messages(["/odom"])]
        first_scan = bag.decode(next(bag.messages(["/lidar/points"])))
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
    assert {messages.stamp_ns(f.header.stamp) for f in flow} <= set(scans)  # the flow answers recorded scans
    assert all({"flow_x", "flow_y", "flow_z"} <= {field.name for field in f.fields} for f in flow)
    swept = decode_cloud(first_scan).time  # a rolling-shutter sweep by default: each column at its own time
    assert swept is not None and swept.min() < -0.09 and swept.max() <= 0.0


def test_the_demo_graph_sweeps_each_column_at_its_time_and_the_real_time_bench_instantly(tmp_path):
    """`ssf demo` casts rolling-shutter sweeps (--sim-param lidar.rolling_shutter:=false: instant ones); `ssf bench
    graph`, the same graph in real time, casts instant sweeps unless its -p says otherwise."""
    from ssf_bringup.bench_graph import bench_graph_spec

    default = demo.demo_graph(demo.DemoPaths(tmp_path), "urban_100", 5.0, 1)
    assert demo.scenario_settings(default) == {"lidar.rolling_shutter": True}
    assert demo.check_scenario("urban_100", demo.scenario_settings(default)).lidar.rolling_shutter
    instant = demo.demo_graph(demo.DemoPaths(tmp_path), "urban_100", 5.0, 1,
                              sim_settings={"lidar.rolling_shutter": False})
    assert not demo.check_scenario("urban_100", demo.scenario_settings(instant)).lidar.rolling_shutter
    sim = next(node for node in instant.nodes if node.executable == "sim_bridge")
    assert "lidar.rolling_shutter:=false" in command_line(sim, {})
    assert demo.scenario_settings(bench_graph_spec("urban_200")) == {"lidar.rolling_shutter": False}
    told = bench_graph_spec("urban_200", parameters={"sim_bridge": {"lidar.rolling_shutter": True}})
    assert demo.scenario_settings(told) == {"lidar.rolling_shutter": True}


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--duration", "-1"], "--duration must be above 0"),
        (["--duration", "inf"], "--duration must be a finite number"),
        (["--seed", "-7"], "--seed must be an integer from 0 to 4294967295"),
        (["--scenario", "nope"], "unknown scenario 'nope'"),
        (["--out", "/proc/nope/demo"], "/proc/nope/demo: cannot create the folder"),
        (["--sim-param", "lidar.rolling_shutter:=maybe"], "lidar.rolling_shutter"),
    ],
)
def test_bad_demo_flags_are_one_line_before_any_process_starts(capsys, tmp_path, args, fragment):
    assert main(["demo", "--out", str(tmp_path / "out"), *args]) == 2
    out, err = capsys.readouterr()
    (line,) = err.strip().splitlines()
    assert line.startswith("ssf: error: ") and fragment in line and out == ""


def test_the_demo_refuses_in_one_line_a_disk_its_recording_will_not_fit(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(demo.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10**12, 10**12 - 10**8, 10**8))
    assert main(["demo", "--out", str(tmp_path / "out")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"ssf: error: {tmp_path / 'out'}: 95.4 MiB free, but 20 s of driving record about ")


def test_the_recording_estimate_follows_the_sensor_the_duration_and_the_topics():
    from sim_bridge.scenario import load_scenario

    urban = load_scenario("urban_100")
    default, everything = demo.Recording.chosen(), demo.Recording.chosen(record_all=True)
    twenty = demo.recording_estimate(urban, 20.0, default)
    assert 300e6 < twenty < 500e6  # measured: 348 MB for 20 s (docs/recordings.md), with room to spare
    assert demo.recording_estimate(urban, 40.0, default) == pytest.approx(2 * twenty, rel=0.01)
    assert demo.recording_estimate(urban, 20.0, everything) > 4 * twenty
    flows = demo.Recording.chosen(extra=["/ssf/flow"])  # a big cloud asked for: counted as everything
    assert demo.recording_estimate(urban, 20.0, flows) == demo.recording_estimate(urban, 20.0, everything)
    sparse = load_scenario("urban_100", {"lidar.model": "vlp16"})
    assert demo.recording_estimate(sparse, 20.0, default) < twenty / 2


def test_demo_topic_choices_become_the_recorders_arguments(tmp_path):
    default = demo.Recording.chosen()
    arguments = default.recorder_arguments(tmp_path / "rec")
    assert arguments[:4] == ["record", "-o", str(tmp_path / "rec"), "--use-sim-time"]
    assert arguments[4:6] == ["--every", "/ssf/semantic_flow:2"] and arguments[6:] == list(demo.DEFAULT_TOPICS)
    assert not set(demo.ON_REQUEST) & set(arguments)
    extra = demo.Recording.chosen(extra=["/ssf/mask", "/ssf/semantic_flow"]).recorder_arguments(tmp_path)
    assert "--every" not in extra and extra[-1] == "/ssf/mask"  # named: recorded whole
    assert demo.Recording.chosen(record_all=True).recorder_arguments(tmp_path) == [
        "record", "-o", str(tmp_path), "--use-sim-time"]  # every topic


@pytest.mark.parametrize(("args", "fragment"), [
    (["--record-all", "--record", "/ssf/mask"], "give it or --record TOPIC ..., not both"),
    (["--record", "ssf/mask"], "topic 'ssf/mask' must be absolute"),
])
def test_bad_record_flags_are_one_line(capsys, tmp_path, args, fragment):
    assert main(["demo", "--out", str(tmp_path / "out"), *args]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: ") and fragment in line


def test_progress_says_simulated_time_against_the_wall_clock(tmp_path):
    progress = demo.Progress(20.0, print, tmp_path)
    line = progress.line(5.0, 30.5, 70 * 2**20)
    assert line == "t 5.0 / 20 s [#######.......................] 6.1× slower than real time, about 1 min 32 s " \
                   "left; recording 70.0 MiB"
    assert "waiting for the first simulated step" in progress.line(0.0, 0.0, 0)
    assert "2.0× faster than real time" in progress.line(10.0, 5.0, 0)


def test_a_middleware_that_cannot_start_is_one_line_before_any_node_starts(tmp_path):
    result = subprocess.run([sys.executable, "-P", "-m", "ssf_bringup.cli", "demo", "--out", str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120, env={**os.environ, "ROS_DOMAIN_ID": "241"})
    assert result.returncode == 2 and result.stdout == ""
    (line,) = result.stderr.strip().splitlines()
    assert line == "ssf: error: ROS_DOMAIN_ID must be an integer 0..232, got '241'"


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
    result = subprocess.run([sys.executable, "-P", "-m", "ssf_bringup.cli", "demo", "--realtime", "--duration", "3",
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
