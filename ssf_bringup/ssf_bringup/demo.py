"""`ssf demo`: the closed loop in the simulator, recorded in simulated time, the episode summarised and drawn."""

from __future__ import annotations

import json
import shutil
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata, resources
from pathlib import Path
from typing import Any, NamedTuple

from ssf_bringup.launcher import GraphSpec, Launcher, NodeSpec, load_graph, with_viewer
from ssf_common import config as config_lib
from ssf_common.checks import require_finite, require_seed
from ssf_common.errors import ConfigError, DataError, SsfError
from ssf_common.jsonio import dumps_strict
from ssf_common.paths import check_writable_dir
from ssf_common.viewer.server import ViewerConfig

# What a recording holds by default: what a replay needs to run perception again (the scans, /tf, /clock), what a
# person looks at (the segmentation, obstacles, odometry, plan, commands, markers, the fusion and planner states) and
# the simulator's truth (boxes, poses). The fusion loop's intermediate clouds (/ssf/flow of every iteration,
# /ssf/mask, /ssf/mask_hint) and the per-point truth cloud (/sim/ground_truth/flow) are recorded on request only.
DEFAULT_TOPICS = ("/lidar/points", "/tf", "/clock", "/ssf/semantic_flow", "/ssf/obstacles", "/ssf/fusion_state",
                  "/odom", "/ssf/path", "/ssf/map", "/ssf/plan", "/ssf/planner_state", "/cmd_vel", "/ssf/markers",
                  "/sim/ground_truth/obstacles", "/sim/ground_truth/odom", "/sim/route", "/sim/episode",
                  "/sim/markers", "/vehicle/twist", "/diagnostics")
ON_REQUEST = ("/ssf/flow", "/ssf/mask", "/ssf/mask_hint", "/sim/ground_truth/flow")  # the big clouds left out
# The segmentation of every other scan: 10 Hz of both clouds would not fit the demo's 400 MB (a float cloud's
# coordinates and flow do not compress); `--record-all` or `--record /ssf/semantic_flow` keep every one.
THINNED = {"/ssf/semantic_flow": 2}
# what a healthy run must hold: every stage of the loop answered at least once
RECORDED_TOPICS = ("/lidar/points", "/clock", "/sim/episode", "/ssf/semantic_flow", "/ssf/obstacles", "/odom",
                   "/ssf/plan", "/cmd_vel")
# Recorded bytes per LiDAR ray of a sweep (MCAP, zstd), measured on urban_100 (`ssf demo`, docs/recordings.md), with
# room to spare: the default topics, and every topic.
BYTES_PER_RAY = {"default": 32.0, "all": 170.0}
PROGRESS_PERIOD_S = 30.0  # a long run says how far it is this often
SCENARIO_LOADERS = "ssf.scenarios"  # entry points: load_scenario(name_or_path) of the installed simulator
REALTIME_LOOP_TIMEOUT_S = 0.15  # in real time a scan's fusion loop answers within the latency budget (scan -> /cmd_vel)
REALTIME_ODOMETRY_NICE = 19  # off the critical path in real time: it takes the cores' idle time (docs/realtime.md)


class Recording(NamedTuple):
    """What the demo's recorder records: every topic, or these topics (with some thinned), at /clock time."""

    topics: tuple[str, ...] | None  # None: every topic
    thinned: dict[str, int]

    @classmethod
    def chosen(cls, record_all: bool = False, extra: Sequence[str] = ()) -> Recording:
        """The default topics plus `extra` (recorded whole), or every topic whole."""
        if record_all:
            return cls(None, {})
        thinned = {topic: n for topic, n in THINNED.items() if topic not in extra}
        return cls(tuple(dict.fromkeys([*DEFAULT_TOPICS, *extra])), thinned)

    def recorder_arguments(self, directory: Path) -> list[str]:
        """`ssf record` arguments for this choice."""
        arguments = ["record", "-o", str(directory), "--use-sim-time"]
        for topic, n in self.thinned.items():
            arguments += ["--every", f"{topic}:{n}"]
        return arguments + list(self.topics or ())


@dataclass(frozen=True)
class DemoPaths:
    """Where a demo run writes its results."""

    out: Path

    @property
    def recording(self) -> Path:
        """The rosbag2 (MCAP) directory."""
        return self.out / "recording"

    @property
    def summary(self) -> Path:
        """The episode summary JSON."""
        return self.out / "episode.json"

    @property
    def picture(self) -> Path:
        """The top-down picture of the episode."""
        return self.out / "episode.png"

    @property
    def graph(self) -> Path:
        """The effective graph that ran."""
        return self.out / "graph.yaml"


def in_real_time(graph: GraphSpec) -> GraphSpec:
    """The graph with the simulator at wall-clock rate instead of lockstep, the fusion loop answering within the
    real-time latency budget (in lockstep time stands still while it waits), the planner planning each scan on its
    obstacles, and the odometry, then off the critical path, yielding the cores to the stages on it."""
    nodes = []
    for node in graph.nodes:
        if node.executable == "sim_bridge":
            node = node.model_copy(update={"parameters": {**node.parameters, "mode": "realtime"}})
        if node.executable == "ssf_fusion_node":
            node = node.model_copy(update={"parameters": {**node.parameters, "timeout_s": REALTIME_LOOP_TIMEOUT_S}})
        if node.executable == "ssf_planner_node":
            node = node.model_copy(update={"parameters": {**node.parameters, "plan_on": "scan"}})
        if node.executable == "ssf_odom_node":
            node = node.model_copy(update={"nice": REALTIME_ODOMETRY_NICE})
        nodes.append(node)
    return graph.model_copy(update={"nodes": nodes})


def demo_graph(paths: DemoPaths, scenario: str, duration_s: float, seed: int, driver: str = "planner",
               recording: Recording | None = None, realtime: bool = False,
               sim_settings: dict[str, Any] | None = None) -> GraphSpec:
    """The shipped demo graph with this run's scenario, its settings (`sim_settings`: dotted names over the graph's,
    e.g. lidar.rolling_shutter), duration, recorded topics and output paths filled in, in lockstep or in real time
    (the episode picture is drawn from the recording afterwards, see `draw_episode`)."""
    graph = load_graph(Path(str(resources.files("ssf_bringup") / "graphs" / "demo.yaml")))
    recording = recording or Recording.chosen()
    nodes: list[NodeSpec] = []
    for node in graph.nodes:
        if node.executable == "ssf" and node.arguments[:1] == ["record"]:
            node = node.model_copy(update={"arguments": recording.recorder_arguments(paths.recording)})
        if node.executable == "sim_bridge":
            parameters = {
                **node.parameters,
                **(sim_settings or {}),
                "scenario": scenario,
                "seed": seed,
                "duration_s": duration_s,
                "summary": str(paths.summary),
                "driver": "none" if driver == "planner" else "follow",
            }
            node = node.model_copy(update={"parameters": parameters})
        if node.executable == "ssf_odom_node" and driver != "planner":  # the planner's commands do not drive the car
            node = node.model_copy(update={"parameters": {**node.parameters, "command_topic": ""}})
        nodes.append(node)
    graph = graph.model_copy(update={"nodes": nodes})
    return in_real_time(graph) if realtime else graph


def check_scenario(scenario: str, settings: dict[str, Any] | None = None) -> Any:
    """Read the scenario with its dotted settings with the installed simulator's own reader, so that a bad one fails
    in one line here; the scenario read (None without a simulator)."""
    found = None
    for loader in metadata.entry_points(group=SCENARIO_LOADERS):
        found = loader.load()(scenario, settings or None)
    return found


def scenario_settings(graph: GraphSpec) -> dict[str, Any]:
    """The scenario settings (dotted names, e.g. lidar.rolling_shutter) the graph gives its simulator."""
    sim = next((node for node in graph.nodes if node.executable == "sim_bridge"), None)
    return {} if sim is None else {name: value for name, value in sim.parameters.items() if "." in name}


def recording_estimate(scenario: Any, duration_s: float, recording: Recording) -> int:
    """Bytes the run will record: rays per sweep times sweeps times the measured bytes per ray, of every topic when
    one of the big clouds is asked for (urban_100's LiDAR, 10 Hz, when the scenario does not say)."""
    spec = scenario.lidar.spec() if scenario is not None and hasattr(scenario, "lidar") else None
    rays, period = (spec.rays, spec.period) if spec is not None else (64 * 1024, 0.1)
    big = recording.topics is None or bool(set(recording.topics) & set(ON_REQUEST))
    per_ray = BYTES_PER_RAY["all" if big else "default"]
    return int(rays * per_ray * (duration_s / period + 1))


def check_disk(out: Path, needed: int, duration_s: float) -> None:
    """Refuse, in one line, a run whose recording will not fit on the disk of `out`."""
    from ssf_common.bags.info import size_text

    free = shutil.disk_usage(out).free
    if free < needed:
        raise ConfigError(f"{out}: {size_text(free)} free, but {duration_s:g} s of driving record about "
                          f"{size_text(needed)}; free some space, choose another --out or a shorter --duration")


def check_inputs(scenario: str, duration_s: float, out: Path, seed: int, video: Path | None = None,
                 recording: Recording | None = None, settings: dict[str, Any] | None = None) -> None:
    """Refuse bad flags (`settings`: the scenario's dotted ones), and a disk too full for the recording, in one line
    before any process starts."""
    from ssf_common.bags.record import check_topic_name

    require_finite(duration_s, "--duration", above=0.0)
    if seed != -1:
        require_seed(seed, "--seed")
    recording = recording or Recording.chosen()
    for topic in recording.topics or ():
        check_topic_name(topic)
    read = check_scenario(scenario, settings)
    if DemoPaths(out).recording.exists():
        raise ConfigError(f"{DemoPaths(out).recording} already exists; choose another --out")
    check_writable_dir(out, "--out folder")
    if video is not None:
        from ssf_common.render.video import check_video_path

        check_video_path(video, "--video")
    check_disk(out, recording_estimate(read, duration_s, recording), duration_s)


def run_demo(scenario: str, duration_s: float, out: Path, seed: int = -1, *, viewer: ViewerConfig | None = None,
             video: Path | None = None, driver: str = "planner", recording: Recording | None = None,
             realtime: bool = False, sim_settings: dict[str, Any] | None = None) -> int:
    """Run the graph until the episode ends (served live to Foxglove with a viewer config, saying how far it is every
    half minute); draw the episode from its recording (and animate it to `video`); print where everything is and
    how big the recording is, or what went wrong (exit 1)."""
    recording = recording or Recording.chosen()
    paths = DemoPaths(out)
    graph = demo_graph(paths, scenario, duration_s, seed, driver, recording, realtime, sim_settings)
    check_inputs(scenario, duration_s, out, seed, video, recording, scenario_settings(graph))
    graph = with_viewer(graph, viewer)
    clock = SimClock()  # a middleware that cannot start here (ROS_DOMAIN_ID, rclpy) fails in one line, before any node
    try:
        paths.graph.write_text(config_lib.dump(graph))
    except OSError as err:
        clock.close()
        raise DataError(f"{paths.graph}: cannot write ({err.strerror})") from None
    who = "the MPC planner on SSF perception" if driver == "planner" else "the built-in route follower"
    pace = "in real time" if realtime else "in lockstep"
    print(f"demo: scenario {scenario}, {duration_s:g} s of simulated driving by {who} {pace}, results in {paths.out}",
          file=sys.stderr)
    start = time.monotonic()
    launcher = Launcher(graph, output=sys.stderr)
    try:
        with Progress(duration_s, lambda line: launcher.say("demo", line), paths.recording, clock):
            launcher.run()
    finally:
        clock.close()
    print(f"demo: graph stopped after {time.monotonic() - start:.0f} s", file=sys.stderr)
    summary, problems = check_results(paths, launcher)
    if not problems:
        problems = draw_episode(paths, video)
    if problems:
        for problem in problems:
            print(f"demo: {problem}", file=sys.stderr)
        print(f"demo: failed; what is in {paths.out} is incomplete", file=sys.stderr)
        return 1
    size = folder_bytes(paths.recording)
    print(f"demo: recording {paths.recording}: {_size_text(size)} ({_episode_words(summary)}; `ssf bag play` replays "
          "it in simulated time)", file=sys.stderr)
    printed = {"episode": summary, "recording": str(paths.recording), "recording_bytes": size,
               "picture": str(paths.picture)}
    print(dumps_strict(printed | ({"video": str(video)} if video is not None else {})))
    return 0


def folder_bytes(folder: Path) -> int:
    """The size of every file under a folder."""
    return sum(path.stat().st_size for path in folder.rglob("*") if path.is_file())


def _size_text(count: int) -> str:
    from ssf_common.bags.info import size_text

    return size_text(count)


def _episode_words(summary: dict[str, Any] | None) -> str:
    """How the episode ended, in words: `duration reached after 20.0 s, 157 m driven`."""
    if not summary:
        return "no episode summary"
    outcome = {"running": "duration reached", "success": "goal reached", "collision": "collision",
               "timeout": "the scenario's time limit reached"}.get(summary.get("outcome", ""), summary.get("outcome"))
    with_what = f" with {summary['collided_with']}" if summary.get("collided_with") else ""
    return f"{outcome}{with_what} after {summary.get('time', 0):.1f} s, {summary.get('distance', 0):.0f} m driven"


class SimClock:
    """The graph's simulated time, read from /clock by a node spinning on a thread of this process."""

    def __init__(self) -> None:
        from ssf_common import topics
        from ssf_common.middleware import QOS_CLOCK, Node

        self.sim_ns = 0
        self.first: tuple[float, int] | None = None  # (monotonic s, sim ns) of the first tick seen
        self.node = Node("ssf_demo_progress", argv=[])
        self.node.create_subscription("rosgraph_msgs/msg/Clock", topics.CLOCK, self._on_clock, QOS_CLOCK)
        self._thread = self.node.spin_in_thread()

    def _on_clock(self, msg: Any) -> None:
        from ssf_common import messages

        self.sim_ns = messages.stamp_ns(msg.clock)
        if self.first is None:
            self.first = (time.monotonic(), self.sim_ns)

    def elapsed(self) -> tuple[float, float]:
        """(simulated s, wall s) since the first tick."""
        if self.first is None:
            return 0.0, 0.0
        return (self.sim_ns - self.first[1]) * 1e-9, time.monotonic() - self.first[0]

    def close(self) -> None:
        """Stop the node."""
        self.node.request_shutdown()
        self._thread.join(timeout=5.0)
        self.node.destroy_node()


class Progress:
    """Says every half minute how far the run is in simulated time, how fast against the wall clock, and how big the
    recording has grown (a context manager around the run)."""

    def __init__(self, total_s: float, say: Callable[[str], None], recording: Path, clock: SimClock | None = None,
                 period_s: float = PROGRESS_PERIOD_S) -> None:
        self.total_s = total_s
        self.say = say
        self.recording = recording
        self.clock = clock
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def line(self, sim_s: float, wall_s: float, recorded: int) -> str:
        """One progress line."""
        from ssf_common.progress import sim_time_line

        return f"{sim_time_line(sim_s, self.total_s, wall_s)}; recording {_size_text(recorded)}"

    def _report(self) -> None:
        while not self._stop.wait(self.period_s):
            sim_s, wall_s = self.clock.elapsed() if self.clock is not None else (0.0, 0.0)
            recorded = folder_bytes(self.recording) if self.recording.is_dir() else 0
            self.say(self.line(sim_s, wall_s, recorded))

    def __enter__(self) -> Progress:
        self._thread = threading.Thread(target=self._report, daemon=True, name="demo-progress")
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)


def draw_episode(paths: DemoPaths, video: Path | None) -> list[str]:
    """The episode picture (and the animation) drawn from the recording; one line per failure."""
    from ssf_common.render.video import render_recording

    print("demo: drawing the episode from the recording", file=sys.stderr)
    try:
        render_recording(paths.recording, picture=paths.picture, video=video, progress=sys.stderr)
    except SsfError as err:
        return [f"cannot draw the episode: {err}"]
    return []


def check_results(paths: DemoPaths, launcher: Launcher) -> tuple[dict[str, Any] | None, list[str]]:
    """The episode summary, and one line per thing that went wrong: a node that died, a damaged recording."""
    from ssf_common.bags.reader import open_bag

    problems = [f"{label} {failure}" for label, failure in launcher.failures]
    failed = {label for label, _ in launcher.failures}
    problems += [f"{label} crashed (exit code {code}) and was restarted" for label, code in launcher.crashes
                 if label not in failed]
    summary = None
    if not paths.summary.is_file():
        problems.append(f"the simulator wrote no episode summary to {paths.summary}")
    else:
        try:
            summary = json.loads(paths.summary.read_text())
        except (OSError, ValueError) as err:
            problems.append(f"the episode summary {paths.summary} is unreadable ({type(err).__name__})")
    try:
        with open_bag(paths.recording) as bag:
            info, topics = bag.info, bag.topics
    except SsfError as err:
        problems.append(f"the recording cannot be read: {err}")
    else:
        if info.damage:
            problems.append(f"the recording is damaged: {'; '.join(info.damage)}")
        empty = [name for name in RECORDED_TOPICS if not topics.get(name) or not topics[name].message_count]
        if empty:
            problems.append(f"the recording holds no {', '.join(empty)}")
    return summary, problems
