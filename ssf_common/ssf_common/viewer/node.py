"""The graph side of the live view: discover the graph's topics, advertise each, and subscribe (raw CDR) to a topic
only while a Foxglove client watches it, as foxglove_bridge does on a ROS 2 machine."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from ssf_common import messages, topics
from ssf_common.errors import ConfigError, SsfError

if TYPE_CHECKING:
    from ssf_common.viewer.server import FoxgloveServer

DISCOVERY_PERIOD_S = 0.25


def make_viewer_class() -> type:
    """The viewer node class (built lazily so that `ssf --help` does not import the middleware)."""
    from ssf_common.bags.record import OfferedQos, request_qos
    from ssf_common.middleware import QOS_CLOCK, Node

    class Viewer(Node):
        """Advertises every topic of the graph on a Foxglove server and forwards the watched ones' CDR bytes."""

        def __init__(self, server: FoxgloveServer, argv: list[str] | None = None) -> None:
            super().__init__("ssf_viewer", argv=argv)
            self.server = server
            self.offers = OfferedQos(self)
            self.types: dict[str, str] = {}
            self.skipped: set[str] = set()
            self.watched: dict[str, Any] = {}
            self.sim_time_ns: int | None = None
            self.forwarded = 0
            server.set_subscription_callbacks(
                lambda topic: self.call_soon(lambda: self.watch(topic)),
                lambda topic: self.call_soon(lambda: self.unwatch(topic)),
            )
            self.create_timer(DISCOVERY_PERIOD_S, self.discover)
            self.call_soon(self.discover)

        def discover(self) -> None:
            """Advertise the topics that appeared since the last look (the graph's time comes from /clock)."""
            for topic, types in self.get_topic_names_and_types():
                if topic in self.types or topic in self.skipped:
                    continue
                try:
                    if len(types) != 1:
                        raise ConfigError(f"{topic} is published with several types {types}")
                    self.server.advertise(topic, types[0])
                except SsfError as err:
                    self.skipped.add(topic)
                    self.get_logger().warning(f"not serving {topic}: {err}")
                    continue
                self.types[topic] = types[0]
                if topic == topics.CLOCK:
                    self.watch(topic)  # always: it sets the time the clients see

        def watch(self, topic: str) -> None:
            """Subscribe to a topic's CDR bytes (a client subscribed to it)."""
            if topic in self.watched or topic not in self.types:
                return
            on_data = self._on_clock if topic == topics.CLOCK else lambda cdr: self._forward(topic, cdr)
            qos = QOS_CLOCK if topic == topics.CLOCK else request_qos(self.offers.of(topic))
            self.watched[topic] = self.create_subscription(self.types[topic], topic, on_data, qos, raw=True)
            self.get_logger().info(f"serving {topic} ({self.types[topic]})")

        def unwatch(self, topic: str) -> None:
            """Stop receiving a topic nobody watches any more (/clock stays)."""
            if topic == topics.CLOCK or topic not in self.watched:
                return
            self.destroy_subscription(self.watched.pop(topic))
            self.get_logger().info(f"no client watches {topic} any more")

        def now_ns(self) -> int:
            """The graph's time: the latest /clock, or the wall clock when the graph has none."""
            return self.sim_time_ns if self.sim_time_ns is not None else time.time_ns()

        def on_shutdown(self) -> None:
            """Say what was served."""
            self.get_logger().info(f"forwarded {self.forwarded} messages of {len(self.types)} topics")

        def _forward(self, topic: str, cdr: bytes) -> None:
            self.server.log(topic, cdr, self.now_ns())
            self.forwarded += 1

        def _on_clock(self, cdr: bytes) -> None:
            clock = messages.deserialize(cdr, "rosgraph_msgs/msg/Clock")
            self.sim_time_ns = messages.stamp_ns(clock.clock)
            self.server.broadcast_time(self.sim_time_ns)
            self._forward(topics.CLOCK, cdr)

    return Viewer
