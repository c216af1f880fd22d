"""`ssf record [-o DIR] [TOPIC ...]`: record topics of the graph into a rosbag2 directory (MCAP storage)."""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ssf_common.errors import ConfigError, SsfError

if TYPE_CHECKING:
    from ssf_common.bags.qos import Qos
    from ssf_common.bags.writer import BagWriter

DISCOVERY_PERIOD_S = 0.25
FLUSH_CHECK_PERIOD_S = 0.25
RECORD_DEPTH = 100
CLOCK_TOPIC = "/clock"


def default_output_dir(now: float | None = None) -> Path:
    """bags/<local time> under the current directory, as rosbag2 names its recordings."""
    return Path("bags") / time.strftime("%Y_%m_%d-%H_%M_%S", time.localtime(now))


class OfferedQos:
    """QoS offered by the writers of a topic, read from DDS discovery (embedded backend; unknown elsewhere)."""

    def __init__(self, node: Any) -> None:
        self._reader = None
        if node.backend_name == "dds":
            from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication

            from ssf_common.middleware.embedded import Participant

            self._reader = BuiltinDataReader(Participant.get().dp, BuiltinTopicDcpsPublication)

    def of(self, topic: str) -> list[Any]:
        """One middleware QoS per writer of `topic` (empty when unknown)."""
        if self._reader is None:
            return []
        from cyclonedds.qos import Policy

        from ssf_common.middleware import Durability, QoS, Reliability
        from ssf_common.middleware.embedded import ros_topic_to_dds

        found = []
        for sample in self._reader.read(N=4096):
            if getattr(sample, "topic_name", None) != ros_topic_to_dds(topic):
                continue
            qos = sample.qos
            history = qos[Policy.History] if Policy.History in qos else None
            found.append(
                QoS(
                    depth=max(int(getattr(history, "depth", 10) or 10), 1),
                    reliability=Reliability.BEST_EFFORT
                    if qos[Policy.Reliability] == Policy.Reliability.BestEffort
                    else Reliability.RELIABLE,
                    durability=Durability.TRANSIENT_LOCAL
                    if qos[Policy.Durability] == Policy.Durability.TransientLocal
                    else Durability.VOLATILE,
                )
            )
        return found


def request_qos(offers: Sequence[Any]) -> Any:
    """Subscription QoS compatible with every offer (rosbag2's rule): reliable / transient-local only if all are."""
    from ssf_common.middleware import Durability, QoS, Reliability

    reliable = bool(offers) and all(q.reliability is Reliability.RELIABLE for q in offers)
    latched = bool(offers) and all(q.durability is Durability.TRANSIENT_LOCAL for q in offers)
    return QoS(
        depth=RECORD_DEPTH,
        reliability=Reliability.RELIABLE if reliable else Reliability.BEST_EFFORT,
        durability=Durability.TRANSIENT_LOCAL if latched else Durability.VOLATILE,
    )


def to_bag_profiles(offers: Sequence[Any]) -> tuple[Qos, ...]:
    """Middleware QoS offers as rosbag2 offered_qos_profiles."""
    from ssf_common.bags.qos import parse_profiles
    from ssf_common.middleware.qos import qos_to_rosbag2

    return parse_profiles([qos_to_rosbag2(q) for q in offers], "recorder")


class LogClock:
    """Log time from the graph's /clock, as `ros2 bag record --use-sim-time` takes it: each message is logged at the
    latest /clock value; those that arrive before the first /clock wait for it (at 0 when none comes)."""

    def __init__(self, node: Any, writer: BagWriter) -> None:
        from ssf_common import messages
        from ssf_common.middleware import QOS_CLOCK

        self._messages = messages
        self.writer = writer
        self.now_ns: int | None = None
        self.waiting: list[tuple[str, bytes]] = []
        node.create_subscription("rosgraph_msgs/msg/Clock", CLOCK_TOPIC, self.on_clock, QOS_CLOCK)

    def on_clock(self, msg: Any) -> None:
        """Advance the log time; the first tick releases the messages that waited for it."""
        self.now_ns = self._messages.stamp_ns(msg.clock)
        self.release()

    def write(self, topic: str, data: bytes) -> None:
        """Log one message at the current /clock time."""
        if self.now_ns is None:
            self.waiting.append((topic, bytes(data)))
        else:
            self.writer.write(topic, data, self.now_ns)

    def release(self) -> None:
        """Write the messages that waited for the first /clock (at 0 when it never came)."""
        for topic, data in self.waiting:
            self.writer.write(topic, data, self.now_ns or 0)
        self.waiting.clear()


def make_recorder_class():
    """The recorder node class (built lazily so `ssf --help` does not import the middleware)."""
    from ssf_common.middleware import Node

    class Recorder(Node):
        """Subscribes (raw CDR) to the chosen topics or to every topic that appears, writing each message (every
        n-th of a thinned topic) at its log time: wall time, or the graph's /clock with `sim_time`."""

        def __init__(self, writer: BagWriter, topics: Sequence[str] | None, argv: list[str] | None = None, *,
                     sim_time: bool = False, every: Mapping[str, int] | None = None) -> None:
            super().__init__("ssf_recorder", argv=argv)
            self.writer = writer
            self.wanted = None if not topics else set(topics)
            self.every = dict(every or {})
            self.received: Counter[str] = Counter()
            self.offers = OfferedQos(self)
            self.skipped: set[str] = set()
            self.log_clock = LogClock(self, writer) if sim_time else None
            self.create_timer(DISCOVERY_PERIOD_S, self.discover)
            self.create_timer(FLUSH_CHECK_PERIOD_S, self.writer.flush_if_due)
            self.call_soon(self.discover)

        def discover(self) -> None:
            """Subscribe to topics that appeared since the last look."""
            for topic, types in self.get_topic_names_and_types():
                if topic in self.writer.topics or topic in self.skipped:
                    continue
                if self.wanted is not None and topic not in self.wanted:
                    continue
                try:
                    if len(types) != 1:
                        raise ConfigError(f"{topic} is published with several types {types}")
                    self.subscribe(topic, types[0])
                except SsfError as err:
                    self.skipped.add(topic)
                    self.get_logger().warning(f"not recording {topic}: {err}")

        def subscribe(self, topic: str, type_name: str) -> None:
            """Start recording one topic."""
            offers = self.offers.of(topic)
            self.writer.add_topic(topic, type_name, to_bag_profiles(offers))
            self.create_subscription(type_name, topic, lambda data, name=topic: self.take(name, data),
                                     request_qos(offers), raw=True)
            thinned = f", one message in {self.every[topic]}" if self.every.get(topic, 1) > 1 else ""
            self.get_logger().info(f"recording {topic} ({type_name}){thinned}")

        def take(self, topic: str, data: bytes) -> None:
            """Write one received message (unless its topic is thinned and this is not its turn)."""
            self.received[topic] += 1
            if (self.received[topic] - 1) % self.every.get(topic, 1):
                return
            if self.log_clock is not None:
                self.log_clock.write(topic, data)
            else:
                self.writer.write(topic, data, self.get_clock().now_ns())

        def on_shutdown(self) -> None:
            """Write what already arrived, then close the bag: summary, metadata record and metadata.yaml."""
            self.deliver_received()
            if self.log_clock is not None:
                self.log_clock.release()
            self.writer.close()
            self.get_logger().info(f"wrote {self.writer.message_count} messages to {self.writer.directory}")

    return Recorder


def run_record(args: argparse.Namespace) -> int:
    """Record until SIGINT/SIGTERM, then close a valid bag."""
    from ssf_common.bags.writer import BagWriter, BagWriterConfig
    from ssf_common.config import build, dump
    from ssf_common.middleware import run

    settings = {"chunk_bytes": args.chunk_bytes, "chunk_seconds": args.chunk_seconds}
    config = build(BagWriterConfig, {k: v for k, v in settings.items() if v is not None}, source="ssf record")
    directory = Path(args.output) if args.output else default_output_dir()
    for topic in args.topics:
        check_topic_name(topic)
    every = parse_every(args.every)
    custom = {"recorder": "ssf record", "writer_config": dump(config), "log_time": "/clock" if args.use_sim_time
              else "wall clock"}
    if every:
        custom["thinned"] = ", ".join(f"{topic}: one message in {n}" for topic, n in every.items())
    writer = BagWriter(directory, config, custom_data=custom)
    print(f"recording to {directory}" + (" (log time from /clock)" if args.use_sim_time else ""), file=sys.stderr)
    recorder = make_recorder_class()
    status = run(lambda argv: recorder(writer, args.topics, argv=argv, sim_time=args.use_sim_time, every=every),
                 argv=[])
    writer.close()
    return status


def check_topic_name(topic: str) -> str:
    """ConfigError, in one line, for a topic name that is not absolute."""
    if not topic.startswith("/"):
        raise ConfigError(f"topic '{topic}' must be absolute (start with '/')")
    return topic


def parse_every(items: Sequence[str]) -> dict[str, int]:
    """`--every TOPIC:N` flags as {topic: n}; ConfigError, in one line, for a malformed one."""
    every: dict[str, int] = {}
    for item in items:
        topic, _, count = item.rpartition(":")
        if not topic or not count.isdigit() or int(count) < 1:
            raise ConfigError(f"--every {item!r}: expected TOPIC:N with N a whole number from 1 (e.g. /ssf/semantic_flow:2)")
        every[check_topic_name(topic)] = int(count)
    return every


def add_parser(top: argparse._SubParsersAction) -> None:
    """Register `ssf record`."""
    parser = top.add_parser("record", help="record topics to a rosbag2 directory (MCAP)", description=run_record.__doc__)
    parser.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (all when none is named)")
    parser.add_argument("-o", "--output", metavar="DIR", help="bag directory to create (default bags/<time>)")
    parser.add_argument("--use-sim-time", action="store_true",
                        help="log each message at the graph's /clock time (as ros2 bag record --use-sim-time), so "
                        "that the bag's duration and its replay follow simulated time")
    parser.add_argument("--every", action="append", default=[], metavar="TOPIC:N",
                        help="record only every N-th message of TOPIC, starting with the first (repeatable)")
    parser.add_argument("--chunk-bytes", type=int, help="finish a chunk at this size (default 4 MiB)")
    parser.add_argument("--chunk-seconds", type=float, help="finish a chunk at least this often (default 1 s)")
    parser.set_defaults(func=run_record)
