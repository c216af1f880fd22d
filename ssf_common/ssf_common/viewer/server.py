"""The Foxglove side of the live view: one channel per graph topic, carrying ROS 2 CDR under its `ros2msg` schema."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable
from typing import Any

from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError, MessageError
from ssf_common.viewer import DEFAULT_PORT, LOOPBACK

SCHEMA_ENCODING = "ros2msg"  # the .msg text with its dependencies, as rosbag2 stores it in MCAP
MESSAGE_ENCODING = "cdr"  # the serialized message with its 4-byte encapsulation header, as rmw hands it over


class ViewerConfig(Section):
    """Where the live view listens."""

    host: str = Field(LOOPBACK, min_length=1, description="interface to listen on; loopback unless told otherwise")
    port: int = Field(DEFAULT_PORT, ge=0, le=65535, description="WebSocket port; 0 picks a free one")
    name: str = Field("ssf", min_length=1, description="server name shown by the Foxglove app")


def check_port_free(host: str, port: int) -> None:
    """Refuse, in one line, a host and port that nothing could listen on now (before a graph starts)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ConfigError(f"--foxglove-host '{host}' is not an address of this machine ({err.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as err:
            raise ConfigError(f"cannot listen on {host}:{port} ({err.strerror}); choose another --foxglove port")\
                from None


class _Subscribers:
    """Which clients subscribe to which topic; calls back on a topic's first subscriber and its last leaving.

    The foxglove-sdk calls a listener from its own threads, once per client and channel."""

    def __init__(self) -> None:
        self.on_first: Callable[[str], None] = lambda topic: None
        self.on_last: Callable[[str], None] = lambda topic: None
        self._clients: dict[str, set[int]] = {}
        self._lock = threading.Lock()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        """A client subscribed to a channel."""
        with self._lock:
            clients = self._clients.setdefault(channel.topic, set())
            first = not clients
            clients.add(client.id)
        if first:
            self.on_first(channel.topic)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """A client unsubscribed from a channel (or left)."""
        with self._lock:
            clients = self._clients.get(channel.topic, set())
            had = bool(clients)
            clients.discard(client.id)
            last = had and not clients
        if last:
            self.on_last(channel.topic)


class FoxgloveServer:
    """A foxglove-sdk WebSocket server with one channel per advertised topic, in a context of its own."""

    def __init__(self, config: ViewerConfig) -> None:
        import foxglove
        from foxglove.websocket import Capability

        self.config = config
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._listener = _Subscribers()
        try:
            self._server = foxglove.start_server(
                name=config.name, host=config.host, port=config.port, context=self._context,
                server_listener=self._listener, capabilities=[Capability.Time],
            )
        except Exception as err:  # noqa: BLE001 - the SDK raises its own error types for bind failures
            raise ConfigError(f"cannot listen on {config.host}:{config.port} ({err})") from None

    @property
    def port(self) -> int:
        """The port the server listens on (the chosen one when the config said 0)."""
        return self._server.port

    @property
    def url(self) -> str:
        """ws://HOST:PORT, what the Foxglove app opens."""
        host = f"[{self.config.host}]" if ":" in self.config.host else self.config.host
        return f"ws://{host}:{self.port}"

    def set_subscription_callbacks(self, on_first: Callable[[str], None], on_last: Callable[[str], None]) -> None:
        """Route the clients' first subscription and last unsubscription of each topic to these callbacks."""
        self._listener.on_first = on_first
        self._listener.on_last = on_last

    def advertise(self, topic: str, type_name: str) -> None:
        """Offer a topic with its ROS 2 type's schema (MessageError when the type is unknown)."""
        if topic in self._channels:
            return
        from foxglove import Channel, Schema

        from ssf_common import messages

        type_name = messages.normalize_type_name(type_name)
        try:
            schema = messages.msgdef(type_name)
        except Exception as err:  # noqa: BLE001 - rosbags raises several types for unknown definitions
            raise MessageError(f"no definition of {type_name} to advertise {topic} with ({err})") from None
        self._channels[topic] = Channel(
            topic, schema=Schema(name=type_name, encoding=SCHEMA_ENCODING, data=schema.encode()),
            message_encoding=MESSAGE_ENCODING, context=self._context,
        )

    @property
    def topics(self) -> list[str]:
        """The advertised topics."""
        return sorted(self._channels)

    def log(self, topic: str, cdr: bytes, log_time_ns: int) -> None:
        """Send one message's CDR bytes, as they are, to the clients subscribed to its topic."""
        self._channels[topic].log(bytes(cdr), log_time=int(log_time_ns))

    def broadcast_time(self, stamp_ns: int) -> None:
        """Tell the clients the graph's current time (sim time when the graph has /clock)."""
        self._server.broadcast_time(int(stamp_ns))

    def stop(self) -> None:
        """Close every connection and stop listening."""
        for channel in self._channels.values():
            channel.close()
        self._server.stop()
