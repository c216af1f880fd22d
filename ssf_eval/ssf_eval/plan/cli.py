"""`ssf bench plan`: MPC solve time per obstacle count (the planner core alone, no simulator)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups

MAX_OBSTACLES = 100_000  # a flood; more is a test of memory, not of the planner


def register(groups: CommandGroups) -> None:
    """Add `ssf bench plan`."""
    bench = groups.bench.add_parser(
        "plan", help="MPC solve time (median, p95, max) for 0, 5, 10, 20 obstacles (or a flood: 10000), fallback rate, "
        "peak RSS",
        description="The planner driven closed-loop at the reference speed on a straight road with N obstacles kept "
        "around the ego (vehicles in the neighbouring lanes, pedestrians on the pavements, some crossing); every "
        "tick's solve is timed (one thread). K is raised to N where N exceeds it, up to 50 (every obstacle in the "
        "problem); above 50 (a flood, e.g. 10000, all within range) K stays and the planner's own selection keeps the "
        "obstacles.max_considered nearest. The 0-obstacle row is the baseline of the same run (route tracking alone).")
    bench.add_argument("--obstacles", default="0,5,10,20", help="comma-separated obstacle counts (default 0,5,10,20; "
                       "at most 100000)")
    bench.add_argument("--ticks", type=int, default=300, help="timed ticks per count (default 300)")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--json", type=Path, help="write the rows and the effective config here")
    bench.add_argument("--config", type=Path, help="planner config YAML")
    bench.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                       help="planner config override, e.g. -p solver.qp:=qrqp -p horizon:=12")
    bench.set_defaults(func=run_bench_command)


def run_bench_command(args: argparse.Namespace) -> int:
    """ssf bench plan."""
    import resource

    from ssf_common.config import build, parse_overrides, read_yaml
    from ssf_common.errors import ConfigError
    from ssf_common.paths import check_writable
    from ssf_planner_node.core.bench import run_bench_planner
    from ssf_planner_node.core.config import PlannerConfig

    if args.ticks < 1:
        raise ConfigError(f"--ticks must be at least 1, got {args.ticks}")
    if not 0 <= args.seed <= 2**32 - 1:
        raise ConfigError(f"--seed must be from 0 to 2^32 - 1, got {args.seed}")
    try:
        counts = [int(item) for item in args.obstacles.split(",") if item.strip()]
    except ValueError:
        raise ConfigError(f"--obstacles expects comma-separated integers, got {args.obstacles!r}") from None
    if not counts or min(counts) < 0 or max(counts) > MAX_OBSTACLES:
        raise ConfigError(f"--obstacles expects counts from 0 to {MAX_OBSTACLES}, got {args.obstacles!r}")
    if args.json:
        check_writable(args.json, "result file")
    config = build(PlannerConfig, read_yaml(args.config) if args.config else {}, parse_overrides(args.param, "-p"),
                   source=str(args.config or "-p"))
    rows = []
    print("| obstacles | K | tick ms median | p95 | max | CPU ms median | fallbacks | rounds |", flush=True)
    print("| --- | --- | --- | --- | --- | --- | --- | --- |", flush=True)
    for count in counts:
        row = run_bench_planner(config, count, args.ticks, args.seed)
        rows.append(row)
        print(f"| {row.obstacles} | {row.max_obstacles} | {row.solve_ms_median:.1f} | {row.solve_ms_p95:.1f} | "
              f"{row.solve_ms_max:.1f} | {row.cpu_ms_median:.1f} | {row.fallbacks} ({100 * row.fallback_rate:.2f} %) | "
              f"{row.rounds_mean:.2f} |",
              flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak_rss_mb {peak:.0f}, QP solver {config.solver.qp}, horizon {config.horizon} x {config.dt:g} s",
          file=sys.stderr)
    if args.json:
        from dataclasses import asdict

        from ssf_eval.results import write_result

        write_result(args.json, {"rows": [asdict(row) for row in rows], "peak_rss_mb": round(peak, 1),
                                 "ticks": args.ticks, "seed": args.seed}, {"planner": config})
    return 0
