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
SDK_SUBPROTOCOL = "foxglove.sdk.v1"  # what the foxglove-sdk server speaks (the Foxglove app, foxglove_bridge >= 3)
# The same protocol under its old name: Lichtblick, older Foxglove Studio and foxglove_bridge 0.8 clients offer only it
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
HANDSHAKE_LIMIT = 16 * 1024  # bytes of an HTTP upgrade request or answer at most
RELAY_BUFFER = 1 << 20


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
    """A foxglove-sdk WebSocket server with one channel per advertised topic, in a context of its own, behind a
    front that lets clients of either subprotocol name in (see `SubprotocolFront`)."""

    def __init__(self, config: ViewerConfig) -> None:
        import foxglove
        from foxglove.websocket import Capability

        self.config = config
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._listener = _Subscribers()
        self._front = SubprotocolFront(config.host, config.port)
        try:
            self._server = foxglove.start_server(
                name=config.name, host=LOOPBACK, port=0, context=self._context,
                server_listener=self._listener, capabilities=[Capability.Time],
            )
        except Exception as err:  # noqa: BLE001 - the SDK raises its own error types for bind failures
            self._front.stop()
            raise ConfigError(f"cannot start the Foxglove server on {LOOPBACK} ({err})") from None
        self._front.start((LOOPBACK, self._server.port))

    @property
    def port(self) -> int:
        """The port the server listens on (the chosen one when the config said 0)."""
        return self._front.port

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
        self._front.stop()
        for channel in self._channels.values():
            channel.close()
        self._server.stop()


class SubprotocolFront:
    """Listens where the viewer was asked to and relays each client, byte for byte, to the foxglove-sdk server on
    loopback. The SDK accepts only the subprotocol name `foxglove.sdk.v1`; a client that offers only
    `foxglove.websocket.v1` (the same protocol under its old name) has its upgrade request carry the new name on the
    way in and the answer the old one on the way out. Everything after the handshake passes unchanged."""

    def __init__(self, host: str, port: int) -> None:
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
            family, _, _, _, address = infos[0]
            self._listener = socket.create_server(address[:2], family=family, backlog=16)
        except OSError as err:
            raise ConfigError(f"cannot listen on {host}:{port} ({getattr(err, 'strerror', None) or err})") from None
        self.port: int = self._listener.getsockname()[1]
        self._backend: tuple[str, int] | None = None
        self._sockets: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stopped = threading.Event()

    def start(self, backend: tuple[str, int]) -> None:
        """Accept clients, relaying them to `backend`."""
        self._backend = backend
        threading.Thread(target=self._accept, daemon=True, name="viewer-front").start()

    def _accept(self) -> None:
        while not self._stopped.is_set():
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(client,), daemon=True, name="viewer-client").start()

    def _serve(self, client: socket.socket) -> None:
        """One client: the handshake (renamed when legacy), then both directions relayed until either side closes."""
        backend = None
        try:
            self._track(client)
            request, rest = read_head(client)
            request, legacy = to_sdk_request(request)
            backend = socket.create_connection(self._backend, timeout=10.0)
            backend.settimeout(None)
            self._track(backend)
            for sock in (client, backend):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            backend.sendall(request + rest)
            answer, rest = read_head(backend)
            client.sendall((to_legacy_answer(answer) if legacy else answer) + rest)
            upstream = threading.Thread(target=_relay, args=(client, backend), daemon=True, name="viewer-upstream")
            upstream.start()
            _relay(backend, client)
            upstream.join()
        except (OSError, MessageError):
            pass  # a client that leaves mid-handshake, or speaks no HTTP: nothing to serve
        finally:
            for sock in (client, backend):
                if sock is not None:
                    self._untrack(sock)
                    sock.close()

    def _track(self, sock: socket.socket) -> None:
        with self._lock:
            self._sockets.add(sock)

    def _untrack(self, sock: socket.socket) -> None:
        with self._lock:
            self._sockets.discard(sock)

    def stop(self) -> None:
        """Stop accepting and end every relayed connection."""
        self._stopped.set()
        self._listener.close()
        with self._lock:
            for sock in self._sockets:
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass


def read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (up to and including the blank line) and whatever arrived after it; MessageError when the peer
    closes first or the head is too long."""
    data = b""
    while b"\r\n\r\n" not in data:
        if len(data) > HANDSHAKE_LIMIT:
            raise MessageError(f"an HTTP head longer than {HANDSHAKE_LIMIT} bytes")
        chunk = sock.recv(4096)
        if not chunk:
            raise MessageError("the connection closed during the WebSocket handshake")
        data += chunk
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def offered_subprotocols(request: bytes) -> list[str]:
    """The subprotocols a WebSocket upgrade request offers, in its order."""
    offered = []
    for line in request.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"sec-websocket-protocol":
            offered += [item.strip().decode("latin-1") for item in value.split(b",") if item.strip()]
    return offered


def to_sdk_request(request: bytes) -> tuple[bytes, bool]:
    """The upgrade request as the SDK server accepts it, and whether it was renamed (it offered only the old name)."""
    offered = offered_subprotocols(request)
    if SDK_SUBPROTOCOL in offered or LEGACY_SUBPROTOCOL not in offered:
        return request, False
    lines = [line for line in request.split(b"\r\n")
             if line.partition(b":")[0].strip().lower() != b"sec-websocket-protocol"]
    lines.insert(1, f"Sec-WebSocket-Protocol: {SDK_SUBPROTOCOL}".encode())
    return b"\r\n".join(lines), True


def to_legacy_answer(answer: bytes) -> bytes:
    """The SDK server's upgrade answer with the subprotocol the legacy client asked for."""
    lines = answer.split(b"\r\n")
    for index, line in enumerate(lines):
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"sec-websocket-protocol" and value.strip() == SDK_SUBPROTOCOL.encode():
            lines[index] = name + b": " + LEGACY_SUBPROTOCOL.encode()
    return b"\r\n".join(lines)


def _relay(source: socket.socket, target: socket.socket) -> None:
    """Copy bytes from one socket to the other until the source closes; then close the target's sending side."""
    buffer = bytearray(RELAY_BUFFER)
    view = memoryview(buffer)
    try:
        while count := source.recv_into(buffer):
            target.sendall(view[:count])
    except OSError:
        pass
    finally:
        try:
            target.shutdown(socket.SHUT_WR)
        except OSError:
            pass
