"""The middleware layer: one rclpy-shaped API over real rclpy or embedded, ROS 2 wire-compatible Cyclone DDS.

Choose with SSF_MIDDLEWARE=auto|rclpy|dds (auto: rclpy when it imports, otherwise embedded DDS).
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Sequence

from ssf_common.errors import SsfError
from ssf_common.heap import hold_freed_memory
from ssf_common.interrupts import interruptible
from ssf_common.middleware.node import (
    Clock,
    Heard,
    Logger,
    Node,
    Publisher,
    SteadyClock,
    Subscription,
    Timer,
    dropped_text,
)
from ssf_common.middleware.qos import (
    QOS_CLOCK,
    QOS_DEFAULT,
    QOS_LATCHED,
    QOS_SENSOR_DATA,
    Durability,
    QoS,
    Reliability,
)

__all__ = [
    "Clock",
    "Durability",
    "Heard",
    "Logger",
    "Node",
    "Publisher",
    "QOS_CLOCK",
    "QOS_DEFAULT",
    "QOS_LATCHED",
    "QOS_SENSOR_DATA",
    "QoS",
    "Reliability",
    "SteadyClock",
    "Subscription",
    "Timer",
    "dropped_text",
    "run",
    "shutdown",
]


def shutdown() -> None:
    """Leave the DDS domain / shut rclpy down (idempotent)."""
    if "rclpy" in sys.modules:
        import rclpy

        rclpy.try_shutdown()
    from ssf_common.middleware.embedded import Participant

    Participant.close()


def run(node_factory: Callable[..., Node], argv: Sequence[str] | None = None) -> int:
    """Console-script body of a node: build it, spin until SIGINT/SIGTERM, shut down cleanly.

    Exit status: 2 when the node could not be built (bad parameters or files), else the node's `exit_code`."""
    interruptible()
    hold_freed_memory()
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        node = node_factory(argv=args)
    except SsfError as err:
        print(f"[ERROR] {err}", file=sys.stderr, flush=True)
        shutdown()
        return 2
    except KeyboardInterrupt:
        shutdown()
        return 0

    for name in node.undeclared_overrides():
        node.get_logger().warning(f"ignoring parameter '{name}': {node.get_name()} has no such parameter")

    def stop(_signum: int, _frame: object) -> None:
        node.request_shutdown()

    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        node.get_logger().info(f"started ({node.backend_name} backend)")
        node.spin()
    except KeyboardInterrupt:
        pass
    finally:
        try:
            node.on_shutdown()
        finally:
            node.destroy_node()
            shutdown()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    return int(getattr(node, "exit_code", 0))  # a node sets exit_code when its work failed after it started
