"""The `ssf` command line: one entry point, with subcommands contributed by each installed package.

A package contributes commands through an entry point in the `ssf.commands` group that names a function
`register(groups: CommandGroups) -> None`; imports stay lazy inside the command functions so that `ssf --help` is
fast. Whatever subset of the packages is installed, `ssf` offers exactly their commands."""

from __future__ import annotations

import argparse
import sys
from importlib import metadata
from typing import NoReturn, Sequence

from ssf_bringup.commands import register
from ssf_common.command_groups import CommandGroups
from ssf_common.errors import SsfError
from ssf_common.heap import hold_freed_memory
from ssf_common.interrupts import interruptible

COMMANDS_GROUP = "ssf.commands"


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (and exit 2), like every other error of `ssf`."""

    def error(self, message: str) -> NoReturn:
        """Print `PROG: error: MESSAGE (see PROG --help)` and exit 2."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The full `ssf` parser with every package's commands."""
    parser = OneLineParser(
        prog="ssf",
        description="SSF-PAN: semantic scene flow perception and navigation, as a ROS 2 node graph.",
    )
    top = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    groups = CommandGroups(
        top=top,
        train=_group(top, "train", "train the networks"),
        eval=_group(top, "eval", "the paper's tables on simulator or recorded data, method beside method"),
        bench=_group(top, "bench", "speed and memory figures (medians, JSON with --json)"),
    )
    register(groups)  # the application's own commands come first
    for entry in sorted(metadata.entry_points(group=COMMANDS_GROUP), key=lambda entry: entry.name):
        if entry.value.startswith("ssf_bringup."):
            continue
        try:
            contribute = entry.load()
        except ModuleNotFoundError as err:  # an entry point left behind by a package that is gone
            print(f"ssf: note: commands of '{entry.name}' are unavailable ({err})", file=sys.stderr)
            continue
        contribute(groups)
    return parser


def _group(top: argparse._SubParsersAction, name: str, help_text: str) -> argparse._SubParsersAction:
    parser = top.add_parser(name, help=help_text, description=help_text)
    return parser.add_subparsers(dest=f"{name}_command", metavar="WHAT", required=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one `ssf` command; user errors print one line and exit 2."""
    interruptible()
    hold_freed_memory()  # what the nodes do: the in-process stages and benches run as they would in them
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.func(args)
    except SsfError as err:
        print(f"ssf: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
