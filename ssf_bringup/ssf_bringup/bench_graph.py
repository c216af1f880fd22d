"""`ssf bench graph`: the whole graph in real time, every node its own process, measured from the outside.

The simulator steps every 0.1 s of wall time whatever the stages do (real time, as a vehicle would); a probe node
records when scans, odometry and commands appear, every node's /diagnostics, and psutil samples each process."""

from __future__ import annotations

import argparse
import bisect
import collections
import io
import math
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ssf_bringup.demo import in_real_time
from ssf_bringup.launcher import GraphSpec, Launcher, load_graph
from ssf_common import messages, pose_msgs, topics
from ssf_common.config import parse_override
from ssf_common.diagnostics import read_status
from ssf_common.errors import ConfigError
from ssf_common.geometry.se3 import invert, yaw_of
from ssf_common.render.frames import header_stamp

SAMPLE_PERIOD_S = 1.0
WARMUP_S = 5.0  # the first seconds (imports, discovery, the first scans) are not counted
GRACE_S = 1.0  # the graph runs on this long after the window, so that its last scans can be answered


@dataclass
class NodeRow:
    """One node's figures over the measured window."""

    node: str
    processing_ms_median: float | None
    processing_ms_p95: float | None
    answered: int
    dropped: int
    cpu_share: float  # of one core, mean over the window
    rss_mb: float  # at the end
    rss_slope_mb_per_10min: float  # over the second half of the window (the first fills caches and pools)
    rss_mb_per_minute: list[float] = field(default_factory=list)  # RSS at the end of each minute of the window
    cpu_ms_per_scan: float | None = None  # CPU time (user + system) over the inputs answered in the window: per scan
    # (flow, segmentation, fusion, odometry), tick (planner) or step (simulator); None where none was answered


@dataclass
class GraphBench:
    """The graph's end-to-end figures and one row per node (the JSON keys of `ssf bench graph`)."""

    duration_s: float
    scenario: str
    scans: int
    cmd_vel_rate_hz: float  # as `ros2 topic hz` gives it: one over the mean interval between the window's commands
    latency_p50_ms: float | None
    latency_p95_ms: float | None
    scans_dropped_ratio: float
    nodes: list[NodeRow] = field(default_factory=list)
    episode: str = "running"  # how the (first) simulated drive stood when the measurement ended: running, success, collision, timeout
    episode_time_s: float = 0.0  # simulated seconds driven by then
    episodes: dict[str, int] = field(default_factory=dict)  # every drive that ended, by outcome
    episodes_requested: int = 1  # --episodes: 1 ends the measurement with the first drive, 0 drives back to back
    distance_m: float = 0.0  # metres the ego drove, every drive of the run together
    average_speed_mps: float = 0.0  # distance_m over the simulated seconds driven
    odom_error_p50_m: float | None = None  # /odom against the simulator's truth over the first drive: position error
    odom_error_max_m: float | None = None  # (both in the odometry frame, the first /odom's pose as the origin) ...
    odom_heading_error_max_deg: float | None = None  # ... and heading error
    cmd_vel_commands: int = 0  # commands sent in the window
    cmd_vel_gap_max_ms: float | None = None  # the longest the car went without a command in the window
    scan_rate_hz: float = 0.0  # the scans' own rate over the window, as cmd_vel_rate_hz (what the commands answer)


class Probe:
    """Listens to the graph: wall time of each /clock stamp, scans, perception's answers (odometry, obstacles),
    commands, diagnostics."""

    def __init__(self, spin: bool = True) -> None:
        from ssf_common.middleware import QOS_DEFAULT, QOS_SENSOR_DATA, Node

        self.node = Node("ssf_bench_probe")
        self.lock = threading.Lock()
        self.clock_wall: dict[int, list[float]] = collections.defaultdict(list)  # a restarted clock shows a stamp again
        self.scans: list[tuple[float, int]] = []
        self.answers: list[tuple[float, int]] = []  # when each /odom or /ssf/obstacles came, and the scan it answers
        self.pairs: dict[int, int] = {}  # the flow's pairs (/ssf/ego_motion): first scan's stamp -> second's
        self.odometry_poses: list[tuple[int, np.ndarray]] = []  # the first drive's /odom: stamp, odom <- base_link
        self.truth_poses: dict[int, np.ndarray] = {}  # the first drive's true poses: stamp -> world <- base_link
        self.truth_last = -1
        self.first_drive = {"odom": True, "truth": True}  # stamps going back end the first drive's poses
        self.commands: list[float] = []
        self.diagnostics: dict[str, dict[str, float]] = {}
        self.reports: dict[str, list[tuple[float, dict[str, float]]]] = collections.defaultdict(list)  # every report
        self.episode: tuple[str, float] = ("running", 0.0)
        self.ended: list[tuple[str, float]] = []  # every drive that ended: outcome, simulated seconds
        self.driven: list[tuple[float, float]] = []  # per drive, the latest (simulated seconds, metres) reported
        self.node.create_subscription("rosgraph_msgs/msg/Clock", topics.CLOCK, self.on_clock, QOS_DEFAULT)
        self.node.create_subscription("sensor_msgs/msg/PointCloud2", topics.LIDAR_POINTS, self.on_scan, QOS_SENSOR_DATA,
                                      raw=True)
        self.node.create_subscription("nav_msgs/msg/Odometry", topics.ODOM, self.on_odometry, QOS_DEFAULT)
        self.node.create_subscription("ssf_interfaces/msg/ObstacleArray", topics.OBSTACLES, self.on_obstacles,
                                      QOS_DEFAULT, raw=True)
        self.node.create_subscription("ssf_interfaces/msg/EgoMotion", topics.EGO_MOTION, self.on_ego_motion,
                                      QOS_DEFAULT)
        self.node.create_subscription("nav_msgs/msg/Odometry", topics.GT_ODOM, self.on_truth, QOS_DEFAULT)
        self.node.create_subscription("geometry_msgs/msg/Twist", topics.CMD_VEL, self.on_command, QOS_DEFAULT)
        self.node.create_subscription("diagnostic_msgs/msg/DiagnosticArray", topics.DIAGNOSTICS, self.on_diagnostics,
                                      QOS_DEFAULT)
        self.node.create_subscription("ssf_interfaces/msg/EpisodeResult", topics.EPISODE, self.on_episode, QOS_DEFAULT)
        if spin:  # a subclass that listens to more spins once its subscriptions are made
            self.node.spin_in_thread()

    def on_episode(self, msg: Any) -> None:
        names = {msg.OUTCOME_RUNNING: "running", msg.OUTCOME_SUCCESS: "success", msg.OUTCOME_COLLISION: "collision",
                 msg.OUTCOME_TIMEOUT: "timeout"}
        outcome = (names.get(msg.outcome, f"outcome {msg.outcome}"), float(msg.time))
        with self.lock:
            if not self.driven or msg.time < self.driven[-1][0]:  # the clock went back: the next drive
                self.driven.append((0.0, 0.0))
            self.driven[-1] = (float(msg.time), float(msg.distance))
            if outcome[0] != "running":
                self.ended.append(outcome)
            if self.episode[0] == "running":  # the first drive's outcome stays once it is known
                self.episode = outcome

    def on_clock(self, msg: Any) -> None:
        stamp, now = messages.stamp_ns(msg.clock), time.monotonic()
        with self.lock:
            walls = self.clock_wall[stamp]
            if not walls or now - walls[-1] > 1.0:  # a stamp seen again later: the simulator started another drive
                walls.append(now)

    def shown_at(self, stamp: int, before: float) -> float | None:
        """When /clock last showed this stamp before the given wall time (a restarted clock shows stamps again)."""
        walls = self.clock_wall.get(stamp)
        if not walls:
            return None
        index = bisect.bisect_right(walls, before) - 1
        return walls[index] if index >= 0 else None

    def on_scan(self, cdr: bytes) -> None:
        with self.lock:
            self.scans.append((time.monotonic(), header_stamp(cdr)))

    def on_obstacles(self, cdr: bytes) -> None:
        """Obstacles of scan t, found on the pair (t, t+1) (its flow's ego motion came first), answer scan t+1."""
        stamp = header_stamp(cdr)
        with self.lock:
            self.answers.append((time.monotonic(), self.pairs.get(stamp, stamp)))

    def on_ego_motion(self, msg: Any) -> None:
        with self.lock:
            self.pairs[messages.stamp_ns(msg.header.stamp)] = messages.stamp_ns(msg.next_stamp)

    def on_odometry(self, msg: Any) -> None:
        stamp = messages.stamp_ns(msg.header.stamp)
        with self.lock:
            self.answers.append((time.monotonic(), stamp))
            self.first_drive["odom"] &= not self.odometry_poses or stamp > self.odometry_poses[-1][0]
            if self.first_drive["odom"]:
                self.odometry_poses.append((stamp, pose_msgs.matrix_from_pose(msg.pose.pose)))

    def on_truth(self, msg: Any) -> None:
        stamp = messages.stamp_ns(msg.header.stamp)
        with self.lock:
            self.first_drive["truth"] &= stamp > self.truth_last
            if self.first_drive["truth"]:
                self.truth_poses[stamp] = pose_msgs.matrix_from_pose(msg.pose.pose)
            self.truth_last = stamp

    def on_command(self, _msg: Any) -> None:
        with self.lock:
            self.commands.append(time.monotonic())

    def on_diagnostics(self, msg: Any) -> None:
        now = time.monotonic()
        with self.lock:
            for name, values in read_status(msg).items():
                self.diagnostics[name] = values
                self.reports[name].append((now, values))

    def answered_between(self, name: str, since: float) -> tuple[float, float, int] | None:
        """From the first to the last report of a node after `since`: their times and the inputs answered in between
        (None before two reports)."""
        reports = [(at, answered_count(values)) for at, values in self.reports.get(name, []) if at >= since]
        if len(reports) < 2:
            return None
        return reports[0][0], reports[-1][0], reports[-1][1] - reports[0][1]

    def close(self) -> None:
        self.node.destroy_node()


def bench_graph_spec(scenario: str, episodes: int = 1, parameters: dict[str, dict[str, Any]] | None = None,
                     mode: str = "realtime") -> GraphSpec:
    """The demo graph without its recorder, the simulator in real time (or lockstep, as the demo) driven by the planner
    (`episodes` drives back to back, 0: until stopped), with `parameters` set per node name."""
    graph = load_graph(Path(str(resources.files("ssf_bringup") / "graphs" / "demo.yaml")))
    graph = in_real_time(graph) if mode == "realtime" else graph
    parameters = parameters or {}
    nodes = []
    for node in graph.nodes:
        if node.executable == "ssf":
            continue
        if node.executable == "sim_bridge":  # instant sweeps unless told, to compare with earlier runs (rolling-shutter
            # sweeps cost the graph ~11 ms of CPU a scan: docs/realtime.md)
            node = node.model_copy(update={"parameters": {**node.parameters, "scenario": scenario, "mode": mode,
                                                          "driver": "none", "duration_s": 0.0, "episodes": episodes,
                                                          "lidar.rolling_shutter": False}})
        if node.name in parameters:
            node = node.model_copy(update={"parameters": {**node.parameters, **parameters[node.name]}})
        nodes.append(node)
    unknown = sorted(set(parameters) - {node.name for node in nodes})
    if unknown:
        raise ConfigError(f"-p {unknown[0]}:...: no node of that name in the graph; the nodes are "
                          f"{', '.join(node.name for node in nodes)}")
    return graph.model_copy(update={"nodes": nodes})


def per_node_parameters(items: list[str]) -> dict[str, dict[str, Any]]:
    """Per-node settings from `NODE:NAME:=VALUE` items, e.g. ssf_fusion_node:fusion.max_iterations:=1."""
    settings: dict[str, dict[str, Any]] = {}
    for item in items:
        node, separator, setting = item.partition(":")
        if not separator or not node.strip() or setting.startswith("="):
            raise ConfigError(f"-p expects NODE:NAME:=VALUE (e.g. ssf_fusion_node:fusion.max_iterations:=1), got {item!r}")
        name, value = parse_override(setting, f"-p {node}:")
        settings.setdefault(node.strip(), {})[name] = value
    return settings


def answered_count(numbers: dict[str, float]) -> int:
    """The inputs a node's diagnostics say it answered: its workers' answered inputs, else its own count of estimates,
    segmentations, fusion iterations, odometry steps, planner ticks or simulator steps."""
    return int(sum(value for key, value in numbers.items() if key.endswith("_answered"))) or int(
        sum(value for key, value in numbers.items() if key in ("estimates", "segmentations", "steps", "ticks",
                                                               "iterations")))


def sample_processes(launcher: Launcher, samples: dict[str, list[tuple[float, float, float, float]]],
                     stop: threading.Event) -> None:
    """Every second: (time, CPU % of one core, RSS MB, CPU seconds used so far) of each node process."""
    import psutil

    handles: dict[str, psutil.Process] = {}
    while not stop.wait(SAMPLE_PERIOD_S):
        for managed in launcher.managed:
            if managed.process is None or managed.process.poll() is not None:
                continue
            try:
                handle = handles.get(managed.label)
                if handle is None or handle.pid != managed.process.pid:
                    handle = handles[managed.label] = psutil.Process(managed.process.pid)
                    handle.cpu_percent(None)
                    continue
                used = handle.cpu_times()
                samples.setdefault(managed.label, []).append(
                    (time.monotonic(), handle.cpu_percent(None), handle.memory_info().rss / 2**20, used.user + used.system))
            except psutil.Error:
                continue


def arrival_rate(walls: list[float]) -> tuple[float, float | None]:
    """A topic's rate as `ros2 topic hz` gives it (one over the mean interval: a count over a fixed window is a message
    more or less by the phase of its ends) and the longest interval (ms); 0 and None under two messages."""
    if len(walls) < 2:
        return 0.0, None
    walls = sorted(walls)
    return (len(walls) - 1) / (walls[-1] - walls[0]), float(np.diff(walls).max() * 1e3)


def latencies_ms(probe: Probe, since: float, until: float = math.inf) -> tuple[list[float], set[tuple[int, float]]]:
    """Scan stamp -> the /cmd_vel that answers it: each command answers the scan of the perception answer that came
    last before it (/odom of the scan, or the obstacles of the pair that ends with it), the first command after it;
    the scan's time is when /clock showed that stamp, between since and until (its answer may come after)."""
    answered: set[tuple[int, float]] = set()  # (stamp, when /clock showed it): stamps repeat when drives restart
    latency: list[float] = []
    answers = sorted(probe.answers)
    index = -1
    for wall in sorted(probe.commands):
        while index + 1 < len(answers) and answers[index + 1][0] <= wall:
            index += 1
        if index < 0 or wall < since:
            continue
        arrived, stamp = answers[index]
        shown = probe.shown_at(stamp, arrived)
        if shown is None or not since <= shown <= until or (stamp, shown) in answered:
            continue
        answered.add((stamp, shown))
        latency.append((wall - shown) * 1e3)
    return latency, answered


class OdometryError(NamedTuple):
    """The odometry against the truth at the stamps both give: position error median and max (m), heading max (deg)."""

    p50_m: float
    max_m: float
    heading_max_deg: float
    poses: int


def odometry_error(odometry: list[tuple[int, np.ndarray]], truth: dict[int, np.ndarray]) -> OdometryError | None:
    """Odometry poses (stamp, odom <- base_link; the first one's frame is the odometry's origin) against true poses
    (stamp -> world <- base_link), each moved into the frame of the true pose at the first odometry stamp."""
    matched = [(stamp, pose) for stamp, pose in odometry if stamp in truth]
    if not matched:
        return None
    first_stamp, first_pose = matched[0]
    origin = truth[first_stamp] @ invert(first_pose)  # world <- odom
    position, heading = [], []
    for stamp, pose in matched:
        error = invert(origin @ pose) @ truth[stamp]
        position.append(float(np.linalg.norm(error[:2, 3])))
        heading.append(abs(np.degrees(yaw_of(error))))
    return OdometryError(float(np.median(position)), max(position), max(heading), len(matched))


def node_rows(probe: Probe, samples: dict[str, list[tuple[float, float, float, float]]], since: float) -> list[NodeRow]:
    """One row per node: its diagnostics, CPU share, CPU time per input answered and memory over the window."""
    rows = []
    for label, series in sorted(samples.items()):
        window = [sample for sample in series if sample[0] >= since]
        if not window:
            continue
        times, cpu, rss, used = (np.array(column) for column in zip(*window))
        settled = times >= times[0] + 0.5 * (times[-1] - times[0])  # the slope of the second half: caches have filled
        slope = float(np.polyfit(times[settled], rss[settled], 1)[0] * 600.0) if settled.sum() > 2 else 0.0
        numbers = probe.diagnostics.get(label, {})
        answered = answered_count(numbers)
        dropped = int(sum(value for key, value in numbers.items() if key.endswith("_dropped")))
        minutes = [float(rss[times <= t][-1]) for t in np.arange(times[0] + 60.0, times[-1] + 1e-9, 60.0)]
        between = probe.answered_between(label, since)
        per_input = None
        if between is not None and between[2] > 0 and len(used) > 1:  # CPU seconds used between the two reports
            first, last, inputs = between
            per_input = float((np.interp(last, times, used) - np.interp(first, times, used)) * 1e3 / inputs)
        rows.append(NodeRow(label, numbers.get("processing_ms_median"), numbers.get("processing_ms_p95"), answered,
                            dropped, float(cpu.mean() / 100.0), float(rss[-1]), slope, minutes, per_input))
    return rows


def run_bench_graph(duration_s: float, scenario: str = "urban_200", log: Any = None, episodes: int = 1,
                    parameters: dict[str, dict[str, Any]] | None = None) -> GraphBench:
    """Start the graph, measure for duration_s after the warm-up, stop it, compute the figures."""
    graph = bench_graph_spec(scenario, episodes, parameters)
    launcher = Launcher(graph, output=log or io.StringIO())
    probe = Probe()
    samples: dict[str, list[tuple[float, float, float, float]]] = {}
    stop = threading.Event()
    sampler = threading.Thread(target=sample_processes, args=(launcher, samples, stop), daemon=True)
    started = time.monotonic()
    try:
        launcher.start()
        sampler.start()
        window_start, window_end = started + WARMUP_S, started + WARMUP_S + duration_s
        while time.monotonic() < window_end + GRACE_S:
            if not launcher.poll():
                window_end = min(window_end, time.monotonic())
                break
            time.sleep(0.05)
    finally:
        stop.set()
        launcher.stop()
        probe.close()
    measured = max(window_end - window_start, 1e-9)  # scans and commands counted in one window
    with probe.lock:
        arrivals = [(wall, stamp) for wall, stamp in probe.scans if window_start <= wall < window_end]
        scans = [(stamp, probe.shown_at(stamp, wall + 0.5)) for wall, stamp in arrivals]
        commands = [wall for wall in probe.commands if window_start <= wall < window_end]
        latency, answered = latencies_ms(probe, window_start, window_end)
        ended = collections.Counter(outcome for outcome, _ in probe.ended)
        driven_s, distance = (float(sum(column)) for column in zip((0.0, 0.0), *probe.driven))
        odometry = odometry_error(list(probe.odometry_poses), dict(probe.truth_poses))
    answered_scans = len(answered & set(scans))
    rate, gap = arrival_rate(commands)
    return GraphBench(
        duration_s=round(measured, 2), scenario=scenario, scans=len(scans),
        cmd_vel_rate_hz=rate, cmd_vel_commands=len(commands), cmd_vel_gap_max_ms=gap,
        scan_rate_hz=arrival_rate([wall for wall, _ in arrivals])[0],
        latency_p50_ms=float(np.percentile(latency, 50)) if latency else None,
        latency_p95_ms=float(np.percentile(latency, 95)) if latency else None,
        scans_dropped_ratio=1.0 - answered_scans / len(scans) if scans else 1.0,
        nodes=node_rows(probe, samples, window_start), episode=probe.episode[0],
        episode_time_s=round(probe.episode[1], 2), episodes=dict(ended),
        episodes_requested=episodes, distance_m=round(distance, 1),
        average_speed_mps=round(distance / driven_s, 2) if driven_s > 0 else 0.0,
        odom_error_p50_m=None if odometry is None else round(odometry.p50_m, 3),
        odom_error_max_m=None if odometry is None else round(odometry.max_m, 3),
        odom_heading_error_max_deg=None if odometry is None else round(odometry.heading_max_deg, 2))


def format_bench(bench: GraphBench) -> str:
    """The figures as text: end to end, then per node."""
    p50 = f"{bench.latency_p50_ms:.0f}" if bench.latency_p50_ms is not None else "-"
    p95 = f"{bench.latency_p95_ms:.0f}" if bench.latency_p95_ms is not None else "-"
    lines = [f"{bench.scenario}, {bench.duration_s:.0f} s measured: {bench.scans} scans ({bench.scan_rate_hz:.2f} Hz), "
             f"/cmd_vel {bench.cmd_vel_rate_hz:.2f} Hz, "
             f"scan -> /cmd_vel p50 {p50} ms p95 {p95} ms, scans dropped end to end {100 * bench.scans_dropped_ratio:.1f} %"
             + ("" if bench.cmd_vel_gap_max_ms is None else f", commands at most {bench.cmd_vel_gap_max_ms:.0f} ms apart"),
             f"the ego drove {bench.distance_m:.0f} m at {bench.average_speed_mps:.1f} m/s on average" + (
                 "" if bench.odom_error_max_m is None else f"; /odom against the truth (first drive): "
                 f"{bench.odom_error_p50_m:.2f} m median, {bench.odom_error_max_m:.2f} m and "
                 f"{bench.odom_heading_error_max_deg:.1f} deg at most"),
             f"{'node':<18} {'ms p50':>7} {'ms p95':>7} {'answered':>9} {'dropped':>8} {'CPU':>6} {'CPU ms/in':>9} "
             f"{'RSS MB':>7} {'MB/10min':>9}"]
    if bench.episodes_requested != 1 and bench.episodes:
        ended = ", ".join(f"{count} {outcome}" for outcome, count in sorted(bench.episodes.items()))
        lines.insert(1, f"drives ended back to back: {ended}")
    elif bench.episode != "running":
        lines.insert(1, f"the drive ended after {bench.episode_time_s:.1f} s of simulated time ({bench.episode}): "
                        "the figures cover the graph until then")
    for row in bench.nodes:
        median = f"{row.processing_ms_median:7.1f}" if row.processing_ms_median is not None else f"{'-':>7}"
        p95_row = f"{row.processing_ms_p95:7.1f}" if row.processing_ms_p95 is not None else f"{'-':>7}"
        per_input = f"{row.cpu_ms_per_scan:9.1f}" if row.cpu_ms_per_scan is not None else f"{'-':>9}"
        lines.append(f"{row.node:<18} {median} {p95_row} {row.answered:9d} {row.dropped:8d} {100 * row.cpu_share:5.0f}% "
                     f"{per_input} {row.rss_mb:7.0f} {row.rss_slope_mb_per_10min:9.2f}")
    return "\n".join(lines)


def bench_graph_command(args: argparse.Namespace) -> int:
    """ssf bench graph."""
    from ssf_bringup.demo import check_scenario, scenario_settings
    from ssf_common.checks import require_finite
    from ssf_common.jsonio import write_json
    from ssf_common.paths import check_writable

    duration = require_finite(args.duration, "--duration", above=0.0)
    if args.json:
        check_writable(args.json, "result file")
    if args.episodes < 0:
        raise ConfigError(f"--episodes must be 0 (back to back until the duration is over) or more, got {args.episodes}")
    parameters = per_node_parameters(args.param)
    spec = bench_graph_spec(args.scenario, args.episodes, parameters)  # unknown node names fail here, before any process
    check_scenario(args.scenario, scenario_settings(spec))  # and a bad scenario or scenario setting
    print(f"bench graph: {args.scenario} in real time for {WARMUP_S:g} + {duration:g} s, every node its own process",
          file=sys.stderr)
    bench = run_bench_graph(duration, args.scenario, sys.stderr if args.verbose else None, args.episodes, parameters)
    print(format_bench(bench))
    if args.json:
        write_json(args.json, asdict(bench))
    return 0


def add_parser(bench_commands: argparse._SubParsersAction) -> None:
    """`ssf bench graph`."""
    parser = bench_commands.add_parser(
        "graph", help="the whole graph in real time: per-node time, drops, CPU, RSS; scan -> /cmd_vel latency and rate",
        description="Runs the full graph (the simulator in real time at 10 Hz, driven by the planner; every node its "
        "own process) and reports, after a warm-up, each node's processing time (median, p95, from /diagnostics), "
        "inputs answered and dropped, CPU share of one core and RSS (with its slope), and end to end the latency from "
        "a scan's stamp to the /cmd_vel that answers it (p50, p95), the /cmd_vel rate and the share of scans "
        "never answered. In real time the fusion loop answers within 0.15 s and after one iteration (each further "
        "one costs a whole flow estimate): -p ssf_fusion_node:fusion.max_iterations:=3 iterates as the demo does.")
    parser.add_argument("--duration", type=float, default=60.0, help="measured seconds after the warm-up (default 60)")
    parser.add_argument("--scenario", default="urban_200", help="scenario (default urban_200)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--episodes", type=int, default=1, help="drives back to back: 1 (default) ends the measurement "
                        "with the first drive; 0 starts the next drive (next seed, the clock from zero, every node "
                        "starting a new sequence) until --duration is over, as a long memory run needs")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NODE:NAME:=VALUE",
                        help="a node's parameter, e.g. -p ssf_fusion_node:fusion.max_iterations:=1 (repeatable)")
    parser.add_argument("--verbose", action="store_true", help="show the nodes' output")
    parser.set_defaults(func=bench_graph_command)
