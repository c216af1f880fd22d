"""The contract of the `ssf` command line: each package adds its commands to these groups."""

from __future__ import annotations

import argparse
from dataclasses import dataclass


@dataclass(frozen=True)
class CommandGroups:
    """Subparser groups that packages add their commands to."""

    top: argparse._SubParsersAction
    train: argparse._SubParsersAction
    eval: argparse._SubParsersAction
    bench: argparse._SubParsersAction
