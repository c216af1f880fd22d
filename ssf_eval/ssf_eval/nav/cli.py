"""`ssf eval nav`: the paper's closed-loop navigation table, perception source beside perception source."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ssf_common.command_groups import CommandGroups

DEFAULT_AGENTS = "50,100,200,500,800,1000"
DEFAULT_PERCEPTION = "gt,dbscan,dbscan0,ssf,follower"


def register(groups: CommandGroups) -> None:
    """Add `ssf eval nav`."""
    nav = groups.eval.add_parser(
        "nav", help="closed-loop navigation: success rate (Wilson 95 %%), time and speed per perception and density",
        description="Seeded trials of the simulator's route (A -> B in the odometry frame, reference speed 10 m/s) "
        "driven by the RDA-style MPC on each perception source (gt: the simulator's boxes; dbscan / dbscan0: "
        "LiDAR clusters with tracked / zero velocity; ssf: semantic scene flow), and the simulator's rule-based "
        "follower as a reference row. Every finished trial is appended to a JSONL file at once; --resume FILE "
        "skips what it holds. Trial seeds are --seed .. --seed + trials - 1 in every cell.")
    nav.add_argument("--agents", default=DEFAULT_AGENTS, help=f"comma-separated agent counts (default {DEFAULT_AGENTS})")
    nav.add_argument("--perception", default=DEFAULT_PERCEPTION,
                     help=f"comma-separated sources: gt, dbscan, dbscan0, ssf, follower (default {DEFAULT_PERCEPTION})")
    nav.add_argument("--trials", type=int, default=20, help="trials per cell (default 20; the paper: 100)")
    nav.add_argument("--seed", type=int, default=100, help="first trial seed (default 100; tuning used 10-19)")
    nav.add_argument("--route-length", type=float, default=None, metavar="M",
                     help="drive only the first M metres of the route (default: all of it, ~961 m)")
    nav.add_argument("--time-limit", type=float, default=None, metavar="S",
                     help="seconds per trial (default: the scenario's limit scaled to the route length, at least 60)")
    nav.add_argument("--pose", choices=("gt", "ssf"), default="gt", help="ego pose from ground truth or SSF odometry")
    where = nav.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="local process pool size (default: CPU count)")
    where.add_argument("--ray", metavar="ADDRESS", help="run trials on Ray: 'auto', 'ray://HOST:PORT' or 'local' "
                       "(needs pip install '.[ray]')")
    nav.add_argument("--resume", type=Path, metavar="FILE", help="trial log (JSONL) to append to; trials it holds are "
                     "skipped (default: a new nav_trials_<time>.jsonl here)")
    nav.add_argument("--table-only", action="store_true",
                     help="run nothing: the table (and --json, --plot) of the trials the --resume log already holds")
    nav.add_argument("--json", type=Path, help="write the table (one row per cell) and the effective config here")
    nav.add_argument("--plot", type=Path, metavar="PNG", help="success rate, time and speed against agents")
    nav.add_argument("--video-first", type=int, default=0, metavar="N",
                     help="film the first N trials of every cell as bird's-eye videos (default 0: none)")
    nav.add_argument("--video-dir", type=Path, default=Path("nav_videos"), metavar="DIR",
                     help="where the videos go, one PERCEPTION_AGENTS_SEED.mp4 per filmed trial (default nav_videos)")
    nav.add_argument("--video-format", choices=("mp4", "gif"), default="mp4", help="video format (default mp4)")
    nav.add_argument("--latency", type=float, default=0.0, metavar="S",
                     help="perception answers S seconds after its scan, as the real-time graph on a loaded machine "
                     "does (default 0: lockstep)")
    nav.add_argument("--answer-every", type=int, default=1, metavar="N",
                     help="perception answers one scan in N, the others dropped as by a busy node (default 1)")
    nav.add_argument("--graph-bench", type=Path, metavar="JSON",
                     help="perception as late and as rare as a measured real-time graph gives it: --latency and "
                     "--answer-every from the JSON of `ssf bench graph` (its scan -> /cmd_vel median latency and the "
                     "share of scans it answered); the rows are named '(real time)'")
    nav.add_argument("--loop-iterations", type=int, default=1, metavar="N",
                     help="ssf: flow <-> segmentation iterations per scan pair, each scan starting from the previous "
                     "one's mask (default 1, as the real-time graph runs the loop; the demo's lockstep graph uses 3)")
    nav.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                     help="planner config override, e.g. -p horizon:=12 -p obstacles.max_obstacles:=8")
    nav.add_argument("-s", "--scenario-param", action="append", default=[], metavar="NAME:=VALUE",
                     help="scenario setting of every trial's world (the names of `ssf sim -p`), e.g. -s "
                     "agents.ego_yield:=0 (agents keep their way: the ego must give way); part of each trial's key")
    nav.set_defaults(func=run_eval_nav)


def graph_timing(path: Path) -> tuple[float, int]:
    """(latency s, answer every N scans) of a real-time graph from the JSON of `ssf bench graph`: its median scan ->
    /cmd_vel latency, and one scan in round(1 / share answered)."""
    import json

    from ssf_common.errors import ConfigError

    try:
        bench = json.loads(path.read_text())
        latency_ms, dropped = float(bench["latency_p50_ms"]), float(bench["scans_dropped_ratio"])
    except OSError as err:
        raise ConfigError(f"--graph-bench {path}: cannot read it ({err.strerror})") from None
    except (ValueError, KeyError, TypeError):
        raise ConfigError(f"--graph-bench {path}: not the JSON of `ssf bench graph` (latency_p50_ms and "
                          "scans_dropped_ratio needed)") from None
    if not (0.0 <= latency_ms <= 10_000.0 and 0.0 <= dropped < 1.0):
        raise ConfigError(f"--graph-bench {path}: latency_p50_ms {latency_ms:g} or scans_dropped_ratio {dropped:g} "
                          "out of range")
    return round(latency_ms / 1000.0, 3), max(1, round(1.0 / (1.0 - dropped)))


def run_eval_nav(args: argparse.Namespace) -> int:
    """ssf eval nav."""
    import os

    import math

    from ssf_common.config import build, parse_overrides
    from ssf_common.errors import ConfigError
    from ssf_common.paths import check_writable
    from ssf_eval.nav.campaign import LocalRunner, RayRunner, TrialLog, campaign_specs, run_campaign
    from ssf_eval.nav.loop import PERCEPTION_NAMES, scenario_for
    from ssf_eval.nav.stats import summarise
    from ssf_eval.results import write_result
    from ssf_planner_node.core.config import PlannerConfig

    perceptions = [name.strip() for name in args.perception.split(",") if name.strip()]
    unknown = [name for name in perceptions if name not in PERCEPTION_NAMES]
    if unknown or not perceptions:
        raise ConfigError(f"--perception: unknown source '{(unknown or [''])[0]}'; choose from {', '.join(PERCEPTION_NAMES)}")
    agents = _counts(args.agents)
    if args.route_length is not None and not (math.isfinite(args.route_length) and args.route_length >= 20):
        raise ConfigError(f"--route-length must be at least 20 m, got {args.route_length:g}")
    if args.time_limit is not None and not (math.isfinite(args.time_limit) and args.time_limit > 0):
        raise ConfigError(f"--time-limit must be a positive number of seconds, got {args.time_limit:g}")
    if args.trials < 1:
        raise ConfigError(f"--trials must be at least 1, got {args.trials}")
    if not 0 <= args.seed <= 2**32 - 1 - args.trials:
        raise ConfigError(f"--seed must be from 0 to 2^32 - 1 - trials, got {args.seed}")
    if args.graph_bench is not None:
        args.latency, args.answer_every = graph_timing(args.graph_bench)
        print(f"navigation: perception {args.latency:.3f} s late, one scan in {args.answer_every}, as {args.graph_bench} "
              "measured the real-time graph", file=sys.stderr)
    if not (math.isfinite(args.latency) and 0 <= args.latency <= 10):
        raise ConfigError(f"--latency must be from 0 to 10 s, got {args.latency:g}")
    if args.answer_every < 1:
        raise ConfigError(f"--answer-every must be at least 1, got {args.answer_every}")
    if not 1 <= args.loop_iterations <= 20:
        raise ConfigError(f"--loop-iterations must be from 1 to 20, got {args.loop_iterations}")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    overrides = parse_overrides(args.param, "-p")
    planner = build(PlannerConfig, overrides, source="-p")
    scenario = parse_overrides(args.scenario_param, "-s")
    for path, what in ((args.json, "result file"), (args.plot, "picture")):
        if path is not None:
            check_writable(path, what)
    if args.table_only and (args.resume is None or not args.resume.is_file()):
        raise ConfigError("--table-only needs --resume FILE: an existing trial log")
    log_path = args.resume or Path(f"nav_trials_{time.strftime('%Y%m%d_%H%M%S')}.jsonl")
    check_writable(log_path, "trial log")
    for count in sorted(set(agents)):  # a bad setting is one line now, not a failure in every trial
        scenario_for(count, scenario)
    specs = campaign_specs(perceptions, agents, args.trials, args.seed, args.route_length, args.time_limit, args.pose,
                           overrides, scenario, latency_s=args.latency, answer_every=args.answer_every,
                           loop_iterations=args.loop_iterations)
    specs = with_videos(specs, args.video_first, args.video_dir, args.video_format, args.trials)
    runner = RayRunner(args.ray) if args.ray else LocalRunner(args.workers or os.cpu_count() or 1)
    print(f"navigation: {len(specs)} trials ({len(perceptions)} sources x {len(agents)} densities x {args.trials}), "
          f"route {args.route_length or 'full'} m, trial log {log_path}", file=sys.stderr)
    if args.table_only:
        wanted = {_without_pose(spec.key) for spec in specs}  # a log may hold trials of either pose source
        records = [record for record in TrialLog(log_path).records() if _without_pose(record.key) in wanted]
    else:
        records = run_campaign(specs, TrialLog(log_path), runner)
    cells = summarise(records, planner.reference_speed)
    print(format_nav_table(cells))
    failures = format_failures(records)
    if failures:
        print(failures)
    protocol = {"agents": agents, "perception": perceptions, "trials": args.trials, "seed": args.seed,
                "route_length": args.route_length, "time_limit": args.time_limit, "pose": args.pose,
                "latency_s": args.latency, "answer_every": args.answer_every, "loop_iterations": args.loop_iterations,
                "trial_log": str(log_path)}
    if args.json:
        write_result(args.json, {"protocol": protocol, "cells": [cell.to_json() for cell in cells]},
                     {"planner": planner, "protocol": protocol})
    if args.plot:
        from ssf_eval.nav.plot import plot_cells

        counts = sorted({cell.trials for cell in cells}) or [0]
        trials = f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        print(plot_cells(cells, args.plot, f"{trials} trials per cell, route {args.route_length or 'full'} m"),
              file=sys.stderr)
    return 0


def _without_pose(key: str) -> str:
    """A trial key without its pose source (the last part)."""
    return key.rsplit("/", 1)[0]


def with_videos(specs: list, first: int, folder: Path, suffix: str, trials: int) -> list:
    """The specs, the first `first` trials of every cell set to film themselves into `folder`."""
    from dataclasses import replace

    from ssf_common.errors import ConfigError
    from ssf_common.render.video import check_video_path

    if first < 0:
        raise ConfigError(f"--video-first must be 0 or more, got {first}")
    if first == 0:
        return specs
    check_video_path(folder / f"check.{suffix}", "--video-dir")
    filmed = []
    for spec in specs:
        video = ""
        if spec.seed - specs[0].seed < min(first, trials):
            video = str(folder / f"{spec.perception}_{spec.agents}_{spec.seed}.{suffix}")
        filmed.append(replace(spec, video=video))
    return filmed


def format_nav_table(cells) -> str:
    """The paper's table: success (with its interval), time and speed (average, and while moving as the paper's), one
    row per cell."""
    lines = ["| perception | agents | success (95 % CI) | time (s) | avg speed (m/s) | moving speed (m/s) | collisions | "
             "timeouts | stuck | behind a queue | BARN score | trials |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for cell in cells:
        low, high = cell.success_ci95
        time_s = "–" if cell.navigation_time_s is None else f"{cell.navigation_time_s:.1f}"
        speed = "–" if cell.average_speed_mps is None else f"{cell.average_speed_mps:.2f}"
        moving = "–" if cell.moving_speed_mps is None else f"{cell.moving_speed_mps:.2f}"
        lines.append(f"| {cell.source} | {cell.agents} | {cell.success_rate:.2f} ({low:.2f}–{high:.2f}) | {time_s} | "
                     f"{speed} | {moving} | {cell.collisions} | {cell.timeouts} | {cell.stuck} | {cell.queued} | {cell.barn_score:.3f} | "
                     f"{cell.trials} |")
    return "\n".join(lines)


def format_failures(records) -> str:
    """Which worlds each cell failed in and how (seed: outcome, what it hit or how many vehicles stood ahead), to
    compare the sources world by world; empty when every trial succeeded."""
    from ssf_eval.nav.loop import QUEUE_MIN
    from ssf_eval.nav.stats import source_name

    cells: dict[tuple[str, int], list[str]] = {}
    for record in sorted(records, key=lambda record: (record.agents, record.perception, record.pose, record.seed)):
        if record.success:
            continue
        why = record.outcome.replace("_", " ")
        if record.collided_with:
            why += f" ({record.collided_with})"
        elif record.standing_ahead is not None and record.standing_ahead >= QUEUE_MIN:
            why += f" (behind a queue of {record.standing_ahead})"
        late = record.latency_s > 0 or record.answer_every > 1
        cells.setdefault((source_name(record.perception, record.pose, late), record.agents), []).append(
            f"{record.seed} {why}")
    return "\n".join(["failed trials (seed: outcome):"] + [f"- {source}/{agents}: {'; '.join(items)}"
                                                           for (source, agents), items in cells.items()]) if cells else ""


def _counts(text: str) -> list[int]:
    from ssf_common.errors import ConfigError

    try:
        counts = [int(item) for item in text.split(",") if item.strip()]
    except ValueError:
        raise ConfigError(f"--agents expects comma-separated integers, got {text!r}") from None
    if not counts or min(counts) < 0:
        raise ConfigError(f"--agents expects counts >= 0, got {text!r}")
    return counts
