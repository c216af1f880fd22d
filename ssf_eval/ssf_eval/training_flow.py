"""`ssf train seg-flow`: the flow a segmentation network trains on, estimated by one of the project's flow estimators
and cached beside each exported pair (the segmentation package never imports the flow package, so the estimate is
made here, once, where both stages may meet)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ssf_common.command_groups import CommandGroups


def register(groups: CommandGroups) -> None:
    """Add `ssf train seg-flow`."""
    command = groups.train.add_parser(
        "seg-flow", help="cache a flow estimator's flow beside exported pairs, for `ssf train seg --flow E`",
        description="Runs the flow estimator (no mask: the fusion loop's first iteration) on every pair under --data "
        "and writes NAME.flow_E.npy (float32, one row per point of scan t) beside NAME.npz; pairs that already "
        "have one are skipped unless --force.")
    command.add_argument("--data", type=Path, required=True, help="folder of exported .npz pairs (searched recursively)")
    command.add_argument("--estimator", default="rigid", help="flow estimator (default rigid)")
    command.add_argument("--force", action="store_true", help="re-estimate pairs that already have a cached flow")
    command.add_argument("--flow-config", type=Path, help="estimator config YAML (preprocess.*, registration.*, rigid.*)")
    command.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                         help="override one estimator config value")
    command.add_argument("--device", default="cpu", help="torch device for network estimators")
    command.set_defaults(func=run_seg_flow)


def run_seg_flow(args: argparse.Namespace) -> int:
    """ssf train seg-flow."""
    from ssf_common.dataset.estimates import flow_estimate_path, write_flow_estimate
    from ssf_common.dataset.pairs import pair_files, read_pair
    from ssf_flow_node.core.estimator import make_estimator
    from ssf_flow_node.options import flow_config

    estimator = make_estimator(args.estimator, flow_config(args), device=args.device)
    files = pair_files(args.data)
    todo = [path for path in files if args.force or not flow_estimate_path(path, args.estimator).is_file()]
    print(f"{estimator.name}: flow for {len(todo)} of {len(files)} pairs under {args.data}", file=sys.stderr)
    for done, path in enumerate(todo, start=1):
        pair = read_pair(path)
        write_flow_estimate(path, args.estimator, estimator.estimate(pair.pc1, pair.pc2).flow)
        if done % 20 == 0 or done == len(todo):
            print(f"  pair {done}/{len(todo)}", file=sys.stderr, flush=True)
    return 0
