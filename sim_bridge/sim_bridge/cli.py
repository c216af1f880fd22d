"""`ssf sim`, `ssf dataset export` and `ssf bench sim`."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict
from pathlib import Path

from sim_bridge.options import add_protocol_options, protocol_from_args
from ssf_common.command_groups import CommandGroups
from sim_bridge.scenario import overrides_from_pairs
from ssf_common.checks import require_finite, require_seed
from ssf_common.errors import ConfigError
from ssf_common.jsonio import dumps_strict, write_json
from ssf_common.paths import check_writable


def register(groups: CommandGroups) -> None:
    """Add sim_bridge's commands."""
    sim = groups.top.add_parser(
        "sim",
        help="run the simulator node (scans, /clock and ground truth out, /cmd_vel in)",
        description="Run one episode of a scenario as the sim_bridge node: publish scans, /clock and ground truth, "
        "drive the ego with the built-in route follower (--driver follow) or with /cmd_vel (--driver none), "
        "until success, collision, timeout or --duration; print the summary. --offline runs the same episode "
        "without the middleware, as fast as the machine allows.",
    )
    sim.add_argument("--scenario", required=True, help="shipped scenario name or a YAML file")
    sim.add_argument("--seed", type=int, default=None, help="seed (default: the scenario's)")
    mode = sim.add_mutually_exclusive_group()
    mode.add_argument(
        "--lockstep", dest="realtime", action="store_false",
        help="each step waits for its /cmd_vel, or for --rate with the follower (default; deterministic)",
    )
    mode.add_argument("--realtime", dest="realtime", action="store_true", help="step every 0.1 s of wall time")
    sim.add_argument(
        "--driver", choices=("follow", "none"), default="follow",
        help="the built-in route follower, or none: obey /cmd_vel from a planner",
    )
    sim.add_argument("--rate", type=float, default=10.0, help="lockstep steps per second with the follower; 0 = flat out")
    sim.add_argument("--offline", action="store_true", help="no middleware: the core loop only, as fast as possible")
    sim.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    add_override_option(sim)
    sim.add_argument("--render", type=Path, default=None, metavar="PNG", help="draw a top-down picture of the episode")
    sim.add_argument("--json", type=Path, default=None, metavar="FILE", help="write the episode summary as JSON")
    sim.set_defaults(func=_sim, realtime=False)

    dataset = groups.top.add_parser("dataset", help="simulator datasets with exact ground truth")
    dataset_commands = dataset.add_subparsers(dest="dataset_command", metavar="WHAT", required=True)
    export = dataset_commands.add_parser(
        "export",
        help="write frame pairs with ground-truth flow, a KITTI-style sequence and a JSON description",
        description="Simulate FRAMES steps and write pairs/NNNNNN.npz (pc1 pc2 flow instance1 class1 dynamic1 "
        "pose1 pose2), sequence/velodyne/*.bin + sequence/poses.txt and dataset.json under --out.",
    )
    export.add_argument("--scenario", required=True, help="shipped scenario name or a YAML file")
    export.add_argument("--seed", type=int, default=None)
    export.add_argument("--frames", type=int, required=True, help="number of consecutive pairs")
    export.add_argument("--warmup", type=float, default=None, metavar="S",
                        help="simulated seconds before the first pair, so that the traffic is moving (default: the "
                        "scenario's episode.warmup_s, 2 s unless it says otherwise)")
    export.add_argument("--out", type=Path, required=True)
    add_protocol_options(export)
    add_override_option(export)
    export.set_defaults(func=_export)

    bench = groups.bench.add_parser(
        "sim",
        help="simulator step time and memory per agent count",
        description="Time one full step (agents, ray casting of the scenario's LiDAR (64x1024 rays by default), "
        "ground truth, PointCloud2 + CDR) per agent count; -p changes the scenario (-p lidar.model:=os1_128).",
    )
    bench.add_argument("--agents", default="0,100,500,1000", help="comma-separated agent counts")
    bench.add_argument("--steps", type=int, default=50, help="timed steps per agent count")
    bench.add_argument("--warmup", type=int, default=20, help="untimed steps first, so traffic has formed (default 20)")
    bench.add_argument("--scenario", default="crowd_1000", help="scenario whose agent count is varied")
    bench.add_argument("--seed", type=int, default=None)
    bench.add_argument("--json", type=Path, default=None, metavar="FILE")
    add_override_option(bench)
    bench.set_defaults(func=_bench)


def add_override_option(parser: argparse.ArgumentParser) -> None:
    """-p/--param NAME:=VALUE scenario overrides (--set is an old name of the same option)."""
    parser.add_argument(
        "-p", "--param", dest="set", action="append", default=[], metavar="NAME:=VALUE",
        help="scenario setting, e.g. -p agents.count:=20 (YAML value; NAME=VALUE works too)",
    )
    parser.add_argument("--set", dest="set", action="append", help=argparse.SUPPRESS)


def check_sim_args(args: argparse.Namespace) -> None:
    """Refuse bad numbers and unwritable outputs in one line, before the episode runs."""
    if args.seed is not None:
        require_seed(args.seed)
    if args.duration is not None:
        require_finite(args.duration, "--duration", above=0.0)
    require_finite(args.rate, "--rate", at_least=0.0)
    if args.json:
        check_writable(args.json, "--json summary")
    if args.render:
        check_writable(args.render, "--render picture")


def _sim(args: argparse.Namespace) -> int:
    check_sim_args(args)
    if not args.offline:
        return _sim_node(args)
    return _sim_offline(args)


def _sim_node(args: argparse.Namespace) -> int:
    from sim_bridge.node import SimBridgeNode
    from sim_bridge.scenario import load_scenario
    from ssf_common.middleware import run

    load_scenario(args.scenario, overrides_from_pairs(args.set))  # a bad scenario is a CLI error, before any node starts
    from ssf_common.config import param_text

    parameters: dict[str, object] = {
        "scenario": args.scenario,
        "mode": "realtime" if args.realtime else "lockstep",
        "driver": args.driver,
        "rate": args.rate,
        "seed": -1 if args.seed is None else args.seed,
        "duration_s": args.duration or 0.0,
        "summary": str(args.json) if args.json else "",
        "render": str(args.render) if args.render else "",
    }
    ros_args = ["--ros-args"]
    for name, value in parameters.items():
        if value != "":
            ros_args += ["-p", f"{name}:={param_text(value)}"]
    if args.set:
        ros_args += ["-p", f"overrides:={param_text(list(args.set))}"]
    nodes: list[SimBridgeNode] = []

    def make_node(argv: list[str]) -> SimBridgeNode:
        nodes.append(SimBridgeNode(argv=argv))
        return nodes[-1]

    code = run(make_node, ros_args)
    if code == 0 and nodes and nodes[0].summary is not None:
        print(dumps_strict(nodes[0].summary, indent=None))
    return code


def _sim_offline(args: argparse.Namespace) -> int:
    from sim_bridge.ego import VelocityCommand
    from sim_bridge.scenario import load_scenario
    from sim_bridge.simulator import Simulator, episode_summary

    scenario = load_scenario(args.scenario, overrides_from_pairs(args.set))
    sim = Simulator(scenario, args.seed)
    frame = sim.reset()
    driver = sim.follower() if args.driver == "follow" else None
    limit = scenario.episode.time_limit if args.duration is None else min(args.duration, scenario.episode.time_limit)
    started = time.monotonic()
    report_every = max(1, int(round(10.0 / sim.dt)))
    while not sim.done and frame.status.time < limit - 1e-9:
        command = (
            driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome)
            if driver
            else VelocityCommand()
        )
        frame = sim.step(command)
        if args.realtime:
            time.sleep(max(0.0, started + frame.status.time - time.monotonic()))
        if frame.index % report_every == 0:
            status = frame.status
            print(
                f"t={status.time:6.1f} s  distance {status.distance:7.1f} m  speed {frame.ego.speed:5.2f} m/s",
                file=sys.stderr,
            )
    summary = episode_summary(sim, time.monotonic() - started)
    print(dumps_strict(summary, indent=None))
    if args.json:
        write_json(args.json, summary)
    if args.render:
        from sim_bridge.render import render_episode

        render_episode(sim, args.render)
    return 0


def _export(args: argparse.Namespace) -> int:
    from sim_bridge.dataset.export import export
    from sim_bridge.scenario import load_scenario

    if args.frames < 1:
        raise ConfigError(f"--frames must be at least 1, got {args.frames}")
    protocol = protocol_from_args(args)
    scenario = load_scenario(args.scenario, overrides_from_pairs(args.set))

    def progress(done: int, total: int) -> None:
        print(f"pair {done}/{total}", file=sys.stderr)

    out = export(scenario, args.out, args.seed, args.frames, protocol, progress=progress, warmup_s=args.warmup)
    print(out)
    return 0


def _bench(args: argparse.Namespace) -> int:
    from sim_bridge.bench import run_bench_sim
    from sim_bridge.scenario import load_scenario

    try:
        counts = [int(value) for value in args.agents.split(",") if value.strip()]
    except ValueError:
        raise ConfigError(f"--agents {args.agents!r}: expected comma-separated integers") from None
    if not counts or min(counts) < 0:
        raise ConfigError(f"--agents {args.agents!r}: expected non-negative agent counts")
    if args.steps < 1:
        raise ConfigError(f"--steps must be at least 1, got {args.steps}")
    overrides = overrides_from_pairs(args.set)
    load_scenario(args.scenario, overrides)  # fail fast on a bad name or setting

    def progress(row) -> None:
        print(
            f"{row.agents} agents: median {row.step_ms_median} ms, p95 {row.step_ms_p95} ms, "
            f"peak RSS {row.peak_rss_mb} MB",
            file=sys.stderr,
        )

    if args.warmup < 0:
        raise ConfigError(f"--warmup must not be negative, got {args.warmup}")
    if args.seed is not None:
        require_seed(args.seed)
    if args.json:
        check_writable(args.json, "--json figures")
    rows = run_bench_sim(args.scenario, counts, args.steps, args.seed, args.warmup, progress, overrides)
    payload = [asdict(row) for row in rows]
    print(dumps_strict(payload))
    if args.json:
        write_json(args.json, payload)
    return 0
