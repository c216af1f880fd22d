"""What each stage did, as the ROS-standard /diagnostics topic: inputs answered and dropped, processing time.

Every node keeps a `StageStats` and publishes it about once a second as one `diagnostic_msgs/DiagnosticStatus`
(name = node name, key-value pairs); `ssf bench graph` and any ROS 2 diagnostics tool read them."""

from __future__ import annotations

import collections
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ssf_common import messages

HARDWARE_ID = "ssf-pan"
WINDOW = 2000  # processing times kept for the percentiles


@dataclass
class StageStats:
    """Counts and processing times of one node's work."""

    name: str
    counts: collections.Counter = field(default_factory=collections.Counter)
    times_ms: collections.deque = field(default_factory=lambda: collections.deque(maxlen=WINDOW))

    def record(self, milliseconds: float, answered: str = "answered") -> None:
        """One input answered in this many milliseconds of processing."""
        self.times_ms.append(float(milliseconds))
        self.counts[answered] += 1

    def count(self, key: str, amount: int = 1) -> None:
        """Count something (dropped, failed, fallbacks, ...)."""
        self.counts[key] += amount

    def set(self, key: str, value: int) -> None:
        """Set a cumulative count kept elsewhere (e.g. a worker's dropped inputs)."""
        self.counts[key] = int(value)

    def values(self) -> dict[str, float]:
        """The numbers reported: every count, and the median / p95 / mean processing time."""
        report: dict[str, float] = {key: float(value) for key, value in sorted(self.counts.items())}
        if self.times_ms:
            times = np.asarray(self.times_ms)
            report |= {"processing_ms_median": float(np.median(times)), "processing_ms_p95": float(np.percentile(times, 95)),
                       "processing_ms_mean": float(times.mean())}
        return report

    def message(self, stamp_ns: int) -> Any:
        """diagnostic_msgs/DiagnosticArray with this node's status."""
        key_value = messages.msg_type("diagnostic_msgs/msg/KeyValue")
        status = messages.msg_type("diagnostic_msgs/msg/DiagnosticStatus")(
            level=0, name=self.name, message=summary(self.values()), hardware_id=HARDWARE_ID,
            values=[key_value(key=key, value=f"{value:.6g}") for key, value in self.values().items()])
        return messages.msg_type("diagnostic_msgs/msg/DiagnosticArray")(
            header=messages.header(stamp_ns, ""), status=[status])


def summary(values: dict[str, float]) -> str:
    """One human line of the numbers."""
    parts = [f"{key} {value:g}" for key, value in values.items() if not key.startswith("processing")]
    if "processing_ms_median" in values:
        parts.append(f"median {values['processing_ms_median']:.1f} ms, p95 {values['processing_ms_p95']:.1f} ms")
    return ", ".join(parts)


def read_status(msg: Any) -> dict[str, dict[str, float]]:
    """node name -> its numbers, from a DiagnosticArray (values that are not numbers are left out)."""
    found: dict[str, dict[str, float]] = {}
    for status in msg.status:
        numbers = {}
        for item in status.values:
            try:
                numbers[item.key] = float(item.value)
            except ValueError:
                continue
        found[status.name] = numbers
    return found


def advertise(node: Any, stats: StageStats, period_s: float = 1.0, refresh: Callable[[], None] | None = None) -> None:
    """Publish a node's stats on /diagnostics every period_s of its clock (refresh() first updates counts kept
    elsewhere, such as a worker's dropped inputs)."""
    from ssf_common import topics
    from ssf_common.middleware import QOS_DEFAULT

    publisher = node.create_publisher("diagnostic_msgs/msg/DiagnosticArray", topics.DIAGNOSTICS, QOS_DEFAULT)

    def publish() -> None:
        if refresh is not None:
            refresh()
        publisher.publish(stats.message(node.get_clock().now_ns()))

    node.create_timer(period_s, publish)


def worker_counts(stats: StageStats, worker: Any) -> Callable[[], None]:
    """A refresh that copies a LatestWorker's processed / dropped / failed counts per kind of input."""

    def refresh() -> None:
        for kind in worker.processed:
            stats.set(f"{kind}_answered", worker.processed[kind])
            stats.set(f"{kind}_dropped", worker.dropped[kind])
            stats.set(f"{kind}_failed", worker.failed[kind])

    return refresh
