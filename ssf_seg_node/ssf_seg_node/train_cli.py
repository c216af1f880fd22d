"""`ssf train seg`: the OGC-style network (self-supervised) and the supervised PointNet++ baseline."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups, add_training_run_options


def register(groups: CommandGroups) -> None:
    """Add `ssf train seg`."""
    train = groups.train.add_parser(
        "seg", help="train the segmentation networks (ogc self-supervised, pointnet supervised)",
        description="Trains on exported pairs (`ssf dataset export`). ogc learns K soft masks without labels (L_mot + "
        "L_SC + L_CD + smoothness) on the flow of a project estimator cached beside the pairs (`ssf train seg-flow "
        "--data DIR --estimator rigid`) or on the ground-truth flow (--flow gt); pointnet learns static/dynamic "
        "from the labels. Labels of --val pairs are read only to log accuracy and moving IoU. Checkpoints carry "
        "their config and resume with --resume (also on another device: --device cuda); Ctrl-C or SIGTERM "
        "stops after the current step and saves.")
    train.add_argument("--data", type=Path, required=True, help="folder of exported .npz pairs (searched recursively)")
    train.add_argument("--val", type=Path, help="folder of validation pairs (scored against their labels, never trained on)")
    train.add_argument("--out", type=Path, default=Path("seg.pt"), help="checkpoint to write (default seg.pt)")
    train.add_argument("--resume", type=Path, help="continue from this checkpoint with its config")
    train.add_argument("--method", choices=("ogc", "pointnet"), help="network (default ogc)")
    train.add_argument("--input", choices=("points", "flow", "both"), help="what the network sees (default both)")
    train.add_argument("--flow", help="flow trained on: gt, or a cached estimator's (default rigid)")
    add_training_run_options(train, "losses.motion:=10")
    train.set_defaults(func=run_train_seg)


def run_train_seg(args: argparse.Namespace) -> int:
    """ssf train seg."""
    from ssf_common.config import load, parse_overrides
    from ssf_common.dataset.pairs import pair_files
    from ssf_common.paths import check_writable
    from ssf_seg_node.core.ogc.training import SegTrainConfig, SegTrainer

    check_writable(args.out, "checkpoint")
    files = pair_files(args.data)
    validation = pair_files(args.val) if args.val else None
    log = lambda line: print(line, file=sys.stderr, flush=True)
    if args.resume:
        trainer = SegTrainer.resume(args.resume, files, args.out, validation, args.device, args.steps, args.minutes, log)
    else:
        overrides = parse_overrides(args.param, "-p")
        for name, value in (("method", args.method), ("network.input", args.input), ("flow", args.flow),
                            ("steps", args.steps), ("batch_size", args.batch_size), ("max_minutes", args.minutes),
                            ("threads", args.threads)):
            if value is not None:
                overrides[name] = value
        trainer = SegTrainer(load(SegTrainConfig, args.config, overrides), files, args.out, validation, args.device, log)
    config = trainer.config
    log(f"training {config.method.value} on input '{config.network.input.value}' with '{config.flow}' flow: "
        f"{len(files)} pairs, {len(trainer.validation_files)} validation pairs, step {trainer.step} to {config.steps} -> {args.out}")
    result = trainer.run()
    if result.losses:
        tenth = max(1, len(result.losses) // 10)
        head, tail = result.losses[:tenth], result.losses[-tenth:]
        log(f"done: step {result.step}, loss {sum(head) / len(head):.4f} (first tenth) -> {sum(tail) / len(tail):.4f} "
            f"(last tenth), checkpoint {result.checkpoint}")
    return 0
