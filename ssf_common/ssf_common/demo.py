"""`ssf demo`: the closed loop in the simulator, every topic recorded, the episode summarised and drawn."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from importlib import metadata, resources
from pathlib import Path
from typing import Any

from ssf_common import config as config_lib
from ssf_common.checks import require_finite, require_seed
from ssf_common.errors import ConfigError, DataError, SsfError
from ssf_common.jsonio import dumps_strict
from ssf_common.launch import GraphSpec, Launcher, NodeSpec, load_graph
from ssf_common.paths import check_writable_dir
from ssf_common.viewer.command import with_viewer
from ssf_common.viewer.server import ViewerConfig

# what a healthy run must hold: every stage of the loop answered at least once
RECORDED_TOPICS = ("/lidar/points", "/clock", "/sim/episode", "/ssf/flow", "/ssf/mask", "/ssf/semantic_flow",
                   "/ssf/obstacles", "/odom", "/ssf/plan", "/cmd_vel")
SCENARIO_LOADERS = "ssf.scenarios"  # entry points: load_scenario(name_or_path) of the installed simulator
REALTIME_LOOP_TIMEOUT_S = 0.15  # in real time a scan's fusion loop answers within the latency budget (scan -> /cmd_vel)


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
    """The graph with the simulator at wall-clock rate instead of lockstep, and the fusion loop answering within the
    real-time latency budget (in lockstep time stands still while it waits)."""
    nodes = []
    for node in graph.nodes:
        if node.executable == "sim_bridge":
            node = node.model_copy(update={"parameters": {**node.parameters, "mode": "realtime"}})
        if node.executable == "ssf_fusion_node":
            node = node.model_copy(update={"parameters": {**node.parameters, "timeout_s": REALTIME_LOOP_TIMEOUT_S}})
        nodes.append(node)
    return graph.model_copy(update={"nodes": nodes})


def demo_graph(paths: DemoPaths, scenario: str, duration_s: float, seed: int, driver: str = "planner",
               realtime: bool = False) -> GraphSpec:
    """The shipped demo graph with this run's scenario, duration and output paths filled in, in lockstep or in real
    time (the episode picture is drawn from the recording afterwards, see `draw_episode`)."""
    graph = load_graph(Path(str(resources.files("ssf_common") / "graphs" / "demo.yaml")))
    nodes: list[NodeSpec] = []
    for node in graph.nodes:
        if node.executable == "ssf" and node.arguments[:1] == ["record"]:
            node = node.model_copy(update={"arguments": ["record", "-o", str(paths.recording)]})
        if node.executable == "sim_bridge":
            parameters = {
                **node.parameters,
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


def check_scenario(scenario: str) -> None:
    """Read the scenario with the installed simulator's own reader, so that a bad one fails in one line here."""
    for loader in metadata.entry_points(group=SCENARIO_LOADERS):
        loader.load()(scenario)


def check_inputs(scenario: str, duration_s: float, out: Path, seed: int, video: Path | None = None) -> None:
    """Refuse bad flags in one line before any process starts."""
    require_finite(duration_s, "--duration", above=0.0)
    if seed != -1:
        require_seed(seed, "--seed")
    check_scenario(scenario)
    if DemoPaths(out).recording.exists():
        raise ConfigError(f"{DemoPaths(out).recording} already exists; choose another --out")
    check_writable_dir(out, "--out folder")
    if video is not None:
        from ssf_common.render.video import check_video_path

        check_video_path(video, "--video")


def run_demo(scenario: str, duration_s: float, out: Path, seed: int = -1, *, viewer: ViewerConfig | None = None,
             video: Path | None = None, driver: str = "planner", realtime: bool = False) -> int:
    """Run the graph until the episode ends (served live to Foxglove with a viewer config); draw the episode from its
    recording (and animate it to `video`); print where everything is, or what went wrong (exit 1)."""
    check_inputs(scenario, duration_s, out, seed, video)
    paths = DemoPaths(out)
    graph = with_viewer(demo_graph(paths, scenario, duration_s, seed, driver, realtime), viewer)
    try:
        paths.graph.write_text(config_lib.dump(graph))
    except OSError as err:
        raise DataError(f"{paths.graph}: cannot write ({err.strerror})") from None
    who = "the MPC planner on SSF perception" if driver == "planner" else "the built-in route follower"
    pace = "in real time" if realtime else "in lockstep"
    print(f"demo: scenario {scenario}, {duration_s:g} s of simulated driving by {who} {pace}, results in {paths.out}",
          file=sys.stderr)
    start = time.monotonic()
    launcher = Launcher(graph, output=sys.stderr)
    launcher.run()
    print(f"demo: graph stopped after {time.monotonic() - start:.0f} s", file=sys.stderr)
    summary, problems = check_results(paths, launcher)
    if not problems:
        problems = draw_episode(paths, video)
    if problems:
        for problem in problems:
            print(f"demo: {problem}", file=sys.stderr)
        print(f"demo: failed; what is in {paths.out} is incomplete", file=sys.stderr)
        return 1
    printed = {"episode": summary, "recording": str(paths.recording), "picture": str(paths.picture)}
    print(dumps_strict(printed | ({"video": str(video)} if video is not None else {})))
    return 0


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
