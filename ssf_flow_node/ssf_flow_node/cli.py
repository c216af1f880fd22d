"""`ssf` commands of ssf_flow_node: flow estimate, train flow, eval flow, bench flow."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ssf_common.cli import CommandGroups

ALL_ESTIMATORS = ("zero", "ego", "rigid", "asf-points", "asf-implicit", "asf-explicit")


def register(groups: CommandGroups) -> None:
    from sim_bridge.cli import add_protocol_options

    """Add the scene flow commands."""
    flow = groups.top.add_parser("flow", help="scene flow between two scans")
    flow_commands = flow.add_subparsers(dest="flow_command", metavar="WHAT", required=True)
    estimate = flow_commands.add_parser(
        "estimate", help="scene flow for two scan files (.npy, KITTI .bin, .pcd, .ply)",
        description="Flow for every finite point of PC1 (points with NaN/Inf coordinates are dropped on reading), "
        "written as float32 (N, 3) .npy: PC1 + flow lies on PC2's surfaces, in PC1's sensor frame. Made for whole "
        "scans: the estimator spends its 8192 points on non-ground structure within 35 m (-p "
        "preprocess.remove_ground=false -p preprocess.max_range=60 for scans already cut).")
    estimate.add_argument("pc1", type=Path, help="scan t")
    estimate.add_argument("pc2", type=Path, help="scan t+1")
    estimate.add_argument("--mask", type=Path, help=".npy or text file: one dynamic probability (0..1) per point of PC1")
    estimate.add_argument("--out", type=Path, required=True, help="output FLOW.npy")
    add_estimator_options(estimate)
    estimate.set_defaults(func=run_estimate)

    train = groups.train.add_parser("flow", help="train the ASF-style scene flow network",
                                    description="Supervised (multi-scale EPE) or self-supervised (Chamfer + smoothness) "
                                    "training on exported pairs; checkpoints carry their config and can be resumed.")
    train.add_argument("--data", type=Path, required=True, help="directory of exported .npz pairs")
    train.add_argument("--out", type=Path, default=Path("asf.pt"), help="checkpoint to write (default asf.pt)")
    train.add_argument("--resume", type=Path, help="continue from this checkpoint with its config")
    train.add_argument("--mode", choices=("supervised", "self_supervised"))
    train.add_argument("--strategy", choices=("explicit", "implicit", "points"), help="how the mask is fed")
    train.add_argument("--steps", type=int)
    train.add_argument("--batch-size", type=int)
    train.add_argument("--minutes", type=float, help="stop and save after this many minutes")
    train.add_argument("--threads", type=int, help="torch CPU threads")
    train.add_argument("--device", default="cpu", help="cpu or cuda")
    train.add_argument("--config", type=Path, help="training config YAML (dotted names as in the checkpoint)")
    train.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override one config value")
    train.set_defaults(func=run_train)

    evaluate = groups.eval.add_parser(
        "flow", help="EPE3D / AS / AR / Outliers per estimator, with baselines and the mask ablation",
        description="Every estimator on the same pairs and masks; metrics pooled over points for all, static and "
        "dynamic points (EPE3D, AS, AR and Outliers as defined by FlowNet3D and used by the paper).")
    source = evaluate.add_mutually_exclusive_group(required=True)
    source.add_argument("--scenario", help="simulator scenario to generate pairs from")
    source.add_argument("--data", type=Path, help="directory of exported .npz pairs")
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--frames", type=int, default=10, help="pairs to generate from the scenario")
    evaluate.add_argument("--skip", type=int, default=20,
                          help="simulator pairs to drop first: the ego and the agents start from rest (default 20)")
    add_protocol_options(evaluate)
    evaluate.add_argument("--estimators", "--estimator", nargs="+", default=list(ALL_ESTIMATORS), metavar="E",
                          help=f"default: {' '.join(ALL_ESTIMATORS)}")
    evaluate.add_argument("--masks", choices=("none", "noisy", "gt"), default="noisy",
                          help="mask given to every estimator (noisy: ground truth with 10%% objects dropped, 3%% points flipped)")
    evaluate.add_argument("--json", type=Path, help="write the results here")
    evaluate.add_argument("--plot", type=Path, help="PNG: bird's-eye view of the last pair, each estimator's error per point")
    evaluate.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest on a loaded machine)")
    add_estimator_options(evaluate, with_name=False)
    evaluate.set_defaults(func=run_eval)

    bench = groups.bench.add_parser("flow", help="ms per frame (median, p95) per estimator at 8192 points, peak RSS",
                                    description="Each estimator on the same few simulator pairs (after the first 20 "
                                    "frames) with noisy masks, as the fusion loop hands them to the node.")
    bench.add_argument("--frames", type=int, default=20)
    bench.add_argument("--scenario", default="urban_200", help="simulator scenario the pairs come from ('synthetic': built-in street)")
    add_protocol_options(bench)
    bench.add_argument("--estimators", "--estimator", nargs="+", default=["ego", "rigid", "asf"], metavar="E")
    bench.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest on a loaded machine)")
    bench.add_argument("--json", type=Path)
    add_estimator_options(bench, with_name=False)
    bench.set_defaults(func=run_bench)


def add_estimator_options(parser: argparse.ArgumentParser, with_name: bool = True) -> None:
    """Options shared by the commands that build estimators."""
    if with_name:
        parser.add_argument("--estimator", default="rigid", help="zero | ego | rigid | asf | asf-points | asf-implicit | asf-explicit")
    parser.add_argument("--flow-config", type=Path, help="estimator config YAML (preprocess.*, registration.*, rigid.*, asf.*)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override one estimator config value, e.g. preprocess.points=4096")
    if with_name:
        parser.add_argument("--device", default="cpu", help="torch device for asf")


def parse_overrides(items: list[str], flag: str) -> dict[str, Any]:
    """NAME=VALUE pairs with YAML-typed values."""
    import yaml

    from ssf_common.errors import ConfigError

    values = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise ConfigError(f"{flag} expects NAME=VALUE, got {item!r}")
        values[name] = yaml.safe_load(text)
    return values


def flow_config(args: argparse.Namespace, whole_scans: bool = False):
    """The estimator config from --flow-config and -p overrides (over the whole-scan defaults if asked)."""
    from ssf_common.config import build, read_yaml
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig

    file = read_yaml(args.flow_config) if args.flow_config else {}
    return build(FlowConfig, WHOLE_SCAN if whole_scans else {}, file, parse_overrides(args.param, "-p"),
                 source=str(args.flow_config or "-p"))


def read_mask(path: Path, count: int):
    """A per-point mask file: .npy or whitespace-separated text."""
    import numpy as np

    from ssf_common.errors import DataError

    try:
        values = np.load(path, allow_pickle=False) if path.suffix == ".npy" else np.loadtxt(path, ndmin=1)
    except FileNotFoundError:
        raise DataError(f"{path}: no such mask file") from None
    except (OSError, ValueError) as err:
        raise DataError(f"{path}: not a readable mask ({err})") from None
    if np.asarray(values).size != count:
        raise DataError(f"{path}: {np.asarray(values).size} mask values for {count} points of scan t")
    return np.asarray(values, dtype=np.float32).reshape(count)


def run_estimate(args: argparse.Namespace) -> int:
    """ssf flow estimate."""
    import numpy as np

    from ssf_common.scan_io import read_scan
    from ssf_flow_node.core.estimator import make_estimator

    estimator = make_estimator(args.estimator, flow_config(args, whole_scans=True), device=args.device)
    pc1, pc2 = read_scan(args.pc1), read_scan(args.pc2)
    mask = read_mask(args.mask, pc1.shape[0]) if args.mask else None
    result = estimator.estimate(pc1, pc2, mask)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.save(args.out, result.flow)
    speed = np.linalg.norm(result.flow, axis=1)
    print(f"{estimator.name}: {len(result.flow)} points, flow |median| {np.median(speed):.3f} m, max {speed.max():.3f} m, "
          f"ego translation {np.linalg.norm(result.ego[:3, 3]):.3f} m -> {args.out}", file=sys.stderr)
    return 0


def run_train(args: argparse.Namespace) -> int:
    """ssf train flow."""
    from ssf_common.config import load
    from ssf_flow_node.core.data import pair_files
    from ssf_flow_node.core.training import TrainConfig, Trainer

    files = pair_files(args.data)
    log = lambda line: print(line, file=sys.stderr, flush=True)
    if args.resume:
        trainer = Trainer.resume(args.resume, files, args.out, args.device, args.steps, args.minutes, log)
    else:
        overrides = parse_overrides(args.set, "--set")
        for name, value in (("mode", args.mode), ("network.strategy", args.strategy), ("steps", args.steps),
                            ("batch_size", args.batch_size), ("max_minutes", args.minutes), ("threads", args.threads)):
            if value is not None:
                overrides[name] = value
        trainer = Trainer(load(TrainConfig, args.config, overrides), files, args.out, args.device, log)
    log(f"training {trainer.config.network.strategy.value} network ({trainer.config.mode.value}) on {len(files)} pairs "
        f"from step {trainer.step} to {trainer.config.steps} -> {args.out}")
    result = trainer.run()
    if result.losses:
        head, tail = result.losses[: max(1, len(result.losses) // 10)], result.losses[-max(1, len(result.losses) // 10):]
        log(f"done: step {result.step}, loss {sum(head) / len(head):.4f} (first tenth) -> {sum(tail) / len(tail):.4f} (last tenth), "
            f"checkpoint {result.checkpoint}")
    return 0


def evaluation_pairs(args: argparse.Namespace):
    """Pairs from an export directory or generated from a simulator scenario."""
    from ssf_flow_node.core.data import as_flow_pair, read_pairs

    from sim_bridge.cli import protocol_from_args
    from sim_bridge.dataset.export import generate_pairs

    if args.data is not None:
        return list(read_pairs(args.data))
    pairs = generate_pairs(args.scenario, args.seed, args.skip + args.frames, protocol_from_args(args))
    return [as_flow_pair(pair) for index, pair in enumerate(pairs) if index >= args.skip]


def build_estimators(names: list[str], args: argparse.Namespace, skip_missing: bool):
    """Estimators by name; asf variants without weights are skipped (with a note) when allowed."""
    from ssf_common.errors import DataError
    from ssf_flow_node.core.estimator import make_estimator

    config = flow_config(args)
    estimators = []
    for name in names:
        try:
            estimators.append(make_estimator(name, config))
        except DataError as err:
            if not (skip_missing and name.startswith("asf")):
                raise
            print(f"skipping {name}: {err}", file=sys.stderr)
    return estimators


def run_eval(args: argparse.Namespace) -> int:
    """ssf eval flow."""
    import torch

    from ssf_flow_node.core.evaluation import MaskSource, evaluate, format_table

    torch.set_num_threads(args.threads)
    estimators = build_estimators(args.estimators, args, skip_missing=args.estimators == list(ALL_ESTIMATORS))
    pairs = evaluation_pairs(args)
    where = f"data {args.data}" if args.data else f"scenario {args.scenario} seed {args.seed}, pairs {args.skip}-{args.skip + args.frames - 1}"
    print(f"evaluating {len(estimators)} estimators on {len(pairs)} pairs ({where}), masks: {args.masks}", file=sys.stderr)
    results = evaluate(estimators, pairs, MaskSource(args.masks), args.seed,
                       progress=lambda done: print(f"  pair {done}/{len(pairs)}", file=sys.stderr, flush=True))
    print(f"scene flow on {len(pairs)} pairs ({where}), masks: {args.masks}")
    print(format_table(results))
    if args.json:
        payload = {"source": where, "pairs": len(pairs), "masks": args.masks,
                   "results": [{"estimator": r.name, "ms_median": r.ms_median, "frames": r.frames,
                                **{split: getattr(r.scores, split)._asdict() for split in ("all", "static", "dynamic")}}
                               for r in results]}
        args.json.write_text(json.dumps(payload, indent=2))
    if args.plot:
        from ssf_flow_node.core.evaluation import mask_for
        from ssf_flow_node.core.plot import plot_pair

        import numpy as np

        pair = pairs[-1]
        mask = mask_for(pair, MaskSource(args.masks), np.random.default_rng(args.seed))
        shown = {estimator.name: estimator.estimate(pair.pc1, pair.pc2, mask) for estimator in estimators
                 if estimator.name != "zero"}
        print(plot_pair(pair, shown, args.plot, f"{where}: last pair, masks {args.masks}"), file=sys.stderr)
    return 0


def run_bench(args: argparse.Namespace) -> int:
    """ssf bench flow: ms per pair at 8192 points on simulator pairs (or synthetic street pairs)."""
    import resource
    import time

    import numpy as np
    import torch

    from ssf_flow_node.core.data import noisy_mask
    from ssf_flow_node.core.synthetic import synthetic_pair

    torch.set_num_threads(args.threads)
    estimators = build_estimators(args.estimators, args, skip_missing=False)
    count = max(2, min(args.frames, 5))
    if args.scenario == "synthetic":
        pairs = [synthetic_pair(seed, agents=20, ego_step=1.0) for seed in range(count)]
    else:
        pairs = evaluation_pairs(argparse.Namespace(**{**vars(args), "data": None, "seed": 0, "skip": 20, "frames": count}))
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
        args.json.write_text(json.dumps({"estimators": figures, "peak_rss_mb": peak, "threads": args.threads}, indent=2))
    return 0
