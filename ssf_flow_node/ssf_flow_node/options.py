"""The estimator options that every command building scene flow estimators shares (`ssf flow`, `ssf eval flow`,
`ssf bench flow`, `ssf train`): flags, the config they give, the estimators they name."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ALL_ESTIMATORS = ("zero", "ego", "rigid", "asf-points", "asf-implicit", "asf-explicit")


def add_estimator_options(parser: argparse.ArgumentParser, with_name: bool = True) -> None:
    """Options shared by the commands that build estimators."""
    if with_name:
        parser.add_argument("--estimator", default="rigid", help="zero | ego | rigid | asf | asf-points | asf-implicit | asf-explicit")
    parser.add_argument("--flow-config", type=Path, help="estimator config YAML (preprocess.*, registration.*, rigid.*, asf.*)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="override one estimator config value, e.g. -p preprocess.points:=4096")
    if with_name:
        parser.add_argument("--device", default="cpu", help="torch device for asf")


def flow_config(args: argparse.Namespace, whole_scans: bool = False):
    """The estimator config from --flow-config and -p overrides (over the whole-scan defaults if asked)."""
    from ssf_common.config import build, parse_overrides, read_yaml
    from ssf_flow_node.core.estimator import WHOLE_SCAN, FlowConfig

    file = read_yaml(args.flow_config) if args.flow_config else {}
    return build(FlowConfig, WHOLE_SCAN if whole_scans else {}, file, parse_overrides(args.param, "-p"),
                 source=str(args.flow_config or "-p"))


def build_estimators(names: list[str], args: argparse.Namespace, skip_missing: bool, whole_scans: bool = False):
    """Estimators by name; asf variants without weights are skipped (with a note) when allowed."""
    from ssf_common.errors import DataError
    from ssf_flow_node.core.estimator import make_estimator

    config = flow_config(args, whole_scans)
    estimators = []
    for name in names:
        try:
            estimators.append(make_estimator(name, config))
        except DataError as err:
            if not (skip_missing and name.startswith("asf")):
                raise
            print(f"skipping {name}: {err}", file=sys.stderr)
    return estimators
