"""`ssf eval flow` and `ssf bench flow`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups
from ssf_eval.sources import add_pair_source_options
from ssf_flow_node.options import ALL_ESTIMATORS, add_estimator_options


def register(groups: CommandGroups) -> None:
    """Add `ssf eval flow` and `ssf bench flow`."""
    evaluate = groups.eval.add_parser(
        "flow", help="EPE3D / AS / AR / Outliers per estimator, with baselines and the mask ablation",
        description="Every estimator on the same pairs and masks; metrics pooled over points for all, static and "
        "dynamic points (EPE3D, AS, AR and Outliers as defined by FlowNet3D and used by the paper). Simulator "
        "pairs start after --warmup seconds, when the traffic is moving.")
    add_pair_source_options(evaluate, default_frames=10)
    evaluate.add_argument("--estimators", "--estimator", nargs="+", default=list(ALL_ESTIMATORS), metavar="E",
                          help=f"default: {' '.join(ALL_ESTIMATORS)}")
    evaluate.add_argument("--masks", choices=("none", "noisy", "gt"), default="noisy",
                          help="mask given to every estimator (noisy: ground truth with 10%% objects dropped, 3%% points flipped)")
    evaluate.add_argument("--json", type=Path, help="write the results here (and the effective config beside them)")
    evaluate.add_argument("--plot", type=Path, help="PNG: bird's-eye view of the last pair, each estimator's error per point")
    evaluate.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest on a loaded machine)")
    add_estimator_options(evaluate, with_name=False)
    evaluate.set_defaults(func=run_eval_flow)

    bench = groups.bench.add_parser("flow", help="ms per frame (median, p95) per estimator at 8192 points, peak RSS",
                                    description="Each estimator on the same few simulator pairs (after the warm-up) "
                                    "with noisy masks, as the fusion loop hands them to the node.")
    bench.add_argument("--frames", type=int, default=20, help="timed frames per estimator (default 20)")
    bench.add_argument("--scenario", default="urban_200", help="simulator scenario the pairs come from ('synthetic': built-in street)")
    from sim_bridge.options import add_protocol_options

    add_protocol_options(bench)
    bench.add_argument("--estimators", "--estimator", nargs="+", default=["ego", "rigid", "asf"], metavar="E")
    bench.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest on a loaded machine)")
    bench.add_argument("--json", type=Path)
    add_estimator_options(bench, with_name=False)
    bench.set_defaults(func=run_bench_flow)


def run_eval_flow(args: argparse.Namespace) -> int:
    """ssf eval flow."""
    import torch

    from ssf_common.paths import check_writable
    from ssf_eval.flow.evaluate import MaskSource, evaluate_flow, format_flow_table
    from ssf_eval.results import write_result
    from ssf_eval.sources import pairs_from_args
    from ssf_flow_node.options import build_estimators, flow_config

    for path, what in ((args.json, "result file"), (args.plot, "picture")):
        if path is not None:
            check_writable(path, what)
    torch.set_num_threads(args.threads)
    estimators = build_estimators(args.estimators, args, skip_missing=args.estimators == list(ALL_ESTIMATORS),
                                  whole_scans=args.protocol == "whole")
    source = pairs_from_args(args)
    pairs = source.pairs
    print(f"evaluating {len(estimators)} estimators on {len(pairs)} pairs ({source.description}), masks: {args.masks}",
          file=sys.stderr)
    evaluation = evaluate_flow(estimators, pairs, MaskSource(args.masks), args.seed,
                               progress=lambda done: print(f"  pair {done}/{len(pairs)}", file=sys.stderr, flush=True))
    print(f"scene flow on {len(pairs)} pairs ({source.description}), masks: {args.masks}")
    print(format_flow_table(evaluation.results))
    if args.json:
        payload = {"source": source.source, "pairs": len(pairs), "masks": args.masks,
                   "results": [{"estimator": r.name, "ms_median": r.ms_median, "frames": r.frames,
                                **{split: getattr(r.scores, split)._asdict() for split in ("all", "static", "dynamic")}}
                               for r in evaluation.results]}
        write_result(args.json, payload, {"flow": flow_config(args, whole_scans=args.protocol == "whole"), "estimators": args.estimators,
                                          "masks": args.masks, "source": source.source})
    if args.plot and evaluation.last_pair is not None:
        from ssf_eval.flow.plot import plot_pair

        shown = {name: result for name, result in evaluation.last_flows.items() if name != "zero"}
        print(plot_pair(evaluation.last_pair, shown, args.plot, f"{source.description}: last pair, masks {args.masks}"),
              file=sys.stderr)
    return 0


def run_bench_flow(args: argparse.Namespace) -> int:
    """ssf bench flow: ms per pair at 8192 points on simulator pairs (or synthetic street pairs)."""
    import resource
    import time

    import numpy as np
    import torch

    from ssf_common.dataset.masks import noisy_mask
    from ssf_common.dataset.synthetic import synthetic_pair
    from ssf_eval.results import check_bench_args, write_result
    from ssf_eval.sources import protocol_from_args, simulator_pairs
    from ssf_flow_node.options import build_estimators, flow_config

    check_bench_args(args, 1)
    torch.set_num_threads(args.threads)
    whole = args.protocol == "whole"
    estimators = build_estimators(args.estimators, args, skip_missing=False, whole_scans=whole)
    count = max(2, min(args.frames, 5))
    if args.scenario == "synthetic":
        pairs = [synthetic_pair(seed, agents=20, ego_step=1.0) for seed in range(count)]
    else:
        pairs = simulator_pairs(args.scenario, 0, count, protocol_from_args(args)).pairs
    rng = np.random.default_rng(0)
    masks = [noisy_mask(pair, rng) for pair in pairs]  # what the fusion loop hands the node
    figures = {}
    for estimator in estimators:
        estimator.estimate(pairs[0].pc1, pairs[0].pc2)  # warm-up (imports, allocations)
        spent = []
        for frame in range(args.frames):
            started = time.perf_counter()
            estimator.estimate(pairs[frame % count].pc1, pairs[frame % count].pc2, masks[frame % count])
            spent.append((time.perf_counter() - started) * 1e3)
        figures[estimator.name] = {"ms_median": float(np.median(spent)), "ms_p95": float(np.percentile(spent, 95)),
                                   "frames": args.frames, "points": int(len(pairs[0].pc1)), "source": args.scenario,
                                   "protocol": args.protocol}
        print(f"{estimator.name:<14} median {figures[estimator.name]['ms_median']:7.1f} ms  "
              f"p95 {figures[estimator.name]['ms_p95']:7.1f} ms", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak_rss_mb {peak:.0f} (torch threads {args.threads})")
    if args.json:
        write_result(args.json, {"estimators": figures, "peak_rss_mb": peak, "threads": args.threads},
                     {"flow": flow_config(args, whole_scans=whole), "estimators": args.estimators, "scenario": args.scenario})
    return 0
