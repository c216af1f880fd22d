"""The pair protocol options that the commands reading simulator pairs share (`ssf dataset export`, `ssf eval`,
`ssf bench`)."""

from __future__ import annotations

import argparse


def add_protocol_options(parser: argparse.ArgumentParser) -> None:
    """--protocol and the fields it may override (shared by export, eval and bench)."""
    parser.add_argument("--protocol", choices=("paper", "raw", "whole"), default="paper",
                        help="paper: ground removed, 35 m range, 8192 points (the scene-flow benchmarks' KITTI "
                        "protocol); raw: whole scans, ground included, 8192 points; whole: every point of every scan, "
                        "as the nodes see them (default paper)")
    parser.add_argument("--points", type=int, help="points per scan (default 8192)")
    parser.add_argument("--sampling", choices=("random", "voxel", "fps"), help="how the points are picked (default random)")


def protocol_from_args(args: argparse.Namespace):
    """The pair protocol the flags name."""
    from sim_bridge.dataset.export import pair_protocol

    return pair_protocol(args.protocol, points=args.points, sampling=args.sampling)
