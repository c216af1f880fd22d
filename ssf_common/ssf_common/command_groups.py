"""The contract of the `ssf` command line: each package adds its commands to these groups."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class CommandGroups:
    """Subparser groups that packages add their commands to."""

    top: argparse._SubParsersAction
    train: argparse._SubParsersAction
    eval: argparse._SubParsersAction
    bench: argparse._SubParsersAction


def add_training_run_options(train: argparse.ArgumentParser, example: str) -> None:
    """The options every `ssf train` command shares: how long, on what, and its config (`example`: a -p override)."""
    train.add_argument("--steps", type=int)
    train.add_argument("--batch-size", type=int)
    train.add_argument("--minutes", type=float, help="stop and save after this many minutes")
    train.add_argument("--threads", type=int, help="torch CPU threads")
    train.add_argument("--device", default="cpu", help="cpu or cuda")
    train.add_argument("--config", type=Path, help="training config YAML (dotted names as in the checkpoint)")
    train.add_argument("-p", "--param", "--set", dest="param", action="append", default=[], metavar="NAME:=VALUE",
                       help=f"override one training config value, e.g. -p {example}")
