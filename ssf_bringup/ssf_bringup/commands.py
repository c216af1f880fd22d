"""`ssf` commands of the application: launch, demo, view, render, record, bag, bench transport, view, graph and faults."""

from __future__ import annotations

import argparse

from ssf_common.command_groups import CommandGroups
from ssf_common.viewer.command import add_foxglove_options


def register(groups: CommandGroups) -> None:
    """Add the application's commands (the library's own among them)."""
    from ssf_common.render import command as render
    from ssf_common.viewer import command as view

    _register_graph_commands(groups)
    view.add_parser(groups.top)
    render.add_parser(groups.top)
    _register_bag_commands(groups)
    _register_bench_commands(groups)


def _register_graph_commands(groups: CommandGroups) -> None:
    launch = groups.top.add_parser(
        "launch",
        help="start a graph of node processes from a YAML file and supervise them",
        description="Start every node of GRAPH.yaml as its own process (as `ros2 run` would), prefix their "
        "output with the node name, restart crashed nodes (up to max_restarts), and stop them all on "
        "Ctrl-C or SIGTERM.",
    )
    launch.add_argument("graph", help="graph file: nodes: [{executable, name, parameters, remappings, ...}]")
    launch.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    launch.add_argument(
        "-p", "--param", action="append", default=[], metavar="NAME:=VALUE", help="parameter given to every node"
    )
    add_foxglove_options(launch)
    launch.set_defaults(func=_launch)

    demo = groups.top.add_parser(
        "demo",
        help="the main job: the closed loop in the simulator, recorded",
        description="Run the whole graph as node processes (sim_bridge -> flow ⇄ segmentation ⇄ fusion -> odometry -> "
        "planner -> sim_bridge) for --duration seconds of simulated driving in lockstep, record it to MCAP in "
        "simulated time, and write the episode summary and a picture drawn from the recording to --out. The MPC "
        "planner drives on SSF perception; --driver follow lets the simulator's built-in route follower drive instead. "
        "The recording holds what a replay needs to run perception again and what a person looks at (about 17 MB per "
        "simulated second on urban_100: 354 MB for the default 20 s); --record-all adds the fusion loop's "
        "intermediate clouds and the per-point truth (about 95 MB per second).",
    )
    demo.add_argument("--scenario", default="urban_100", help="scenario name or YAML file (default urban_100)")
    demo.add_argument("--duration", type=float, default=20.0, help="seconds of simulated driving (default 20)")
    demo.add_argument("--seed", type=int, default=-1, help="scenario seed (default: the scenario's own)")
    demo.add_argument("--out", default=None, help="output folder (default bags/demo_<time>)")
    demo.add_argument("--driver", choices=("planner", "follow"), default="planner",
                      help="who drives: the MPC planner on SSF perception (default) or the built-in route follower")
    demo.add_argument("--realtime", action="store_true",
                      help="run the simulator at wall-clock 10 Hz: the stages answer what they can in real time, as on a "
                      "car (what `ssf bench graph` measures). Default: lockstep, where the simulator waits for each "
                      "command, so every scan is answered and a slow machine drives the same route, only slower")
    demo.add_argument("--video", metavar="FILE", default=None,
                      help="after the run, render a bird's-eye animation of the recording to FILE (.mp4 or .gif)")
    demo.add_argument("--record-all", action="store_true",
                      help="record every topic, the fusion loop's intermediate clouds (/ssf/flow of every iteration, "
                      "/ssf/mask, /ssf/mask_hint) and the per-point truth (/sim/ground_truth/flow) included")
    demo.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                      help="a scenario setting of the simulator, over the graph's (repeatable); the graph sweeps each "
                      "LiDAR column at its own time, deskewed by the flow and the odometry: --sim-param "
                      "lidar.rolling_shutter:=false casts instant sweeps")
    demo.add_argument("--record", nargs="+", default=[], metavar="TOPIC",
                      help="also record these topics (e.g. /ssf/flow /ssf/mask), and every /ssf/semantic_flow when "
                      "named (by default every other scan's)")
    add_foxglove_options(demo)
    demo.set_defaults(func=_demo)


def _launch(args: argparse.Namespace) -> int:
    from ssf_bringup.launcher import Launcher, load_graph, with_viewer
    from ssf_common.config import parse_overrides
    from ssf_common.viewer.command import viewer_config

    viewer = viewer_config(args, "ssf launch")
    graph = with_viewer(load_graph(args.graph, parse_overrides(args.param, "-p")), viewer)
    return Launcher(graph).run(args.duration)


def _register_bag_commands(groups: CommandGroups) -> None:
    from ssf_common.bags import info, play, record

    record.add_parser(groups.top)
    bag = groups.top.add_parser("bag", help="inspect and replay rosbag2 bags (MCAP or sqlite3)")
    bag_commands = bag.add_subparsers(dest="bag_command", metavar="WHAT", required=True)
    info.add_parser(bag_commands)
    play.add_parser(bag_commands)


def _demo(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from ssf_bringup.demo import Recording, run_demo
    from ssf_common.config import parse_overrides
    from ssf_common.errors import ConfigError
    from ssf_common.viewer.command import viewer_config

    if args.record_all and args.record:
        raise ConfigError("--record-all records every topic already; give it or --record TOPIC ..., not both")
    out = Path(args.out) if args.out else Path("bags") / time.strftime("demo_%Y%m%d_%H%M%S")
    video = Path(args.video) if args.video else None
    return run_demo(args.scenario, args.duration, out, args.seed, viewer=viewer_config(args, "ssf demo"), video=video,
                    driver=args.driver, recording=Recording.chosen(args.record_all, args.record),
                    realtime=args.realtime, sim_settings=parse_overrides(args.sim_param, "--sim-param"))


def _register_bench_commands(groups: CommandGroups) -> None:
    transport = groups.bench.add_parser(
        "transport",
        help="PointCloud2 serialisation and two-process latency over the middleware",
        description="Serialise/deserialise 131072-point clouds, then publish 8192- and 131072-point clouds "
        "at --rate for --duration seconds each from this process to a subscriber process, and report "
        "medians, p99 latencies and the share received over best-effort QoS.",
    )
    transport.add_argument("--rate", type=float, default=10.0, help="publish rate in Hz (default 10)")
    transport.add_argument("--duration", type=float, default=20.0, help="seconds per cloud size (default 20)")
    transport.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    transport.set_defaults(func=_bench_transport)
    from ssf_bringup import bench_faults, bench_graph
    from ssf_bringup import bench_view as view_bench

    view_bench.add_parser(groups.bench)
    bench_graph.add_parser(groups.bench)
    bench_faults.add_parser(groups.bench)


def _bench_transport(args: argparse.Namespace) -> int:
    from ssf_common.bench_transport import bench_transport_command

    return bench_transport_command(args)
