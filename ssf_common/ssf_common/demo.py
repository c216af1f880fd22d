"""`ssf demo`: the closed loop in the simulator, every topic recorded, the episode summarised and drawn."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from ssf_common import config as config_lib
from ssf_common.launch import GraphSpec, Launcher, NodeSpec, load_graph


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


def demo_graph(paths: DemoPaths, scenario: str, duration_s: float, seed: int) -> GraphSpec:
    """The shipped demo graph with this run's scenario, duration and output paths filled in."""
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
                "render": str(paths.picture),
            }
            node = node.model_copy(update={"parameters": parameters})
        nodes.append(node)
    return graph.model_copy(update={"nodes": nodes})


def run_demo(scenario: str, duration_s: float, out: Path, seed: int = -1) -> int:
    """Run the graph until the episode ends; print where everything is."""
    paths = DemoPaths(out)
    if paths.recording.exists():
        from ssf_common.errors import ConfigError

        raise ConfigError(f"{paths.recording} already exists; choose another --out")
    paths.out.mkdir(parents=True, exist_ok=True)
    graph = demo_graph(paths, scenario, duration_s, seed)
    paths.graph.write_text(config_lib.dump(graph))
    print(f"demo: scenario {scenario}, {duration_s:g} s of simulated driving, results in {paths.out}", file=sys.stderr)
    start = time.monotonic()
    code = Launcher(graph, output=sys.stderr).run()
    print(f"demo: graph stopped after {time.monotonic() - start:.0f} s", file=sys.stderr)
    if not paths.summary.is_file():
        print("demo: the simulator wrote no episode summary (see the log above)", file=sys.stderr)
        return 1
    summary = json.loads(paths.summary.read_text())
    print(json.dumps({"episode": summary, "recording": str(paths.recording), "picture": str(paths.picture)}, indent=2))
    return code
