"""`ssf` commands of ssf_flow_node: flow estimate, train flow."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups, add_training_run_options
from ssf_flow_node.options import add_estimator_options, flow_config

def register(groups: CommandGroups) -> None:
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
    estimate.set_defaults(func=run_estimate_flow)

    train = groups.train.add_parser("flow", help="train the ASF-style scene flow network",
                                    description="Supervised (multi-scale EPE) or self-supervised (Chamfer + smoothness) "
                                    "training on exported pairs; checkpoints carry their config and can be resumed. Ctrl-C or "
                                    "SIGTERM stops after the current step and saves.")
    train.add_argument("--data", type=Path, required=True, help="directory of exported .npz pairs")
    train.add_argument("--out", type=Path, default=Path("asf.pt"), help="checkpoint to write (default asf.pt)")
    train.add_argument("--resume", type=Path, help="continue from this checkpoint with its config")
    train.add_argument("--mode", choices=("supervised", "self_supervised"))
    train.add_argument("--strategy", choices=("explicit", "implicit", "points"), help="how the mask is fed")
    add_training_run_options(train, "lr:=5e-4")
    train.set_defaults(func=run_train_flow)


def read_mask(path: Path, count: int):
    """A per-point mask file (.npy or whitespace-separated text) of dynamic probabilities."""
    import numpy as np

    from ssf_common.errors import DataError

    try:
        values = np.load(path, allow_pickle=False) if path.suffix == ".npy" else np.loadtxt(path, ndmin=1)
    except FileNotFoundError:
        raise DataError(f"{path}: no such mask file") from None
    except (OSError, ValueError, EOFError) as err:
        raise DataError(f"{path}: not a readable mask ({err})") from None
    values = np.asarray(values)
    if values.dtype.kind not in "biuf":
        raise DataError(f"{path}: mask holds {values.dtype} values; expected numbers (probabilities in [0, 1])")
    if values.size != count:
        raise DataError(f"{path}: {values.size} mask values for {count} points of scan t")
    return values.astype(np.float32).reshape(count)


def run_estimate_flow(args: argparse.Namespace) -> int:
    """ssf flow estimate."""
    import numpy as np

    from ssf_common.paths import check_writable, save_npy
    from ssf_common.geometry.sweep import pair_times
    from ssf_common.scans import read_scan_with_time
    from ssf_flow_node.core.estimator import make_estimator

    check_writable(args.out, "flow file")
    estimator = make_estimator(args.estimator, flow_config(args, whole_scans=True), device=args.device)
    (pc1, time1), (pc2, time2) = read_scan_with_time(args.pc1), read_scan_with_time(args.pc2)
    mask = read_mask(args.mask, pc1.shape[0]) if args.mask else None
    result = estimator.estimate(pc1, pc2, mask, pair_times(time1, time2, 0.1))  # KITTI's and most drivers' 10 Hz
    save_npy(args.out, result.flow)
    speed = np.linalg.norm(result.flow, axis=1)
    print(f"{estimator.name}: {len(result.flow)} points, flow |median| {np.median(speed):.3f} m, max {speed.max():.3f} m, "
          f"ego translation {np.linalg.norm(result.ego[:3, 3]):.3f} m -> {args.out}", file=sys.stderr)
    return 0


def run_train_flow(args: argparse.Namespace) -> int:
    """ssf train flow."""
    from ssf_common.config import load, parse_overrides
    from ssf_common.dataset.pairs import pair_files
    from ssf_flow_node.core.training import TrainConfig, Trainer

    files = pair_files(args.data)
    log = lambda line: print(line, file=sys.stderr, flush=True)
    if args.resume:
        trainer = Trainer.resume(args.resume, files, args.out, args.device, args.steps, args.minutes, log)
    else:
        overrides = parse_overrides(args.param, "-p")
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
