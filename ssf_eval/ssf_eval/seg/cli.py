"""`ssf seg estimate`, `ssf eval seg`, `ssf eval fusion`, `ssf bench seg` and `ssf bench fusion`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ssf_common.command_groups import CommandGroups
from ssf_eval.sources import add_pair_source_options

DEFAULT_METHODS = ("geometric", "gmm", "dbscan", "pointnet", "ogc", "ssf")


def register(groups: CommandGroups) -> None:
    """Add the segmentation and fusion commands."""
    seg = groups.top.add_parser("seg", help="semantic scene flow for two scans: flow ⇄ segmentation, obstacles")
    seg_commands = seg.add_subparsers(dest="seg_command", metavar="WHAT", required=True)
    estimate = seg_commands.add_parser(
        "estimate", help="the flow ⇄ segmentation loop on two scan files (.npy, KITTI .bin, .pcd, .ply)",
        description="Runs the whole loop (scene flow conditioned on the mask, segmentation of points and flow, until "
        "they agree) on two whole scans and writes, for every finite point of PC1, float32 columns: dynamic "
        "probability, label (0 static, 1 dynamic), instance id, flow x y z. --obstacles writes every obstacle as JSON "
        "in PC1's sensor frame, as the fusion node publishes them: each moving object (moving: true, its velocity in "
        "m/s from the flow) and the still part of the scan as boxes (moving: false: parked cars, poles, walls), each "
        "with id, kind (vehicle, pedestrian or unknown), centre, size, yaw and points.")
    estimate.add_argument("pc1", type=Path, help="scan t")
    estimate.add_argument("pc2", type=Path, help="scan t+1")
    estimate.add_argument("--method", default=None, help="segmenter (default geometric; see `ssf eval seg --help`)")
    estimate.add_argument("--flow-estimator", default=None, help="flow estimator (default rigid)")
    estimate.add_argument("--iterations", type=int, default=None, help="N_iter of the loop (default 5)")
    estimate.add_argument("--dt", type=float, default=None, help="seconds between the scans (default 0.1)")
    estimate.add_argument("--out", type=Path, required=True, help="output SEG.npy (N, 6) float32")
    estimate.add_argument("--obstacles", type=Path, help="also write every obstacle, moving and still, as JSON")
    add_perception_options(estimate)
    estimate.set_defaults(func=run_estimate_seg)

    evaluate = groups.eval.add_parser(
        "seg", help="the paper's segmentation table: accuracy, moving IoU, instances, obstacles, per method × input",
        description="Every segmenter on the same pairs and the same flow (the `rigid` estimate by default), plus the "
        "fusion loop (`ssf`: flow ⇄ segmentation until they agree). Columns: static/dynamic accuracy, balanced "
        "accuracy, moving-class IoU, instance precision/recall/F1/PQ at IoU >= 0.5 (objects under 50 points "
        "ignored), obstacle position and velocity errors (medians), missed moving objects and phantoms per 10 "
        "frames, ms per scan, loop iterations.")
    add_pair_source_options(evaluate, default_frames=10)
    add_seeds_option(evaluate)
    evaluate.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), metavar="M",
                          help=f"segmenters and/or 'ssf' (default: {' '.join(DEFAULT_METHODS)}; missing weights are skipped)")
    evaluate.add_argument("--inputs", nargs="+", default=["both"], choices=("points", "flow", "both"),
                          help="what the segmenters look at (the paper's columns; default both)")
    evaluate.add_argument("--flow", choices=("rigid", "gt"), default="rigid",
                          help="flow given to the segmenters: the rigid estimate, or ground truth (default rigid)")
    add_eval_outputs(evaluate)
    evaluate.set_defaults(func=run_eval_seg)

    fusion = groups.eval.add_parser(
        "fusion", help="the loop's ablation: flow EPE and segmentation IoU after every iteration, convergence",
        description="Runs the fusion loop for up to N_iter iterations on every pair and reports, after each "
        "iteration, EPE3D of all and dynamic points, moving-class IoU, accuracy and the share of frames converged "
        "(frames that converged earlier keep their answer). --plot draws the paper's ablation figure.")
    add_pair_source_options(fusion, default_frames=10)
    add_seeds_option(fusion)
    fusion.add_argument("--iterations", type=int, default=5, help="N_iter of the ablation (default 5; the graph runs "
                        "one, -p fusion.max_iterations)")
    add_eval_outputs(fusion)
    fusion.add_argument("--plot", type=Path, help="PNG of error and IoU against the iteration")
    fusion.set_defaults(func=run_eval_fusion)

    bench_seg = groups.bench.add_parser("seg", help="ms per segmentation at 8192 points per segmenter, peak RSS")
    bench_seg.add_argument("--methods", nargs="+", default=["geometric"], metavar="M")
    add_bench_options(bench_seg)
    bench_seg.set_defaults(func=run_bench_seg)
    bench_fusion = groups.bench.add_parser(
        "fusion", help="CPU ms per scan of each stage of the perception chain on whole scans: flow, segmentation, "
        "fusion (obstacles, the next scan's prior), against the real-time budget",
        description="Streams consecutive pairs of whole scans through the one perception chain (what the nodes run) "
        "and reports each stage's CPU time per scan (median, p95): the flow node's work (carrying the temporal prior, "
        "the estimate), the segmentation node's and the fusion node's (the loop's decision, obstacles moving and still, "
        "what the next scan's prior is made of), beside the budget of each.")
    add_bench_options(bench_fusion)
    bench_fusion.add_argument("--protocol", choices=("whole", "paper"), default="whole",
                              help="whole: every point of every scan, as the nodes see them (default); paper: 8192 "
                              "points, ground removed")
    bench_fusion.set_defaults(func=run_bench_fusion)


def add_seeds_option(parser: argparse.ArgumentParser) -> None:
    """--seeds: several simulator episodes, each a sequence of consecutive pairs, pooled in one table."""
    parser.add_argument("--seeds", type=int, nargs="+", metavar="N",
                        help="simulator seeds to pool (each its own sequence of --frames pairs); overrides --seed")


def sequences_from_args(args: argparse.Namespace):
    """The pairs of every requested seed, one after the other, the indices where a sequence starts, and a source
    description."""
    import numpy as np

    from ssf_eval.sources import PairSet, pairs_from_args

    seeds = args.seeds if args.seeds and args.scenario else [args.seed]
    sets = [pairs_from_args(argparse.Namespace(**{**vars(args), "seed": seed})) for seed in seeds]
    pairs = [pair for pairs in sets for pair in pairs.pairs]
    starts = set(np.cumsum([0] + [len(one.pairs) for one in sets[:-1]]).tolist())
    if len(sets) == 1:
        return sets[0], starts
    description = f"scenario {args.scenario} seeds {' '.join(map(str, seeds))}, {len(pairs)} pairs"
    return PairSet(pairs, description, {**sets[0].source, "seed": seeds, "pairs": len(pairs)}), starts


def add_perception_options(parser: argparse.ArgumentParser) -> None:
    """--config and -p for the perception config (flow.*, seg.*, fusion.*, obstacles.*, scan_period)."""
    parser.add_argument("--config", type=Path,
                        help="perception config YAML (flow.*, seg.*, fusion.*, obstacles.*, scan_period)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="override one perception config value, e.g. -p seg.geometric.min_speed:=0.5")
    parser.add_argument("--device", default="cpu", help="torch device for network methods")


def add_eval_outputs(parser: argparse.ArgumentParser) -> None:
    """--json, --threads and the perception config."""
    parser.add_argument("--json", type=Path, help="write the results here (and the effective config beside them)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    add_perception_options(parser)


def add_bench_options(parser: argparse.ArgumentParser) -> None:
    """Pairs and outputs of the speed benchmarks."""
    parser.add_argument("--frames", type=int, default=20, help="timed frames (default 20)")
    parser.add_argument("--scenario", default="urban_200", help="simulator scenario the pairs come from")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    add_perception_options(parser)


def perception_config(args: argparse.Namespace, scenario=None, **overrides: Any):
    """The perception config from --config, -p and the command's own flags (over the sweep period of a simulated
    scenario: the time between its scans)."""
    from ssf_common.config import build, parse_overrides, read_yaml
    from ssf_eval.pipeline import PerceptionConfig
    from ssf_eval.sources import sweep_period_layer
    from ssf_flow_node.core.estimator import WHOLE_SCAN

    whole = getattr(args, "protocol", None) == "whole" or not hasattr(args, "protocol")  # scans as the nodes see them
    layers = [sweep_period_layer(scenario)] if scenario is not None else []
    layers += [{"flow": WHOLE_SCAN}] if whole else []
    layers += [read_yaml(args.config)] if args.config else []
    flags = {name: value for name, value in overrides.items() if value is not None}
    return build(PerceptionConfig, *layers, parse_overrides(args.param, "-p"), flags, source=str(args.config or "-p"))


def run_estimate_seg(args: argparse.Namespace) -> int:
    """ssf seg estimate."""
    import numpy as np

    from ssf_common.paths import check_writable, save_npy
    from ssf_common.scans import read_scan_with_time
    from ssf_eval.pipeline import PerceptionChain
    from ssf_eval.results import write_result

    check_writable(args.out, "segmentation file")
    if args.obstacles:
        check_writable(args.obstacles, "obstacle file")
    config = perception_config(args, **{"seg.method": args.method, "flow.estimator": args.flow_estimator,
                                        "fusion.max_iterations": args.iterations, "scan_period": args.dt})
    perception = PerceptionChain(config, args.device)
    (pc1, time1), (pc2, time2) = (read_scan_with_time(path, sweep_period=config.scan_period) for path in (args.pc1, args.pc2))
    result = perception.perceive(pc1[:, :3], pc2[:, :3], frame_id="sensor", time1=time1, time2=time2)
    seg = result.fusion.segmentation
    columns = np.column_stack([seg.dynamic_prob, seg.label, seg.instance, result.fusion.flow]).astype(np.float32)
    save_npy(args.out, columns)
    if args.obstacles:  # every obstacle the fusion node publishes: the moving objects, and the still part as boxes
        items = obstacle_items(result.found.moving, moving=True) + obstacle_items(result.found.still, moving=False)
        write_result(args.obstacles, {"frame": "scan 1 sensor frame", "obstacles": items})
    fusion = result.fusion
    print(f"{len(columns)} points, {int(seg.dynamic.sum())} dynamic in {seg.num_instances} objects, "
          f"{fusion.iterations} iterations ({'converged' if fusion.converged else 'stopped at N_iter'}) -> {args.out}"
          + (f"; {len(result.found.moving)} moving and {len(result.found.still)} still obstacles -> {args.obstacles}"
             if args.obstacles else ""), file=sys.stderr)
    return 0


def obstacle_items(obstacles, *, moving: bool) -> list[dict[str, Any]]:
    """Obstacles as JSON objects: id, moving, kind by name, centre, size, yaw, velocity (m/s), points."""
    from ssf_common.records import ObstacleKind

    return [{"id": int(obstacles.ids[i]), "moving": moving, "kind": ObstacleKind(int(obstacles.kinds[i])).name.lower(),
             "centre": obstacles.centres[i], "size": obstacles.sizes[i], "yaw": float(obstacles.yaws[i]),
             "velocity": obstacles.velocities[i], "points": int(obstacles.point_counts[i])}
            for i in range(len(obstacles))]


def build_methods(args: argparse.Namespace, config) -> list:
    """The table's rows: each segmenter × input, and the loop."""
    from ssf_common.errors import DataError
    from ssf_eval.seg.evaluate import SSF, Method
    from ssf_seg_node.core.segmenter import SEGMENTER_BUILDERS, make_segmenter

    methods = []
    default = args.methods == list(DEFAULT_METHODS)
    for name in args.methods:
        if name == SSF:
            methods.append(Method(f"ssf ({config.flow.estimator}⇄{config.seg.method})", None))
            continue
        if name.partition("-")[0] not in SEGMENTER_BUILDERS and default:
            print(f"skipping {name}: not part of this install", file=sys.stderr)
            continue
        inputs = [name.partition("-")[2]] if "-" in name else args.inputs
        for input_name in inputs:
            try:
                methods.append(Method(f"{name.partition('-')[0]}-{input_name}",
                                      make_segmenter(f"{name.partition('-')[0]}-{input_name}", config.seg, args.device)))
            except DataError as err:
                if not default:
                    raise
                print(f"skipping {name}-{input_name}: {err}", file=sys.stderr)
            except Exception as err:  # a method that cannot read this input (ConfigError) is left out of the row
                from ssf_common.errors import ConfigError

                if not isinstance(err, ConfigError) or len(inputs) == 1:
                    raise
                print(f"skipping {name}-{input_name}: {err}", file=sys.stderr)
    return methods


def run_eval_seg(args: argparse.Namespace) -> int:
    """ssf eval seg."""
    import torch

    from ssf_common.paths import check_writable
    from ssf_eval.pipeline import PerceptionChain
    from ssf_eval.results import write_result
    from ssf_eval.seg.evaluate import FlowInput, evaluate_segmentation, format_seg_table
    from ssf_eval.sources import source_scenario
    from ssf_flow_node.core.estimator import make_estimator

    if args.json:
        check_writable(args.json, "result file")
    torch.set_num_threads(args.threads)
    config = perception_config(args, source_scenario(args))
    methods = build_methods(args, config)
    perception = PerceptionChain(config, args.device) if any(m.segmenter is None for m in methods) else None
    source, starts = sequences_from_args(args)
    estimator = make_estimator(config=config.flow, device=args.device)

    def flow_of(pair):
        if args.flow == "gt":
            return FlowInput(pair.flow, pair.ego)
        result = estimator.estimate(pair.pc1, pair.pc2)
        return FlowInput(result.flow, result.ego)

    print(f"segmenting {len(source.pairs)} pairs ({source.description}) with {len(methods)} methods, flow: {args.flow}",
          file=sys.stderr)
    rows = evaluate_segmentation(methods, source.pairs, flow_of, perception, config,
                                 progress=lambda done: print(f"  pair {done}/{len(source.pairs)}", file=sys.stderr, flush=True),
                                 sequence_starts=starts)
    print(f"segmentation on {len(source.pairs)} pairs ({source.description}), flow: {args.flow}")
    print(format_seg_table(rows))
    if args.json:
        write_result(args.json, {"source": source.source, "flow": args.flow, "results": [
            {"method": row.label, **row.scores._asdict(), "obstacles": row.obstacles, "ms_median": row.ms_median,
             "frames": row.frames, "iterations_mean": row.iterations_mean} for row in rows]},
            {"perception": config, "methods": args.methods, "inputs": args.inputs})
    return 0


def run_eval_fusion(args: argparse.Namespace) -> int:
    """ssf eval fusion."""
    import numpy as np
    import torch

    from ssf_common.paths import check_writable
    from ssf_eval.pipeline import PerceptionChain
    from ssf_eval.results import write_result
    from ssf_eval.seg.evaluate import evaluate_iterations, format_iteration_table, plot_iterations
    from ssf_eval.sources import source_scenario

    for path, what in ((args.json, "result file"), (args.plot, "picture")):
        if path is not None:
            check_writable(path, what)
    torch.set_num_threads(args.threads)
    config = perception_config(args, source_scenario(args), **{"fusion.max_iterations": args.iterations})
    perception = PerceptionChain(config, args.device)
    source, starts = sequences_from_args(args)
    rows, taken = evaluate_iterations(perception, source.pairs, progress=lambda done: print(
        f"  pair {done}/{len(source.pairs)}", file=sys.stderr, flush=True), sequence_starts=starts)
    title = f"fusion loop ({config.flow.estimator} ⇄ {config.seg.method}) on {len(source.pairs)} pairs ({source.description})"
    print(title)
    print(format_iteration_table(rows))
    print(f"iterations per frame: median {np.median(taken):.0f}, mean {np.mean(taken):.2f}, max {max(taken)}")
    if args.json:
        write_result(args.json, {"source": source.source, "iterations": [row._asdict() for row in rows],
                                 "iterations_taken": taken}, {"perception": config})
    if args.plot:
        print(plot_iterations(rows, args.plot, title), file=sys.stderr)
    return 0


def bench_pairs(args: argparse.Namespace):
    """A few simulator pairs (paper protocol, after the warm-up) to time on."""
    from ssf_eval.sources import simulator_pairs
    from ssf_eval.results import check_bench_args

    check_bench_args(args, 1)
    return simulator_pairs(args.scenario, 0, max(2, min(args.frames, 5))).pairs


def run_bench_seg(args: argparse.Namespace) -> int:
    """ssf bench seg: ms per segmentation (segmenter only; the flow is computed once beforehand)."""
    import resource
    import time

    import numpy as np
    import torch

    from ssf_eval.results import write_result
    from ssf_flow_node.core.estimator import make_estimator
    from ssf_seg_node.core.segmenter import make_segmenter

    torch.set_num_threads(args.threads)
    config = perception_config(args)
    pairs = bench_pairs(args)
    estimator = make_estimator(config=config.flow)
    flows = [estimator.estimate(pair.pc1, pair.pc2) for pair in pairs]
    figures = {}
    for name in args.methods:
        segmenter = make_segmenter(name, config.seg, args.device)
        segmenter.segment(pairs[0].pc1, flows[0].flow, None, flows[0].ego)  # warm-up
        spent = []
        for frame in range(args.frames):
            pair, flow = pairs[frame % len(pairs)], flows[frame % len(pairs)]
            started = time.perf_counter()
            segmenter.segment(pair.pc1, flow.flow, None, flow.ego)
            spent.append((time.perf_counter() - started) * 1e3)
        figures[name] = {"ms_median": float(np.median(spent)), "ms_p95": float(np.percentile(spent, 95)),
                         "frames": args.frames, "points": int(len(pairs[0].pc1))}
        print(f"{name:<16} median {figures[name]['ms_median']:7.1f} ms  p95 {figures[name]['ms_p95']:7.1f} ms", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak_rss_mb {peak:.0f}")
    if args.json:
        write_result(args.json, {"segmenters": figures, "peak_rss_mb": peak, "scenario": args.scenario},
                     {"perception": config})
    return 0


def run_bench_fusion(args: argparse.Namespace) -> int:
    """ssf bench fusion: CPU ms per scan of each stage of the chain, consecutive pairs streamed."""
    import resource

    import numpy as np
    import torch

    from ssf_eval.pipeline import PerceptionChain
    from ssf_eval.results import check_bench_args, write_result
    from ssf_eval.sources import simulator_pairs
    from sim_bridge.dataset.export import PROTOCOLS

    check_bench_args(args, 2)
    torch.set_num_threads(args.threads)
    config = perception_config(args)
    pairs = simulator_pairs(args.scenario, 0, args.frames + 1, PROTOCOLS[args.protocol]).pairs
    chain = PerceptionChain(config, args.device)
    times = [chain.perceive(pair.pc1, pair.pc2, follows=index > 0).cpu for index, pair in enumerate(pairs)][1:]
    columns = {name: np.array([getattr(row, name) for row in times]) for name in times[0]._fields}
    stages = {"flow": columns["prior_ms"] + columns["flow_ms"], "segmentation": columns["segmentation_ms"],
              "fusion": columns["fusion_ms"]}
    stages["segmentation + fusion"] = stages["segmentation"] + stages["fusion"]
    budgets = {"flow": 50.0, "segmentation + fusion": 20.0}
    figures = {name: {"cpu_ms_median": float(np.median(values)), "cpu_ms_p95": float(np.percentile(values, 95))}
               for name, values in stages.items()}
    print(f"{len(times)} scans of {args.scenario} ({args.protocol}, {len(pairs[0].pc1)} points), CPU ms per scan:")
    for name, row in figures.items():
        budget = f"  (budget {budgets[name]:g} ms: {'met' if row['cpu_ms_median'] <= budgets[name] else 'missed'})" \
            if name in budgets else ""
        print(f"  {name:<22} median {row['cpu_ms_median']:6.1f}  p95 {row['cpu_ms_p95']:6.1f}{budget}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak_rss_mb {peak:.0f}")
    if args.json:
        write_result(args.json, {"stages": figures, "budgets_ms": budgets, "frames": len(times),
                                 "points": int(len(pairs[0].pc1)), "protocol": args.protocol, "peak_rss_mb": peak,
                                 "scenario": args.scenario}, {"perception": config})
    return 0
