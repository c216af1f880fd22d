"""What each stage did and whether it can answer, as the ROS-standard /diagnostics topic.

Every node keeps a `StageStats` (inputs answered and dropped, processing time) and publishes it once a second of the
steady clock as one `diagnostic_msgs/DiagnosticStatus` (name = node name, key-value pairs), whatever simulated time
does. Its level follows ROS's frequency and timestamp status conventions: WARN when an input is stale (older than two
sensor periods by the node's clock), ERROR when the node cannot answer (an input silent for `silent_after_s` of the
steady clock, or its work failing); `ssf bench graph`, `ssf bench faults` and any ROS 2 diagnostics tool read them.
A node says each new condition in one log line at once; one that keeps coming back is counted and said again only
when it lasts or once per `repeat_s`."""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import Field

from ssf_common import messages
from ssf_common.config import Section

HARDWARE_ID = "ssf-pan"
WINDOW = 2000  # processing times kept for the percentiles


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class DiagnosticsConfig(Section):
    """How a node judges its inputs and reports (parameters `diagnostics.*` of every node)."""

    period_s: float = Field(1.0, gt=0.0, description="/diagnostics is published this often (steady clock)")
    renamed: ClassVar[dict[str, str]] = {"sensor_period_s": "scan_period"}
    scan_period: float = Field(0.1, gt=0.0, description="the period inputs come at (the LiDAR's, s)")
    stale_periods: float = Field(2.0, gt=0.0, description="WARN: an input older than this many sensor periods by the "
                                 "node's clock is stale")
    silent_after_s: float = Field(2.0, gt=0.0, description="ERROR: an input silent this long by the steady clock "
                                  "leaves the node unable to answer (a dead stage above it)")
    repeat_s: float = Field(10.0, gt=0.0, description="a condition that comes back within this long is counted and "
                            "said again once it lasts lasting_s or this long has passed")
    lasting_s: float = Field(1.0, gt=0.0, description="a condition that came back and lasts this long is said at once")

    @property
    def stale_after_s(self) -> float:
        """Age (node clock) past which an input is stale."""
        return self.stale_periods * self.scan_period


class Condition(NamedTuple):
    """Something wrong with a node now: a key that names it, its level, one human line."""

    key: str
    level: Level
    text: str


@dataclass
class StageStats:
    """Counts and processing times of one node's work, and the conditions it reports beside its inputs'."""

    name: str
    counts: collections.Counter = field(default_factory=collections.Counter)
    times_ms: collections.deque = field(default_factory=lambda: collections.deque(maxlen=WINDOW))
    conditions: dict[str, Condition] = field(default_factory=dict)

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

    def report(self, key: str, level: Level, text: str) -> None:
        """A condition of the node's own (e.g. the planner braking; the node logs it itself); Level.OK clears it."""
        if level is Level.OK:
            self.conditions.pop(key, None)
        else:
            self.conditions[key] = Condition(key, level, text)

    def values(self) -> dict[str, float]:
        """The numbers reported: every count, and the median / p95 / mean processing time."""
        report: dict[str, float] = {key: float(value) for key, value in sorted(self.counts.items())}
        if self.times_ms:
            times = np.asarray(self.times_ms)
            report |= {"processing_ms_median": float(np.median(times)), "processing_ms_p95": float(np.percentile(times, 95)),
                       "processing_ms_mean": float(times.mean())}
        return report

    def message(self, stamp_ns: int, conditions: Sequence[Condition] = (), extra: dict[str, float] | None = None) -> Any:
        """diagnostic_msgs/DiagnosticArray with this node's status: level and message from the worst conditions."""
        values = self.values() | (extra or {})
        conditions = [*conditions, *self.conditions.values()]
        level = max((condition.level for condition in conditions), default=Level.OK)
        text = "; ".join(condition.text for condition in conditions if condition.level == level)
        key_value = messages.msg_type("diagnostic_msgs/msg/KeyValue")
        status = messages.msg_type("diagnostic_msgs/msg/DiagnosticStatus")(
            level=int(level), name=self.name, message=f"{text}; {summary(values)}" if text else summary(values),
            hardware_id=HARDWARE_ID, values=[key_value(key=key, value=f"{value:.6g}") for key, value in values.items()])
        return messages.msg_type("diagnostic_msgs/msg/DiagnosticArray")(
            header=messages.header(stamp_ns, ""), status=[status])


def summary(values: dict[str, float]) -> str:
    """One human line of the numbers."""
    parts = [f"{key} {value:g}" for key, value in values.items()
             if not key.startswith("processing") and not key.startswith("/")]
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


def read_levels(msg: Any) -> dict[str, tuple[Level, str]]:
    """node name -> (level, message), from a DiagnosticArray."""
    return {status.name: (Level(min(int(status.level), Level.STALE)), status.message) for status in msg.status}


class InputState(NamedTuple):
    """How fresh one input is: its level, one line, its age by the node's clock and its silence by the steady clock
    (None before its first message; age None when the clock went back since it came)."""

    topic: str
    level: Level
    text: str
    age_s: float | None
    silent_s: float | None


def input_state(topic: str, heard: Any, clock_ns: int, steady_ns: int, config: DiagnosticsConfig) -> InputState:
    """Judge one input from when it was last heard (a `Heard`, or None): ERROR when silent past silent_after_s of the
    steady clock, WARN when older than stale_after_s by the node's clock (or, when that clock went back since, by the
    steady one), else OK."""
    if heard is None:
        return InputState(topic, Level.WARN, f"no message on {topic} yet", None, None)
    silent = (steady_ns - heard.steady_ns) * 1e-9
    age = (clock_ns - heard.clock_ns) * 1e-9 if clock_ns >= heard.clock_ns else None
    if silent > config.silent_after_s:
        return InputState(topic, Level.ERROR, f"{topic} silent for {silent:.1f} s: cannot answer", age, silent)
    if (age if age is not None else silent) > config.stale_after_s:
        old = f"{age:.2f} s old" if age is not None else f"from before the clock went back, {silent:.1f} s ago"
        return InputState(topic, Level.WARN, f"{topic} stale ({old})", age, silent)
    return InputState(topic, Level.OK, f"{topic} fresh", age, silent)


def work_condition(before: collections.Counter, after: collections.Counter) -> Condition | None:
    """ERROR when inputs failed since `before` and none was answered: the node cannot answer what it gets."""
    failed = sum(after[key] - before[key] for key in after if key.endswith("_failed"))
    answered = sum(after[key] - before[key] for key in after if key.endswith("_answered"))
    if failed > 0 and answered <= 0:
        return Condition("work", Level.ERROR, f"{failed} inputs failed and none was answered")
    return None


class ConditionLog:
    """Says each condition in one line when it begins, when it gets worse (a higher level is a new condition), and
    when it is over. A condition that comes back within `repeat_s` of its last line (latency hovering around a limit)
    is counted instead, and said again, with the count, once it lasts `lasting_s` or `repeat_s` has passed: a lasting
    fault is never swallowed by the repeat limit."""

    def __init__(self, logger: Any, repeat_s: float = 10.0, lasting_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._logger = logger
        self.repeat_s, self.lasting_s = repeat_s, lasting_s
        self._clock = clock
        self.active: dict[str, tuple[float, Level]] = {}  # condition -> since when (clock s), its level now
        self._said_at: dict[str, float] = {}
        self._announced: set[str] = set()  # active conditions whose line was said
        self._unsaid: collections.Counter = collections.Counter()  # onsets since the condition's last line
        self.repeats: collections.Counter = collections.Counter()  # onsets not said at once, since the start

    def update(self, key: str, active: bool, text: str = "", level: Level = Level.WARN, over: str = "") -> None:
        """The condition `key` holds now (say `text` at `level`) or not (say `over`, or "<key>: over")."""
        now = self._clock()
        if active:
            if key not in self.active:
                self.active[key] = (now, level)
                if now - self._said_at.get(key, -math.inf) >= self.repeat_s:
                    self._say(key, text, level, now)
                else:
                    self._unsaid[key] += 1
                    self.repeats[key] += 1
                return
            since, before = self.active[key]
            self.active[key] = (since, level)
            if level > before:
                self._say(key, text, level, now)
            elif key not in self._announced and (now - since >= self.lasting_s or now - self._said_at[key] >= self.repeat_s):
                self._say(key, f"{text} (it came back {self._unsaid[key]} times since it was last said)", level, now)
        elif key in self.active:
            del self.active[key]
            if key in self._announced:
                self._announced.discard(key)
                self._logger.info(over or f"{key}: over")

    def _say(self, key: str, text: str, level: Level, now: float) -> None:
        self._said_at[key] = now
        self._announced.add(key)
        self._unsaid[key] = 0
        (self._logger.error if level >= Level.ERROR else self._logger.warning)(text)


def advertise(node: Any, stats: StageStats, refresh: Callable[[], None] | None = None,
              inputs: Sequence[str] = ()) -> DiagnosticsConfig:
    """Publish a node's stats on /diagnostics every `diagnostics.period_s` of the steady clock, judging each of its
    `inputs` (topics it subscribes to) and its work; say each change of condition in the log. refresh() first updates
    counts kept elsewhere, such as a worker's dropped inputs. Returns the node's diagnostics config."""
    from ssf_common import topics
    from ssf_common.middleware import QOS_DEFAULT

    config = node.declare_config(DiagnosticsConfig, prefix="diagnostics.")
    publisher = node.create_publisher("diagnostic_msgs/msg/DiagnosticArray", topics.DIAGNOSTICS, QOS_DEFAULT)
    log = ConditionLog(node.get_logger(), config.repeat_s, config.lasting_s)
    watched = [node.resolve_topic(topic) for topic in inputs]
    last_counts = collections.Counter(stats.counts)

    def publish() -> None:
        nonlocal last_counts
        if refresh is not None:
            refresh()
        clock_ns, steady_ns = node.get_clock().now_ns(), node.get_steady_clock().now_ns()
        heard = {subscription.topic_name: subscription.heard for subscription in node.subscriptions}
        states = [input_state(topic, heard.get(topic), clock_ns, steady_ns, config) for topic in watched]
        conditions = [Condition(state.topic, state.level, state.text) for state in states if state.level > Level.OK]
        for state in states:
            if state.silent_s is not None:  # before its first message an input is waiting, not failing: not logged
                log.update(state.topic, state.level > Level.OK, state.text, state.level, f"{state.topic} fresh again")
        work = work_condition(last_counts, stats.counts)
        last_counts = collections.Counter(stats.counts)
        log.update("work", work is not None, work.text if work else "", Level.ERROR, "inputs answered again")
        conditions += [work] if work else []
        extra = {f"{state.topic} age_s": state.age_s for state in states if state.age_s is not None}
        publisher.publish(stats.message(clock_ns, conditions, extra))

    node.create_timer(config.period_s, publish, clock=node.get_steady_clock())
    return config


def worker_counts(stats: StageStats, worker: Any) -> Callable[[], None]:
    """A refresh that copies a LatestWorker's processed / dropped / failed counts per kind of input."""

    def refresh() -> None:
        for kind in worker.processed:
            stats.set(f"{kind}_answered", worker.processed[kind])
            stats.set(f"{kind}_dropped", worker.dropped[kind])
            stats.set(f"{kind}_failed", worker.failed[kind])

    return refresh
