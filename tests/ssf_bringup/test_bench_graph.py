"""`ssf bench graph`'s arithmetic on a scripted probe, and /diagnostics from a node's StageStats."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from ssf_bringup.bench_graph import (GraphBench, Probe, bench_graph_spec, arrival_rate, format_bench, latencies_ms,
                                     node_rows)
from ssf_common import messages
from ssf_common.conversions import ego_motion_to_msg, obstacles_to_msg
from ssf_common.diagnostics import StageStats, read_status
from ssf_common.records import EgoMotion, Obstacles


class ScriptedProbe:
    """What Probe records, written by hand."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.clock_wall = {100: [10.0], 200: [10.1], 300: [10.2], 400: [10.3]}
        self.scans = [(10.0, 100), (10.1, 200), (10.2, 300), (10.3, 400)]
        self.answers = [(10.25, 100), (10.45, 300)]  # odometry or obstacles: scan 200 and 400 never answered
        self.pairs: dict[int, int] = {}
        self.driven: list[tuple[float, float]] = []
        self.commands = [10.27, 10.29, 10.5]  # the second command answers scan 100 again: counted once
        self.diagnostics = {"ssf_flow_node": {"scan_answered": 3, "hint_answered": 2, "scan_dropped": 1,
                                              "processing_ms_median": 40.0, "processing_ms_p95": 55.0}}
        self.reports = {"ssf_flow_node": [(4.0, {"scan_answered": 1}), (110.0, {"scan_answered": 2}),
                                          (410.0, self.diagnostics["ssf_flow_node"])]}
        self.episode = ("running", 0.0)
        self.ended = []

    shown_at = Probe.shown_at
    answered_between = Probe.answered_between


def test_latency_is_measured_from_the_scans_clock_time_to_the_answering_command():
    latency, answered = latencies_ms(ScriptedProbe(), since=0.0)
    assert answered == {(100, 10.0), (300, 10.2)}
    assert latency == pytest.approx([270.0, 300.0])
    assert latencies_ms(ScriptedProbe(), since=10.1)[1] == {(300, 10.2)}  # the warm-up is left out
    assert latencies_ms(ScriptedProbe(), since=0.0, until=10.1)[1] == {(100, 10.0)}  # scans shown after the window too


def test_the_command_rate_is_one_over_the_mean_interval_whatever_the_windows_phase():
    """600 commands 0.1 s apart are 10 Hz (`ros2 topic hz`), not 9.98 because the window's ends cut one off; the
    longest interval is the longest the car went without a command."""
    steady = list(10.03 + 0.1 * np.arange(600))
    assert arrival_rate(steady)[0] == pytest.approx(10.0)
    late = steady[:300] + [wall + 0.06 for wall in steady[300:301]] + steady[302:]  # one answer late, the next dropped
    rate, gap = arrival_rate(late)
    assert rate == pytest.approx(598 / 59.9) and gap == pytest.approx(160.0)
    assert arrival_rate([1.0]) == (0.0, None)


def test_a_command_answers_the_scan_whose_obstacles_came_before_it_though_its_odometry_came_after():
    """The planner plans a scan on the obstacles of the pair that ends with it (stamped with the pair's first scan):
    the odometry of that scan comes after the command."""
    probe = ScriptedProbe()
    Probe.on_ego_motion(probe, ego_motion_to_msg(EgoMotion(100, 200, "lidar", np.eye(4))))  # the flow's pair
    obstacles = obstacles_to_msg(Obstacles.empty(100, "base_link"))
    Probe.on_obstacles(probe, messages.serialize(obstacles, "ssf_interfaces/msg/ObstacleArray"))
    assert probe.answers[-1][1] == 200  # scan 100's obstacles answer scan 200
    probe.answers[-1] = (10.28, 200)  # they came at 10.28
    probe.answers.sort()
    latency, answered = latencies_ms(probe, since=0.0)
    assert answered == {(100, 10.0), (200, 10.1), (300, 10.2)}
    assert latency == pytest.approx([270.0, 190.0, 300.0])


def test_a_restarted_clock_is_measured_from_the_stamps_latest_showing():
    """Drives back to back restart the clock: stamp 100 of the second drive is answered 0.2 s after it was shown."""
    probe = ScriptedProbe()
    probe.clock_wall[100].append(50.0)
    probe.answers.append((50.15, 100))
    probe.commands.append(50.2)
    latency, answered = latencies_ms(probe, since=0.0)
    assert answered == {(100, 10.0), (300, 10.2), (100, 50.0)}
    assert latency[-1] == pytest.approx(200.0)


def test_node_rows_combine_diagnostics_and_process_samples():
    """RSS jumps at the start (caches filling), then leaks 1 MB per 100 s: the slope is taken over the second half."""
    times = np.arange(10.0, 601.0, 10.0)
    rss = 100.0 + 50.0 * (times >= 20) + np.clip(times - 300.0, 0, None) / 100.0
    used = 0.7 * (times - 10.0)  # CPU seconds: 70 % of a core
    samples = {"ssf_flow_node": [(1.0, 0.0, 90.0, 0.0)] + [(t, 70.0, m, u) for t, m, u in zip(times, rss, used)]}
    [row] = node_rows(ScriptedProbe(), samples, since=5.0)
    assert row.answered == 5 and row.dropped == 1 and row.processing_ms_median == 40.0
    assert row.cpu_ms_per_scan == pytest.approx(0.7 * 300.0 * 1e3 / 3)  # 3 inputs answered in 300 s between reports
    assert row.cpu_share == pytest.approx(0.70) and row.rss_mb == pytest.approx(153.0)
    assert row.rss_slope_mb_per_10min == pytest.approx(6.0, rel=0.05)
    assert row.rss_mb_per_minute[0] == pytest.approx(150.0) and row.rss_mb_per_minute[-1] == pytest.approx(152.5)
    assert len(row.rss_mb_per_minute) == 9  # 70 s, 130 s, ... 550 s


def test_stage_stats_travel_as_diagnostics():
    stats = StageStats("ssf_seg_node")
    for ms in (10.0, 20.0, 30.0):
        stats.record(ms, "segmentations")
    stats.set("flow_dropped", 4)
    msg = messages.deserialize(messages.serialize(stats.message(5), "diagnostic_msgs/msg/DiagnosticArray"),
                               "diagnostic_msgs/msg/DiagnosticArray")
    numbers = read_status(msg)["ssf_seg_node"]
    assert numbers["segmentations"] == 3 and numbers["flow_dropped"] == 4 and numbers["processing_ms_median"] == 20.0
    assert "median 20.0 ms" in msg.status[0].message


def test_the_bench_graph_is_the_demo_graph_in_real_time():
    from ssf_bringup.bench_graph import per_node_parameters

    graph = bench_graph_spec("urban_200")
    executables = [node.executable for node in graph.nodes]
    assert "ssf" not in executables  # no recorder
    assert {"sim_bridge", "ssf_flow_node", "ssf_seg_node", "ssf_fusion_node", "ssf_odom_node", "ssf_planner_node"} <= set(executables)
    sim = next(node for node in graph.nodes if node.executable == "sim_bridge")
    assert sim.parameters["mode"] == "realtime" and sim.parameters["driver"] == "none"
    assert sim.parameters["episodes"] == 1
    back_to_back = next(node for node in bench_graph_spec("urban_200", 0).nodes if node.executable == "sim_bridge")
    assert back_to_back.parameters["episodes"] == 0
    assert sim.parameters["lidar.rolling_shutter"] is False  # measured on the sweeps `ssf demo` casts
    rolling = bench_graph_spec("urban_200", 1, per_node_parameters(["sim_bridge:lidar.rolling_shutter:=true"]))
    assert next(node for node in rolling.nodes if node.executable == "sim_bridge").parameters["lidar.rolling_shutter"] is True
    # in real time the planner plans each scan on its obstacles and the odometry, off the critical path, yields the
    # cores; in lockstep (the demo) each step waits for the whole chain, odometry included
    planner = next(node for node in graph.nodes if node.executable == "ssf_planner_node")
    odometry = next(node for node in graph.nodes if node.executable == "ssf_odom_node")
    assert planner.parameters["plan_on"] == "scan" and odometry.nice == 19
    lockstep = bench_graph_spec("urban_200", mode="lockstep")
    assert next(node for node in lockstep.nodes if node.executable == "ssf_planner_node").parameters["plan_on"] == "odometry"
    assert next(node for node in lockstep.nodes if node.executable == "ssf_odom_node").nice == 0


def test_node_parameters_reach_their_node_and_unknown_nodes_are_refused():
    from ssf_bringup.bench_graph import per_node_parameters
    from ssf_bringup.demo import REALTIME_LOOP_TIMEOUT_S
    from ssf_common.errors import ConfigError

    default = next(node for node in bench_graph_spec("urban_200", 1).nodes if node.name == "ssf_fusion_node")
    assert "fusion.max_iterations" not in default.parameters  # one iteration: the default, lockstep or real time
    settings = per_node_parameters(["ssf_fusion_node:fusion.max_iterations:=3", "ssf_flow_node:estimator:=ego"])
    assert settings == {"ssf_fusion_node": {"fusion.max_iterations": 3}, "ssf_flow_node": {"estimator": "ego"}}
    fusion = next(node for node in bench_graph_spec("urban_200", 1, settings).nodes if node.name == "ssf_fusion_node")
    assert fusion.parameters["fusion.max_iterations"] == 3 and fusion.parameters["timeout_s"] == REALTIME_LOOP_TIMEOUT_S == 0.15
    with pytest.raises(ConfigError, match="no node of that name"):
        bench_graph_spec("urban_200", 1, per_node_parameters(["recorder:x:=1"]))
    with pytest.raises(ConfigError, match="NODE:NAME:=VALUE"):
        per_node_parameters(["fusion.max_iterations:=1"])


def test_a_drive_that_ended_early_is_said_with_its_outcome():
    collision = messages.msg_type("ssf_interfaces/msg/EpisodeResult")(
        header=messages.header(0, ""), scenario="urban_200", seed=3, outcome=2, time=13.5, distance=25.0,
        average_speed=1.9, min_clearance=0.0, num_agents=200)
    probe = ScriptedProbe()
    Probe.on_episode(probe, collision)
    assert probe.episode == ("collision", 13.5)
    bench = GraphBench(14.0, "urban_200", 127, 3.1, 656.0, 824.0, 0.68, episode="collision", episode_time_s=13.5)
    assert "ended after 13.5 s of simulated time (collision)" in format_bench(bench).splitlines()[1]
    assert "ended after" not in format_bench(GraphBench(60.0, "urban_200", 600, 3.0, 1.0, 2.0, 0.7))


def test_drives_back_to_back_keep_the_first_outcome_and_count_every_drive():
    result = messages.msg_type("ssf_interfaces/msg/EpisodeResult")
    probe = ScriptedProbe()
    for outcome, time_s, distance in ((0, 5.0, 10.0), (2, 13.5, 30.0), (0, 1.0, 2.0), (1, 96.0, 400.0), (0, 2.0, 3.0)):
        Probe.on_episode(probe, result(header=messages.header(0, ""), scenario="urban_200", seed=3, outcome=outcome,
                                       time=time_s, distance=distance, average_speed=1.0, min_clearance=1.0,
                                       num_agents=200))
    assert probe.episode == ("collision", 13.5)
    assert probe.ended == [("collision", 13.5), ("success", 96.0)]
    assert probe.driven == [(13.5, 30.0), (96.0, 400.0), (2.0, 3.0)]  # each drive's last report: 433 m in 111.5 s
    bench = GraphBench(3600.0, "urban_200", 36000, 3.0, 1.0, 2.0, 0.7, episode="collision", episode_time_s=13.5,
                       episodes={"collision": 1, "success": 1}, episodes_requested=0)
    assert "drives ended back to back: 1 collision, 1 success" in format_bench(bench)
    bench.distance_m, bench.average_speed_mps = 433.0, 3.88
    assert "the ego drove 433 m at 3.9 m/s on average" in format_bench(bench)


def test_odometry_is_scored_against_the_truth_of_the_first_drive():
    from ssf_bringup.bench_graph import odometry_error
    from ssf_common.conversions import odometry_to_msg
    from ssf_common.geometry.se3 import invert, make_pose
    from ssf_common.records import OdometryEstimate

    truth = {k * 100: make_pose(50.0 + 2.0 * k, -3.0, 0.0, yaw=1.0 + 0.01 * k) for k in range(10)}
    origin = invert(truth[200])  # the odometry starts at the stamp-200 pose ...
    odometry = [(k * 100, origin @ truth[k * 100]) for k in range(2, 10)]
    odometry[-1] = (900, odometry[-1][1] @ make_pose(0.3, 0.4, 0.0, yaw=np.radians(2.0)))  # ... and ends 0.5 m off
    score = odometry_error(odometry + [(1000, np.eye(4))], truth)  # a stamp the truth lacks is left out
    assert score.poses == 8 and score.p50_m == pytest.approx(0.0, abs=1e-9)
    assert score.max_m == pytest.approx(0.5) and score.heading_max_deg == pytest.approx(2.0)
    assert odometry_error([], truth) is None

    probe = ScriptedProbe()  # the probe keeps the first drive's poses: stamps going back end it
    probe.answers, probe.odometry_poses, probe.truth_poses = [], [], {}
    probe.truth_last, probe.first_drive = -1, {"odom": True, "truth": True}
    for stamp in (100, 200, 100, 300):
        estimate = OdometryEstimate(stamp, make_pose(stamp * 0.01, 0.0, 0.0), np.eye(6))
        Probe.on_odometry(probe, odometry_to_msg(estimate))
        Probe.on_truth(probe, odometry_to_msg(estimate))
    assert [stamp for stamp, _ in probe.odometry_poses] == [100, 200] and sorted(probe.truth_poses) == [100, 200]
    assert len(probe.answers) == 4  # latency still counts every answer


def test_a_short_bench_graph_reports_cpu_per_scan_of_every_node(tmp_path):
    """`ssf bench graph --duration 5`: the whole graph for real, every node's CPU time per input answered in the JSON."""
    import json
    import subprocess
    import sys

    out = tmp_path / "graph.json"
    result = subprocess.run([sys.executable, "-P", "-m", "ssf_bringup.cli", "bench", "graph", "--duration", "5",
                             "--json", str(out)], capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stderr[-3000:]
    rows = {row["node"]: row for row in json.loads(out.read_text())["nodes"]}
    assert {"sim_bridge", "ssf_flow_node", "ssf_seg_node", "ssf_fusion_node", "ssf_odom_node", "ssf_planner_node"} <= set(rows)
    assert all("cpu_ms_per_scan" in row for row in rows.values())
    # the simulator steps whatever the load (a stage may answer nothing in 5 s on a loaded machine: None then)
    assert rows["sim_bridge"]["cpu_ms_per_scan"] is not None and rows["sim_bridge"]["cpu_ms_per_scan"] > 0
    assert all(row["cpu_ms_per_scan"] is None or row["cpu_ms_per_scan"] > 0 for row in rows.values())
    assert "CPU ms/in" in result.stdout
