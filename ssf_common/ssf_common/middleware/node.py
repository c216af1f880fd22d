"""An rclpy-shaped node whose transport is a pluggable backend and whose callbacks run on one thread."""

from __future__ import annotations

import collections
import os
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeVar

from pydantic import BaseModel

from ssf_common import config as config_lib
from ssf_common import messages
from ssf_common.errors import ConfigError, MessageError, SsfError
from ssf_common.middleware.params import Parameter, coerce, parse_ros_args
from ssf_common.middleware.qos import QOS_CLOCK, QOS_DEFAULT, QoS

ModelT = TypeVar("ModelT", bound=BaseModel)
DecodedT = TypeVar("DecodedT")

_LEVELS = {"debug": 10, "info": 20, "warn": 30, "warning": 30, "error": 40, "fatal": 50}


class Logger:
    """ROS-style console logger: `[LEVEL] [time] [node]: message` on stderr."""

    def __init__(self, name: str, level: str | None = None) -> None:
        self.name = name
        self.level = _LEVELS.get((level or os.environ.get("SSF_LOG_LEVEL", "info")).lower(), 20)

    def _log(self, level: str, text: str) -> None:
        if _LEVELS[level] >= self.level:
            print(f"[{level.upper()}] [{time.time():.6f}] [{self.name}]: {text}", file=sys.stderr, flush=True)

    def debug(self, text: str) -> None:
        """Log at debug level."""
        self._log("debug", text)

    def info(self, text: str) -> None:
        """Log at info level."""
        self._log("info", text)

    def warning(self, text: str) -> None:
        """Log at warning level."""
        self._log("warn", text)

    warn = warning

    def error(self, text: str) -> None:
        """Log at error level."""
        self._log("error", text)

    def fatal(self, text: str) -> None:
        """Log at fatal level."""
        self._log("fatal", text)


class Clock:
    """Node clock: wall time, or the latest /clock value when use_sim_time is set."""

    steady = False  # a clock that can stand still or jump back (simulated time) or be set (wall time)

    RATE_WINDOW_NS = 1_000_000_000  # sim time runs with the steady clock when it kept pace over this long ...
    RATE = 0.7  # ... at least at this rate (a loaded real-time simulator lags; one in lockstep crawls or stands)

    def __init__(self) -> None:
        self.use_sim_time = False
        self._sim_ns = 0
        self._ticks: collections.deque[tuple[int, int]] = collections.deque()  # (steady ns, sim ns) of recent /clock

    def now_ns(self) -> int:
        """Current time in nanoseconds (0 in sim time until the first /clock)."""
        return self._sim_ns if self.use_sim_time else time.time_ns()

    def now_s(self) -> float:
        """Current time in seconds."""
        return self.now_ns() * 1e-9

    def set_sim_time(self, nanoseconds: int) -> None:
        """Advance sim time (from /clock)."""
        self._sim_ns = nanoseconds
        now = time.monotonic_ns()
        self._ticks.append((now, int(nanoseconds)))
        while self._ticks and now - self._ticks[0][0] > self.RATE_WINDOW_NS:
            self._ticks.popleft()

    def running(self, steady_ns: int, within_ns: int) -> bool:
        """Whether the clock moves with the steady one: wall time, or sim time whose /clock came within `within_ns`
        and kept pace with the steady clock over the last RATE_WINDOW_NS (a simulator in real time; not one in
        lockstep, whose time waits for the graph, nor a dead one)."""
        if not self.use_sim_time:
            return True
        if not self._ticks or steady_ns - self._ticks[-1][0] > within_ns:
            return False
        (first_steady, first_sim), (last_steady, last_sim) = self._ticks[0], self._ticks[-1]
        span = last_steady - first_steady
        return span >= self.RATE_WINDOW_NS // 2 and last_sim - first_sim >= self.RATE * span


class SteadyClock:
    """A clock that cannot stop or go back (rclpy's STEADY_TIME): what liveness checks and their timers run on."""

    steady = True
    use_sim_time = False

    def now_ns(self) -> int:
        """Monotonic nanoseconds (an arbitrary origin)."""
        return time.monotonic_ns()

    def now_s(self) -> float:
        """Monotonic seconds."""
        return self.now_ns() * 1e-9


@dataclass
class Timer:
    """A periodic callback on a clock (the node's, or a steady one)."""

    due: float
    period: float
    callback: Callable[[], None]
    clock: Clock | SteadyClock
    cancelled: bool = False

    def cancel(self) -> None:
        """Stop the timer."""
        self.cancelled = True

    def advance(self, now: float) -> None:
        """The next due time after a call at `now`: one period on, missed periods skipped rather than burst."""
        self.due += self.period
        if self.due <= now:
            self.due = now + self.period

    def follow(self, now: float) -> None:
        """A clock gone back by more than a period (a restarted simulator, a looping bag) starts a new sequence: the
        timer is due a period from now instead of waiting for the clock to pass the old due time."""
        if self.due - now > self.period * (1.0 + 1e-9):
            self.due = now + self.period


class Publisher:
    """Publishes messages (serialised once, here) or ready-made CDR bytes."""

    def __init__(self, transport: Any, type_name: str, topic: str) -> None:
        self._transport = transport
        self.msg_type = type_name
        self.topic_name = topic

    def publish(self, msg: Any) -> None:
        """Serialise and publish one message."""
        self._transport.publish_raw(messages.serialize(msg, self.msg_type))

    def publish_raw(self, cdr: bytes | memoryview) -> None:
        """Publish CDR bytes as they are (bag replay)."""
        self._transport.publish_raw(cdr)

    def get_subscription_count(self) -> int:
        """Matched subscriptions."""
        return self._transport.matched_count()

    def wait_for_all_acked(self, timeout_s: float = 1.0) -> bool:
        """Block until every matched reliable subscription acknowledged what was published (rclpy's name), or the
        timeout; True if they all did."""
        return self._transport.wait_for_all_acked(timeout_s)


class Heard(NamedTuple):
    """When a message came: the node's clock (simulated time under use_sim_time) and the steady clock (ns)."""

    clock_ns: int
    steady_ns: int


class Subscription:
    """Delivers decoded messages (or raw CDR) of one topic to a callback on the node's thread."""

    def __init__(self, node: "Node", type_name: str, topic: str, callback: Callable[[Any], None], raw: bool) -> None:
        self._node = node
        self.msg_type = type_name
        self.topic_name = topic
        self._callback = callback
        self._raw = raw
        self.transport: Any = None
        self.dropped = 0
        self.received = 0  # messages its callback took without raising
        self.heard: Heard | None = None  # when the newest of them came

    def deliver(self, cdr: bytes) -> None:
        """Decode one sample and run the callback; a bad message is logged and dropped."""
        try:
            self._callback(cdr if self._raw else messages.deserialize(cdr, self.msg_type))
            self.received += 1
            self.heard = Heard(self._node.get_clock().now_ns(), time.monotonic_ns())
        except SsfError as err:
            self.dropped += 1
            self._node.get_logger().error(dropped_text(self.topic_name, err))
        except Exception as err:  # noqa: BLE001 - a node keeps running whatever one message does
            self.dropped += 1
            self._node.get_logger().error(
                f"callback for {self.topic_name} failed on one message ({type(err).__name__}: {err}); dropped it"
            )

    def get_publisher_count(self) -> int:
        """Matched publishers."""
        return self.transport.matched_count()


def dropped_text(topic: str, err: object, consequence: str = "") -> str:
    """The one line every node logs for a message it could not use."""
    return f"dropped a message on {topic}: {err}{consequence}"


def selected_backend() -> str:
    """'rclpy' or 'dds', from SSF_MIDDLEWARE=auto|rclpy|dds (auto: rclpy when it imports)."""
    choice = os.environ.get("SSF_MIDDLEWARE", "auto").lower()
    if choice not in ("auto", "rclpy", "dds"):
        raise ConfigError(f"SSF_MIDDLEWARE must be auto, rclpy or dds, got {choice!r}")
    if choice == "dds":
        return "dds"
    try:
        import rclpy  # noqa: F401
    except ImportError:
        if choice == "rclpy":
            raise ConfigError("SSF_MIDDLEWARE=rclpy but rclpy does not import: source a ROS 2 Jazzy setup") from None
        return "dds"
    return "rclpy"


def make_backend(node_name: str, namespace: str) -> Any:
    """The transport of one node, as selected_backend() says."""
    if selected_backend() == "rclpy":
        from ssf_common.middleware.rclpy_backend import RclpyBackend

        return RclpyBackend(node_name, namespace)
    from ssf_common.middleware.embedded import EmbeddedBackend

    return EmbeddedBackend(node_name, namespace)


class Node:
    """Base class of every node: parameters, config, logger, clock, pub/sub, timers, spin."""

    def __init__(self, node_name: str, *, argv: list[str] | None = None, namespace: str = "") -> None:
        ros_args = parse_ros_args(list(argv or []), node_name)
        self._name = ros_args.node_name or node_name
        self._namespace = "/" + (ros_args.namespace or namespace).strip("/")
        self._remappings = ros_args.remappings
        self._overrides = ros_args.parameters
        self.unparsed_args = ros_args.unparsed
        self._parameters: dict[str, Parameter] = {}
        self._logger = Logger(self._name)
        self._clock = Clock()
        self._events: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._timers: list[Timer] = []
        self._steady_clock = SteadyClock()
        self._subscriptions: list[Subscription] = []
        self._publishers: list[Publisher] = []
        self._stop = threading.Event()
        self._spinner: threading.Thread | None = None
        self._backend = make_backend(self._name, self._namespace)
        if self.declare_parameter("use_sim_time", False).value:
            self._clock.use_sim_time = True
            self.create_subscription("rosgraph_msgs/msg/Clock", "/clock", self._on_clock, QOS_CLOCK)

    # Identity and helpers

    def get_name(self) -> str:
        """Node name (after a __node remap)."""
        return self._name

    def get_namespace(self) -> str:
        """Node namespace."""
        return self._namespace

    def get_logger(self) -> Logger:
        """The node's logger."""
        return self._logger

    def get_clock(self) -> Clock:
        """The node's clock (sim time when use_sim_time)."""
        return self._clock

    def get_steady_clock(self) -> SteadyClock:
        """A clock that cannot stop or jump back, for liveness: `create_timer(period, callback, clock=...)`."""
        return self._steady_clock

    def decoded(self, decode: Callable[..., DecodedT], msg: Any, topic: str, *args: Any,
                errors: tuple[type[Exception], ...] = (MessageError,), consequence: str = "") -> DecodedT | None:
        """`decode(msg, *args)`, or None with a warning that the message on `topic` was dropped (and what follows)."""
        try:
            return decode(msg, *args)
        except errors as err:
            self._logger.warning(dropped_text(topic, err, consequence))
            return None

    @property
    def subscriptions(self) -> list[Subscription]:
        """The node's subscriptions (as rclpy's Node.subscriptions)."""
        return list(self._subscriptions)

    @property
    def backend_name(self) -> str:
        """'dds' or 'rclpy'."""
        return self._backend.name

    def resolve_topic(self, topic: str) -> str:
        """Apply remappings and the namespace to a topic name."""
        topic = self._remappings.get(topic, topic)
        resolved = topic if topic.startswith("/") else f"{self._namespace.rstrip('/')}/{topic}"
        return self._remappings.get(resolved, resolved)

    # Parameters and config

    def declare_parameter(self, name: str, default: Any = None) -> Parameter:
        """Declare a parameter; an override from --ros-args or --params-file wins if its type fits."""
        value = self._overrides[name] if name in self._overrides else default
        parameter = Parameter(name, coerce(name, value, default))
        self._parameters[name] = parameter
        return parameter

    def get_parameter(self, name: str) -> Parameter:
        """A declared parameter."""
        try:
            return self._parameters[name]
        except KeyError:
            raise ConfigError(f"parameter '{name}' was not declared") from None

    def has_parameter(self, name: str) -> bool:
        """Whether the parameter is declared."""
        return name in self._parameters

    def undeclared_overrides(self) -> list[str]:
        """Overrides given on the command line or in a params file that no declaration used."""
        return sorted(name for name in self._overrides if name not in self._parameters)

    def declare_config(self, model: type[ModelT], prefix: str = "", defaults: dict[str, Any] | None = None) -> ModelT:
        """Declare every field of a config model as a dotted parameter (defaults: the model's, with `defaults`
        laid over them) and return the validated model."""
        defaults = config_lib.flatten(config_lib.build(model, defaults or {}).model_dump(mode="json"))
        for key in [key for key in self._overrides if key.startswith(prefix)]:  # renamed fields' old names too
            name = prefix + config_lib.current_name(model, key[len(prefix):])
            if name != key and name in self._overrides:
                raise ConfigError(f"parameter '{key}' is the old name of '{name}': give only '{name}'")
            if name != key:
                self._overrides[name] = self._overrides.pop(key)
        values = {}
        for name, default in defaults.items():
            values[name] = self.declare_parameter(f"{prefix}{name}", default).value
        sections = {name.split(".")[0] + "." for name in defaults if "." in name}
        misspelled = [
            key for key in self._overrides
            if key.startswith(prefix) and key[len(prefix):] not in defaults
            and any(key[len(prefix):].startswith(section) for section in sections)
        ]
        if misspelled:
            raise ConfigError(f"unknown parameter '{misspelled[0]}' for node {self._name}")
        return config_lib.build(model, values, source=f"parameters of {self._name}")

    # Communication

    def create_publisher(self, msg_type: type | str, topic: str, qos: QoS = QOS_DEFAULT) -> Publisher:
        """A publisher of one message type on one topic."""
        type_name = _type_name(msg_type)
        topic = self.resolve_topic(topic)
        publisher = Publisher(self._backend.create_publisher(type_name, topic, qos), type_name, topic)
        self._publishers.append(publisher)
        return publisher

    def create_subscription(
        self,
        msg_type: type | str,
        topic: str,
        callback: Callable[[Any], None],
        qos: QoS = QOS_DEFAULT,
        *,
        raw: bool = False,
    ) -> Subscription:
        """Subscribe; callback gets the message (or CDR bytes with raw=True) on the node's thread."""
        type_name = _type_name(msg_type)
        topic = self.resolve_topic(topic)
        subscription = Subscription(self, type_name, topic, callback, raw)
        subscription.transport = self._backend.create_subscription(
            type_name, topic, qos, subscription.deliver, self._events.put
        )
        self._subscriptions.append(subscription)
        return subscription

    def destroy_subscription(self, subscription: Subscription) -> bool:
        """Stop one subscription (as rclpy's Node.destroy_subscription); False when it is not this node's."""
        if subscription not in self._subscriptions:
            return False
        self._subscriptions.remove(subscription)
        subscription.transport.destroy()
        return True

    def create_timer(self, period_s: float, callback: Callable[[], None],
                     clock: Clock | SteadyClock | None = None) -> Timer:
        """Call back every period_s seconds of the node's clock, or of `clock` (get_steady_clock(): a timer that runs
        whatever simulated time does)."""
        if period_s <= 0:
            raise ConfigError(f"timer period must be positive, got {period_s}")
        clock = clock or self._clock
        timer = Timer(clock.now_s() + period_s, period_s, callback, clock)
        self._timers.append(timer)
        self._events.put(None)  # wake the executor to consider the new deadline
        return timer

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """Topics currently offered on the graph."""
        return self._backend.topic_names_and_types()

    def call_soon(self, callback: Callable[[], None]) -> None:
        """Run a callback on the node's thread (thread-safe)."""
        self._events.put(callback)

    # Executor

    def spin_once(self, timeout_s: float = 0.1) -> None:
        """Handle one event or due timer, waiting at most timeout_s."""
        wait = min(timeout_s, self._time_to_next_timer())
        try:
            event = self._events.get(timeout=max(wait, 0.0))
        except queue.Empty:
            event = None
        if event is not None:
            self._handle(event)
        self._run_due_timers()

    def spin(self) -> None:
        """Process events until request_shutdown()."""
        while not self._stop.is_set():
            self.spin_once(0.5)

    def spin_in_thread(self) -> threading.Thread:
        """Spin on a daemon thread (tests, tools)."""
        thread = threading.Thread(target=self.spin, name=f"{self._name}-executor", daemon=True)
        thread.start()
        self._spinner = thread
        return thread

    def request_shutdown(self) -> None:
        """Make spin() return (thread- and signal-safe)."""
        self._stop.set()
        self._events.put(None)

    @property
    def shutdown_requested(self) -> bool:
        """Whether request_shutdown() was called."""
        return self._stop.is_set()

    def on_shutdown(self) -> None:
        """Hook for subclasses: flush and close what they own (runs before the node is destroyed)."""

    def deliver_received(self) -> None:
        """Hand every sample already received but not yet taken to its callback (a recorder's last messages when
        it is asked to stop: a stop request leaves them waiting in the readers)."""
        for subscription in list(self._subscriptions):
            if subscription.transport is not None:
                subscription.transport.drain()

    def destroy_node(self, timeout_s: float = 30.0) -> None:
        """Release every publisher, subscription and timer, once a spinning thread has finished its callback (a
        callback still running would publish through a released writer)."""
        spinner = self._spinner
        if spinner is not None and spinner is not threading.current_thread():
            self.request_shutdown()
            spinner.join(timeout_s)
        self._deliver_last_messages()
        for subscription in self._subscriptions:
            subscription.transport.destroy()
        for publisher in self._publishers:
            publisher._transport.destroy()
        self._subscriptions.clear()
        self._publishers.clear()
        self._timers.clear()
        destroy = getattr(self._backend, "destroy_node", None)
        if destroy is not None:
            destroy()

    def _deliver_last_messages(self, timeout_s: float = 1.0) -> None:
        """Give the readers of what this node published a moment to acknowledge it (a lost fragment of the last
        scan is resent only while its writer lives); a reader that is gone costs at most `timeout_s` in all."""
        deadline = time.monotonic() + timeout_s
        for publisher in self._publishers:
            try:
                publisher.wait_for_all_acked(max(deadline - time.monotonic(), 0.0))
            except Exception as err:  # noqa: BLE001 - a writer that cannot wait is destroyed all the same
                self.get_logger().warning(f"{publisher.topic_name}: could not wait for its readers ({err})")

    def _handle(self, event: Any) -> None:
        if event is None:
            return
        if callable(event):
            event()
        else:
            event.drain()

    def _time_to_next_timer(self) -> float:
        self._timers = [timer for timer in self._timers if not timer.cancelled]
        wait = 0.5
        for timer in self._timers:
            now = timer.clock.now_s()
            timer.follow(now)
            remaining = max(timer.due - now, 0.0)
            if timer.clock.use_sim_time and remaining > 0:  # simulated time moves only with a /clock message, an
                remaining = 0.5  # event that wakes the node: nothing to poll for meanwhile
            wait = min(wait, remaining)
        return wait

    def _run_due_timers(self) -> None:
        for timer in list(self._timers):  # in the order they were created
            if timer.cancelled:
                continue
            now = timer.clock.now_s()
            timer.follow(now)
            if timer.due > now:
                continue
            timer.advance(now)
            try:
                timer.callback()
            except SsfError as err:
                self._logger.error(str(err))
            except Exception as err:  # noqa: BLE001 - keep the node alive
                self._logger.error(f"timer callback failed ({type(err).__name__}: {err})")

    def _on_clock(self, msg: Any) -> None:
        self._clock.set_sim_time(messages.stamp_ns(msg.clock))


def _type_name(msg_type: type | str) -> str:
    if isinstance(msg_type, str):
        name = messages.normalize_type_name(msg_type)
        messages.msg_type(name)  # fail early on unknown types
        return name
    name = getattr(msg_type, "__msgtype__", None)
    if name is None:
        raise MessageError(f"{msg_type!r} is not a message type")
    return name
