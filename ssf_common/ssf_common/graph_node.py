"""A node that joins the graph on its inputs and reports their rates: the shell of stages still to come."""

from __future__ import annotations

from typing import Any

from ssf_common.middleware import QOS_DEFAULT, Node, QoS


class ListeningNode(Node):
    """Subscribes to the stage's inputs and logs how many messages each delivered every report period."""

    def __init__(self, name: str, inputs: dict[str, tuple[str, QoS]], argv: list[str] | None = None) -> None:
        super().__init__(name, argv=argv)
        period = self.declare_parameter("report_period_s", 5.0).value
        self.received: dict[str, int] = {topic: 0 for topic in inputs}
        for topic, (type_name, qos) in inputs.items():
            self.create_subscription(type_name, topic, self._counter(topic), qos or QOS_DEFAULT, raw=True)
        self.create_timer(period, self._report)

    def _counter(self, topic: str) -> Any:
        def count(_cdr: bytes) -> None:
            self.received[topic] += 1

        return count

    def _report(self) -> None:
        summary = ", ".join(f"{topic}: {count}" for topic, count in self.received.items())
        self.get_logger().info(f"received {summary}")
