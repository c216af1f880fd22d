"""`ssf bag play PATH`: publish a bag's messages into the graph with their recorded timing and QoS."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

from ssf_common.checks import require_finite
from ssf_common.errors import BagError

if TYPE_CHECKING:
    from ssf_common.bags.qos import Qos
    from ssf_common.bags.reader import BagReader

CLOCK_TOPIC = "/clock"
CLOCK_PERIOD_NS = 10_000_000  # /clock at 100 Hz of bag time


class PlayOptions(NamedTuple):
    """How to replay a bag."""

    rate: float = 1.0
    loop: bool = False
    clock: bool = False
    topics: tuple[str, ...] | None = None
    delay_s: float = 0.0


class PlayStats(NamedTuple):
    """What one replay did."""

    messages: int
    clock_ticks: int
    passes: int
    skipped: int = 0  # messages stamped outside the recording's span (per pass)


class Pacer:
    """Maps bag time to wall time at a rate, sleeping until each instant unless asked to stop."""

    def __init__(
        self,
        rate: float,
        stop: threading.Event,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.rate = rate
        self._stop = stop
        self._clock = clock
        self._origin_wall = 0.0
        self._origin_ns = 0

    def restart(self, bag_ns: int) -> None:
        """Make `bag_ns` correspond to now."""
        self._origin_wall = self._clock()
        self._origin_ns = bag_ns

    def wait_until(self, bag_ns: int) -> bool:
        """Sleep until the wall time of `bag_ns`; False if a stop was requested meanwhile."""
        target = self._origin_wall + (bag_ns - self._origin_ns) * 1e-9 / self.rate
        remaining = target - self._clock()
        if remaining > 0:
            return not self._stop.wait(remaining)
        return not self._stop.is_set()


def publisher_qos(profiles: tuple[Qos, ...]) -> Any:
    """The QoS to offer on replay: the recorded publishers' one when they agree, else the ROS default."""
    from ssf_common.bags.qos import profiles_to_dicts
    from ssf_common.middleware import QOS_DEFAULT
    from ssf_common.middleware.qos import qos_from_rosbag2

    if not profiles:
        return QOS_DEFAULT
    offered = {qos_from_rosbag2(entry) for entry in profiles_to_dicts(profiles)}
    if len({(q.reliability, q.durability) for q in offered}) > 1:
        return QOS_DEFAULT
    return max(offered, key=lambda q: q.depth)


class Player:
    """Publishes a bag's messages at their recorded pace (scaled by the rate), with /clock if asked."""

    def __init__(
        self,
        bag: BagReader,
        options: PlayOptions,
        node: Any,
        stop: threading.Event,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        from ssf_common import messages

        self._messages = messages
        self.bag = bag
        self.options = options
        self.topics = _selected_topics(bag, options.topics)
        bag.require_types(self.topics)
        self.publishers = {
            name: node.create_publisher(bag.topics[name].type_name, name, publisher_qos(bag.topics[name].offered_qos))
            for name in self.topics
        }
        self.clock_publisher = _clock_publisher(node) if options.clock else None
        self._clock_type = messages.msg_type("rosgraph_msgs/msg/Clock")
        self._stop = stop
        self._pacer = Pacer(options.rate, stop, clock)
        self._next_tick_ns = 0
        self.timeline = bag.timeline
        self.sent = self.ticks = self.passes = self.skipped = 0

    def run(self) -> PlayStats:
        """Wait the start delay, then play once (or until stopped, with loop)."""
        if self.options.delay_s > 0 and self._stop.wait(self.options.delay_s):
            return self.stats
        while not self._stop.is_set():
            played_any = self._play_pass()
            self.passes += 1
            if not self.options.loop or not played_any:
                break
        return self.stats

    @property
    def stats(self) -> PlayStats:
        """What was played so far."""
        return PlayStats(self.sent, self.ticks, self.passes, self.skipped)

    def _play_pass(self) -> bool:
        """One pass over the bag, skipping stamps outside the recording's span; False if it played nothing."""
        played_any = False
        self.skipped = 0
        for message in self.bag.messages(self.topics):
            if not self.timeline.contains(message.timestamp_ns):
                self.skipped += 1
                continue
            if not played_any:
                self._pacer.restart(message.timestamp_ns)
                self._next_tick_ns = message.timestamp_ns
                played_any = True
            if not self._clock_until(message.timestamp_ns) or not self._pacer.wait_until(message.timestamp_ns):
                break
            self.publishers[message.topic].publish_raw(message.data)
            self.sent += 1
        return played_any

    def _clock_until(self, bag_ns: int) -> bool:
        """Publish the /clock ticks due up to `bag_ns`; False if stopped meanwhile."""
        if self.clock_publisher is None:
            return True
        while self._next_tick_ns <= bag_ns:
            if not self._pacer.wait_until(self._next_tick_ns):
                return False
            stamp = self._messages.stamp(self._next_tick_ns)
            self.clock_publisher.publish(self._clock_type(clock=stamp))
            self.ticks += 1
            self._next_tick_ns += CLOCK_PERIOD_NS
        return True


def run_play(args: argparse.Namespace) -> int:
    """Replay a bag into the graph; SIGINT/SIGTERM stop it."""
    from ssf_common.bags.reader import open_bag
    from ssf_common.middleware import Node, shutdown

    options = PlayOptions(
        rate=require_finite(args.rate, "--rate", above=0.0),
        loop=args.loop,
        clock=args.clock,
        topics=tuple(args.topics) if args.topics else None,
        delay_s=require_finite(args.delay, "--delay", at_least=0.0),
    )
    from ssf_common.viewer.command import BackgroundViewer, viewer_config

    viewer_settings = viewer_config(args, "ssf bag play")
    stop = threading.Event()
    with open_bag(args.path) as bag:
        info, timeline = bag.info, bag.timeline
        if info.damage:
            print(f"ssf: warning: damaged bag, playing the {info.message_count} readable messages:"
                  f" {'; '.join(info.damage)}", file=sys.stderr)
        if timeline.problem():
            print(f"ssf: warning: {args.path}: {timeline.problem()}; skipping them", file=sys.stderr)
        node = Node("ssf_bag_player", argv=["--ros-args", *args.ros_args] if args.ros_args else [])
        viewer = BackgroundViewer(viewer_settings) if viewer_settings else None  # serves what the player publishes
        previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            stats = Player(bag, options, node, stop).run()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            if viewer is not None:
                viewer.close()
            node.destroy_node()
            shutdown()
    skipped = f", skipped {stats.skipped} with implausible timestamps" if stats.skipped else ""
    print(f"played {stats.messages} messages in {stats.passes} pass(es), {stats.clock_ticks} /clock ticks{skipped}",
          file=sys.stderr)
    return 1 if info.damage or stats.skipped else 0


def add_parser(bag_commands: argparse._SubParsersAction) -> None:
    """Register `ssf bag play`."""
    from ssf_common.viewer.command import add_foxglove_options

    parser = bag_commands.add_parser("play", help="replay a bag into the graph", description=run_play.__doc__)
    parser.add_argument("path", help="bag directory, or a .mcap / .db3 file")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1.0)")
    parser.add_argument("--loop", action="store_true", help="start over at the end, until interrupted")
    parser.add_argument("--clock", action="store_true", help="publish /clock at 100 Hz of bag time")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="replay only these topics")
    parser.add_argument("--delay", type=float, default=0.0, help="seconds to wait (for discovery) before playing")
    add_foxglove_options(parser)
    parser.add_argument("--ros-args", nargs=argparse.REMAINDER, dest="ros_args", help=argparse.SUPPRESS)
    parser.set_defaults(func=run_play)


def _selected_topics(bag: BagReader, wanted: Sequence[str] | None) -> list[str]:
    if wanted is None:
        return [name for name, topic in bag.topics.items() if topic.message_count]
    missing = [name for name in wanted if name not in bag.topics]
    if missing:
        raise BagError(f"{bag.path}: no topic {', '.join(missing)} in the bag (it has {', '.join(sorted(bag.topics))})")
    return list(dict.fromkeys(wanted))


def _clock_publisher(node: Any) -> Any:
    from ssf_common.middleware import QOS_CLOCK

    return node.create_publisher("rosgraph_msgs/msg/Clock", CLOCK_TOPIC, QOS_CLOCK)
