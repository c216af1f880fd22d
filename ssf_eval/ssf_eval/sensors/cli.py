"""`ssf eval sensors`: the issue-12 table, every LiDAR model on every stress scenario, held-out seeds."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups

STRESS_SCENARIOS = ("stress_junction", "stress_queue", "stress_crossing", "stress_parked", "stress_far")


def register(groups: CommandGroups) -> None:
    """Add `ssf eval sensors`."""
    from sim_bridge.options import add_protocol_options
    from sim_bridge.sensors import sensor_names
    from ssf_eval.seg.cli import add_perception_options

    evaluate = groups.eval.add_parser(
        "sensors", help="flow and segmentation per LiDAR model x scenario: dynamic EPE, ego-only EPE, moving IoU",
        description="Each sensor model on each scenario over several seeds, with the nodes' default configuration: "
        "`rigid` and `ego` flow given the masks the fusion loop would give them, the default segmenter on the maskless "
        "`rigid` flow, and the whole fusion loop as the graph runs it (each pair's segmentation carried to the next as its "
        "preliminary mask; what the graph publishes). One table, one row per "
        "sensor x scenario, pooled over seeds and pairs; targets (dynamic EPE <= 0.15 m and <= 0.4 x ego motion "
        "alone, moving IoU >= 0.80) are judged on the loop. Pairs are whole scans by default, as the nodes see them.")
    evaluate.add_argument("--sensors", nargs="+", default=list(sensor_names()), metavar="NAME",
                          help=f"sensor models, comma- or space-separated (default: {','.join(sensor_names())})")
    evaluate.add_argument("--scenarios", nargs="+", default=list(STRESS_SCENARIOS), metavar="NAME",
                          help=f"scenarios, comma- or space-separated (default: {','.join(STRESS_SCENARIOS)})")
    evaluate.add_argument("--seeds", default="0-4", help="simulator seeds, e.g. 0-4 or 0,2,5 (default 0-4: never used "
                          "in training or tuning)")
    evaluate.add_argument("--frames", type=int, default=10, help="pairs per seed (default 10)")
    evaluate.add_argument("--warmup", type=float, default=None, metavar="S",
                          help="simulated seconds before the first pair (default: each scenario's episode.warmup_s)")
    evaluate.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                          help="scenario setting for every cell, e.g. --sim-param lidar.rate_hz:=20 (repeatable)")
    evaluate.add_argument("--masks", choices=("none", "noisy", "gt"), default="noisy",
                          help="mask given to `rigid` and `ego` (default noisy, as `ssf eval flow`); the loop makes its own")
    evaluate.add_argument("--json", type=Path, help="write the cells here (and the effective config beside them)")
    evaluate.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    add_protocol_options(evaluate)
    evaluate.set_defaults(protocol="whole")
    add_perception_options(evaluate)
    evaluate.set_defaults(func=run_eval_sensors)


def names(values: list[str]) -> list[str]:
    """NAME lists given space- or comma-separated."""
    return [name for value in values for name in value.split(",") if name.strip()]


def seed_list(text: str) -> list[int]:
    """Seeds from '0-4', '0,2,5' or a mix."""
    from ssf_common.checks import require_seed
    from ssf_common.errors import ConfigError

    seeds: list[int] = []
    try:
        for part in (item.strip() for item in text.split(",")):
            low, dash, high = part.partition("-")
            span = range(int(low), int(high) + 1) if dash else [int(low)]
            seeds += [require_seed(seed, "--seeds") for seed in span]
    except ValueError:
        raise ConfigError(f"--seeds {text!r}: expected seeds like 0-4 or 0,2,5") from None
    if not seeds or len(seeds) > 1000:
        raise ConfigError(f"--seeds {text!r}: expected between 1 and 1000 seeds")
    return seeds


def run_eval_sensors(args: argparse.Namespace) -> int:
    """ssf eval sensors."""
    import torch

    from sim_bridge.scenario import load_scenario, overrides_from_pairs
    from sim_bridge.sensors import sensor_names
    from sim_bridge.simulator import place_traffic
    from sim_bridge.world import World
    from ssf_common.errors import ConfigError
    from ssf_common.paths import check_writable
    from ssf_eval.flow.evaluate import MaskSource
    from ssf_eval.results import write_result
    from ssf_eval.seg.cli import perception_config
    from ssf_eval.sensors.evaluate import SensorEvaluator, Targets, cell_record, cell_scores, format_cells
    from ssf_eval.sources import protocol_from_args, simulator_pairs

    if args.json:
        check_writable(args.json, "result file")
    sensors, scenarios, seeds = names(args.sensors), names(args.scenarios), seed_list(args.seeds)
    unknown = sorted(set(sensors) - set(sensor_names()))
    if unknown:
        raise ConfigError(f"--sensors: unknown sensor model '{unknown[0]}'; choose from {', '.join(sensor_names())}")
    if args.frames < 1:
        raise ConfigError(f"--frames must be at least 1, got {args.frames}")
    shared = overrides_from_pairs(args.sim_param, "--sim-param")
    plans = {(sensor, name): load_scenario(name, {**shared, "lidar.model": sensor})  # every cell checked first
             for name in scenarios for sensor in sensors}
    for name in scenarios:  # and every seed's traffic placed: a long run never stops half-way on a crowded seed
        for seed in seeds:
            place_traffic(World(plans[sensors[0], name], seed), seed)
    protocol = protocol_from_args(args)
    configs = {cell: perception_config(args, scenario) for cell, scenario in plans.items()}
    torch.set_num_threads(args.threads)
    targets, cells = Targets(), []
    for (sensor, name), config in configs.items():
        evaluator = SensorEvaluator(config, MaskSource(args.masks), args.device)
        parts = []
        for seed in seeds:
            source = simulator_pairs(name, seed, args.frames, protocol, args.warmup, {**shared, "lidar.model": sensor})
            print(f"{sensor} on {source.description}", file=sys.stderr, flush=True)
            parts.append(evaluator.run(source.pairs, seed))
        cells.append(cell_scores(sensor, name, seeds, parts))
        print(format_cells(cells[-1:], targets).splitlines()[-1], file=sys.stderr, flush=True)
        if args.json:  # after every cell, so that a long run leaves what it measured
            write_result(args.json, {"complete": len(cells) == len(configs), "seeds": seeds, "frames": args.frames,
                                     "protocol": protocol, "masks": args.masks, "sim_params": shared,
                                     "targets": targets._asdict(), "cells": [cell_record(c, targets) for c in cells]},
                         {"perception": next(iter(configs.values())), "sensors": sensors, "scenarios": scenarios,
                          "sim_params": shared, "warmup_s": args.warmup, "protocol": protocol})
    print(f"perception per sensor and scenario: seeds {args.seeds}, {args.frames} pairs each, protocol {args.protocol}, "
          f"masks for rigid/ego: {args.masks}")
    print(format_cells(cells, targets))
    return 0
