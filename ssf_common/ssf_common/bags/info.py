"""`ssf bag info PATH [--json]`: what a bag holds, laid out like `ros2 bag info`."""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ssf_common.bags.timeline import Timeline
    from ssf_common.bags.types import BagInfo

EXIT_PROBLEM = 1


def describe_bag(info: BagInfo, timeline: Timeline | None = None) -> str:
    """Human-readable table of a bag (start, end and duration of its plausible span when a timeline is given)."""
    label = 19
    if timeline is not None and timeline.outside:
        info = info._replace(start_ns=timeline.start_ns, end_ns=timeline.end_ns)
    lines = [
        f"{'Files:':<{label}}{_join(f.path.name for f in info.files)}",
        f"{'Bag size:':<{label}}{size_text(sum(f.size_bytes for f in info.files))}",
        f"{'Storage id:':<{label}}{info.storage}",
        f"{'ROS Distro:':<{label}}{info.ros_distro or 'unknown'}",
        f"{'Metadata version:':<{label}}{info.metadata_version if info.metadata_version is not None else 'none (no metadata.yaml)'}",
        f"{'Duration:':<{label}}{info.duration_ns / 1e9:.9f}s",
        f"{'Start:':<{label}}{_time(info.start_ns)}",
        f"{'End:':<{label}}{_time(info.end_ns)}",
        f"{'Messages:':<{label}}{info.message_count}",
    ]
    topics = sorted(info.topics, key=lambda topic: topic.name)
    for index, topic in enumerate(topics):
        head = "Topic information: " if index == 0 else " " * label
        lines.append(
            f"{head}Topic: {topic.name} | Type: {topic.type_name or '(unknown)'} | Count: {topic.message_count}"
            f" | Serialization Format: {topic.serialization_format}"
        )
    if not topics:
        lines.append("Topic information: (none)")
    for index, damage in enumerate(info.damage):
        lines.append(f"{'Damaged:' if index == 0 else '':<{label}}{damage}")
    notes = [timeline.problem(), timeline.order_note()] if timeline is not None else []
    for index, note in enumerate(note for note in notes if note):
        lines.append(f"{'Timestamps:' if index == 0 else '':<{label}}{note}")
    return "\n".join(lines)


def to_json(info: BagInfo, timeline: Timeline | None = None) -> dict[str, Any]:
    """The same facts as a JSON-ready mapping."""
    from ssf_common.bags.qos import profiles_to_dicts

    if timeline is not None and timeline.outside:
        info = info._replace(start_ns=timeline.start_ns, end_ns=timeline.end_ns)
    return {
        "path": str(info.path),
        "storage_identifier": info.storage,
        "metadata_version": info.metadata_version,
        "ros_distro": info.ros_distro,
        "duration_ns": info.duration_ns,
        "start_ns": info.start_ns,
        "end_ns": info.end_ns,
        "message_count": info.message_count,
        "compression_format": info.compression_format,
        "compression_mode": info.compression_mode,
        "custom_data": dict(info.custom_data),
        "files": [
            {
                "path": f.path.name,
                "size_bytes": f.size_bytes,
                "message_count": f.message_count,
                "start_ns": f.start_ns,
                "end_ns": f.end_ns,
                "damage": f.damage,
            }
            for f in info.files
        ],
        "topics": [
            {
                "name": t.name,
                "type": t.type_name,
                "message_count": t.message_count,
                "serialization_format": t.serialization_format,
                "offered_qos_profiles": profiles_to_dicts(t.offered_qos),
                "type_description_hash": t.type_hash,
            }
            for t in info.topics
        ],
        "damage": list(info.damage),
        "timestamps": {
            "outside_span": timeline.outside if timeline else 0,
            "negative": timeline.negative if timeline else 0,
            "out_of_order": timeline.out_of_order if timeline else 0,
            "problem": timeline.problem() if timeline else None,
        },
    }


def run_info(args: argparse.Namespace) -> int:
    """Print what the bag holds; exit 1 with one warning line when it is damaged, holds unknown types or
    messages with implausible timestamps."""
    from ssf_common.bags.reader import open_bag
    from ssf_common.jsonio import dumps_strict

    with open_bag(args.path) as bag:
        info, timeline = bag.info, bag.timeline
        unknown = sorted(f"{t.name} ({t.type_name or 'no type'})" for t in info.topics if t.type_name in bag.unknown_types)
    print(dumps_strict(to_json(info, timeline)) if args.json else describe_bag(info, timeline))
    problems = [f"damaged, {info.message_count} messages readable: {'; '.join(info.damage)}"] if info.damage else []
    if unknown:
        problems.append(f"types unknown and not embedded, messages cannot be decoded: {', '.join(unknown)}")
    if timeline.problem():
        problems.append(f"{timeline.problem()}; bag play skips them")
    if problems:
        print(f"ssf: warning: {args.path}: {' / '.join(problems)}", file=sys.stderr)
        return EXIT_PROBLEM
    return 0


def add_parser(bag_commands: argparse._SubParsersAction) -> None:
    """Register `ssf bag info`."""
    parser = bag_commands.add_parser(
        "info", help="what a bag holds (MCAP or sqlite3 rosbag2)", description=run_info.__doc__
    )
    parser.add_argument("path", help="bag directory, or a .mcap / .db3 file")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.set_defaults(func=run_info)


def _join(names: Any) -> str:
    return "\n                   ".join(names)


def size_text(count: int) -> str:
    """A byte count as rosbag2 prints it: `5.6 MiB`."""
    size = float(count)
    for unit in ("B", "KiB", "MiB"):
        if size < 1024:
            return f"{count} B" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GiB"


def _time(ns: int) -> str:
    stamp = datetime.fromtimestamp(ns / 1e9, tz=timezone.utc)
    return f"{stamp:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})"
