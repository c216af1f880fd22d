"""rclpy backend: a sourced ROS 2 Jazzy carries the same CDR bytes through rmw (serialized pub/sub)."""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from typing import Any

from ssf_common.middleware.qos import QoS, Durability, Reliability


def rclpy_qos(qos: QoS) -> Any:
    """rclpy QoSProfile for a project QoS."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.BEST_EFFORT
        if qos.reliability is Reliability.BEST_EFFORT
        else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability is Durability.TRANSIENT_LOCAL
        else DurabilityPolicy.VOLATILE,
    )


class RclpyPublisher:
    """Publishes serialized messages with rclpy (ROS type support from the installed interfaces)."""

    def __init__(self, publisher: Any) -> None:
        self._publisher = publisher

    def publish_raw(self, cdr: bytes | memoryview) -> None:
        """Publish CDR bytes."""
        self._publisher.publish(bytes(cdr))

    def matched_count(self) -> int:
        """Matched subscriptions."""
        return self._publisher.get_subscription_count()

    def wait_for_all_acked(self, timeout_s: float) -> bool:
        """Block until every matched reliable subscription acknowledged what was published, or the timeout."""
        from rclpy.duration import Duration

        return self._publisher.wait_for_all_acked(Duration(nanoseconds=max(int(timeout_s * 1e9), 0)))

    def destroy(self) -> None:
        """Nothing to do: rclpy destroys it with the node."""


class RclpySubscription:
    """Queues serialized messages from rclpy's thread for the project's executor."""

    def __init__(self, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]) -> None:
        self._on_raw = on_raw
        self._notify = notify
        self._pending: collections.deque[bytes] = collections.deque()
        self.subscription: Any = None

    def receive(self, data: bytes) -> None:
        """rclpy callback (raw=True): hand the bytes over to the executor."""
        self._pending.append(data)
        self._notify(self)

    def drain(self) -> None:
        """Deliver waiting samples."""
        while self._pending:
            self._on_raw(self._pending.popleft())

    def matched_count(self) -> int:
        """Matched publishers."""
        return self.subscription.get_publisher_count() if self.subscription is not None else 0

    def destroy(self) -> None:
        """Nothing to do: rclpy destroys it with the node."""


class RclpyBackend:
    """Transport over a real rclpy node, spun on its own thread; callbacks run on the project's executor."""

    name = "rclpy"

    def __init__(self, node_name: str, namespace: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        if not rclpy.ok():
            rclpy.init(args=None)
        self._node = rclpy.create_node(node_name, namespace=namespace)
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, name=f"{node_name}-rclpy", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        import rclpy
        from rclpy.executors import ExternalShutdownException

        try:
            while rclpy.ok():
                self._executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass

    def create_publisher(self, type_name: str, topic: str, qos: QoS) -> RclpyPublisher:
        """A serialized-message publisher."""
        from rosidl_runtime_py.utilities import get_message

        return RclpyPublisher(self._node.create_publisher(get_message(type_name), topic, rclpy_qos(qos)))

    def create_subscription(
        self, type_name: str, topic: str, qos: QoS, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]
    ) -> RclpySubscription:
        """A serialized-message subscription."""
        from rosidl_runtime_py.utilities import get_message

        subscription = RclpySubscription(on_raw, notify)
        subscription.subscription = self._node.create_subscription(
            get_message(type_name), topic, subscription.receive, rclpy_qos(qos), raw=True
        )
        return subscription

    def topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """Topics on the ROS graph."""
        return [(name, list(types)) for name, types in self._node.get_topic_names_and_types()]

    def destroy_node(self) -> None:
        """Destroy the rclpy node."""
        self._executor.remove_node(self._node)
        self._node.destroy_node()
