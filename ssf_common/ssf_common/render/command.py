"""`ssf render RECORDING --video FILE --picture FILE [-p NAME:=VALUE]`: draw any recorded episode."""

from __future__ import annotations

import argparse
import sys

from ssf_common.jsonio import dumps_strict


def add_parser(top: argparse._SubParsersAction) -> None:
    """Register `ssf render`."""
    parser = top.add_parser(
        "render",
        help="draw a recorded episode: bird's-eye animation (MP4/GIF) and the episode picture",
        description="Read a recording (rosbag2, MCAP or sqlite3) and draw it bird's-eye in the world frame: the scan "
        "coloured by segmentation (/ssf/semantic_flow, else /lidar/points), the true agents, the obstacles the "
        "perception saw with their velocity arrows, the MPC plan, the ego's path and the odometry. Settings: -p "
        "view_radius_m:=40 -p fps:=10 -p stride:=1 -p start_s:=0 -p duration_s:=0 -p size_px:=720 -p max_points:=40000.",
    )
    parser.add_argument("recording", help="bag directory, or a .mcap / .db3 file")
    parser.add_argument("--video", metavar="FILE", help="the animation (.mp4 or .gif)")
    parser.add_argument("--picture", metavar="PNG", help="the episode picture (overview, last moments, fusion Δ)")
    parser.add_argument("--title", default="", help="title drawn on every frame")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="render setting (repeatable)")
    parser.set_defaults(func=run_render)


def run_render(args: argparse.Namespace) -> int:
    """Draw what was asked and print what was written."""
    from ssf_common.config import build, parse_overrides
    from ssf_common.errors import ConfigError
    from ssf_common.render.frames import RenderConfig
    from ssf_common.render.video import render_recording

    if not args.video and not args.picture:
        raise ConfigError("nothing to draw: give --video FILE and/or --picture PNG")
    config = build(RenderConfig, parse_overrides(args.param, "-p"), source="ssf render -p")
    summary = render_recording(args.recording, picture=args.picture, video=args.video, config=config,
                               title=args.title, progress=sys.stderr)
    print(dumps_strict({"frames": summary.frames, "seconds": summary.seconds,
                        "video": str(summary.video) if summary.video else None,
                        "picture": str(summary.picture) if summary.picture else None}))
    return 0
