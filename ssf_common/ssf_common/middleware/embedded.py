"""Embedded backend: Eclipse Cyclone DDS speaking exactly what rmw_cyclonedds_cpp speaks.

DDS topic `rt/<topic>`, type `pkg::msg::dds_::Type_`, plain XCDR1 bytes produced by the project's
serializer, the ROS QoS profiles, and `typehash=RIHS01_...;` in the endpoints' USER_DATA. Samples are
written and taken as raw CDR so that large clouds never pass through Python lists.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from importlib import resources
from typing import Any

from ssf_common import messages
from ssf_common.errors import MiddlewareError
from ssf_common.middleware.qos import QoS, Durability, Reliability

_DEFAULT_CONFIG_NAME = "cyclone.xml"
_TAKE_BATCH = 64


def default_cyclone_config() -> str:
    """The project's loopback Cyclone configuration (XML text)."""
    return resources.files("ssf_common.middleware").joinpath(_DEFAULT_CONFIG_NAME).read_text()


def _configure_environment() -> None:
    """Use the project's loopback configuration unless the user gave their own CYCLONEDDS_URI."""
    if not os.environ.get("CYCLONEDDS_URI"):
        os.environ["CYCLONEDDS_URI"] = default_cyclone_config()


def ros_topic_to_dds(topic: str) -> str:
    """'/lidar/points' -> 'rt/lidar/points' as rmw_cyclonedds maps it."""
    return "rt/" + topic.lstrip("/")


def dds_topic_to_ros(name: str) -> str | None:
    """'rt/lidar/points' -> '/lidar/points'; None for non-ROS topics."""
    return "/" + name[3:] if name.startswith("rt/") else None


class Participant:
    """One DDS participant per process (as rmw does), with topic and builtin-reader caches."""

    _instance: "Participant | None" = None
    _lock = threading.Lock()

    def __init__(self, domain_id: int) -> None:
        _configure_environment()
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.qos import Policy, Qos

        try:
            self.dp = DomainParticipant(domain_id, qos=Qos(Policy.Userdata(data=b"enclave=/;")))
        except Exception as err:  # noqa: BLE001 - cyclonedds raises DDSException with codes
            raise MiddlewareError(f"cannot join DDS domain {domain_id}: {err} (check CYCLONEDDS_URI)") from None
        self.domain_id = domain_id
        self._topics: dict[str, Any] = {}
        self._publications: Any = None
        self._nodes: dict[tuple[str, str], tuple[list[bytes], list[bytes]]] = {}
        self._discovery_writer: Any = None
        self._discovery_lock = threading.Lock()

    @classmethod
    def get(cls) -> "Participant":
        """The process-wide participant on ROS_DOMAIN_ID (default 0)."""
        with cls._lock:
            if cls._instance is None:
                domain = os.environ.get("ROS_DOMAIN_ID", "0")
                if not domain.isdigit() or int(domain) > 232:
                    raise MiddlewareError(f"ROS_DOMAIN_ID must be an integer 0..232, got {domain!r}")
                cls._instance = Participant(int(domain))
            return cls._instance

    @classmethod
    def close(cls) -> None:
        """Delete the participant and everything it owns."""
        with cls._lock:
            instance, cls._instance = cls._instance, None
        DataWatcher.shutdown()
        if instance is not None:
            instance._topics.clear()
            instance._publications = None
            instance._discovery_writer = None
            del instance.dp

    def topic(self, topic: str, type_name: str, *, dds_name: str | None = None) -> Any:
        """The DDS topic for a ROS topic and type (created once)."""
        from cyclonedds.topic import Topic

        from ssf_common.middleware.dds_types import idl_struct

        key = dds_name or ros_topic_to_dds(topic)
        existing = self._topics.get(key)
        if existing is not None:
            if existing[1] != type_name:
                raise MiddlewareError(f"topic '{topic}' is already used with type {existing[1]}, not {type_name}")
            return existing[0]
        dds_topic = Topic(self.dp, key, idl_struct(type_name))
        self._topics[key] = (dds_topic, type_name)
        return dds_topic

    def update_node(self, namespace: str, name: str, readers: list[bytes], writers: list[bytes]) -> None:
        """Record a node's endpoints and announce them on ros_discovery_info (what `ros2 node list` reads)."""
        with self._discovery_lock:
            self._nodes[(namespace, name)] = (list(readers), list(writers))
            self._announce()

    def remove_node(self, namespace: str, name: str) -> None:
        """Forget a node and announce it."""
        with self._discovery_lock:
            if self._nodes.pop((namespace, name), None) is not None:
                self._announce()

    def _announce(self) -> None:
        import numpy as np
        from cyclonedds.pub import DataWriter

        type_name = "rmw_dds_common/msg/ParticipantEntitiesInfo"
        if self._discovery_writer is None:
            qos = dds_qos(QOS_DISCOVERY, type_name)
            topic = self.topic("", type_name, dds_name="ros_discovery_info")
            self._discovery_writer = DataWriter(self.dp, topic, qos)
        gid = messages.msg_type("rmw_dds_common/msg/Gid")
        node_info = messages.msg_type("rmw_dds_common/msg/NodeEntitiesInfo")

        def gids(guids: list[bytes]) -> list[Any]:
            return [gid(data=np.frombuffer(guid, dtype=np.uint8).copy()) for guid in guids]

        info = messages.msg_type(type_name)(
            gid=gid(data=np.frombuffer(self.dp.guid.bytes, dtype=np.uint8).copy()),
            node_entities_info_seq=[
                node_info(node_namespace=ns, node_name=name, reader_gid_seq=gids(r), writer_gid_seq=gids(w))
                for (ns, name), (r, w) in sorted(self._nodes.items())
            ],
        )
        write_raw(self._discovery_writer, messages.serialize(info), "ros_discovery_info")

    def topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """ROS topics that any writer on the domain currently offers."""
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication

        if self._publications is None:
            self._publications = BuiltinDataReader(self.dp, BuiltinTopicDcpsPublication)
        found: dict[str, set[str]] = {}
        for sample in self._publications.read(N=4096):
            if not getattr(sample, "topic_name", None):  # disposed writers carry no name
                continue
            topic = dds_topic_to_ros(sample.topic_name)
            if topic is None:
                continue
            try:
                type_name = messages.ros_type_from_dds(sample.type_name)
            except Exception:  # noqa: BLE001 - a non-ROS writer on the domain
                continue
            found.setdefault(topic, set()).add(type_name)
        return sorted((topic, sorted(types)) for topic, types in found.items())


def dds_qos(qos: QoS, type_name: str) -> Any:
    """Cyclone QoS equal to what rmw_cyclonedds offers for a ROS QoS profile."""
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration

    reliability = (
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100))
        if qos.reliability is Reliability.RELIABLE
        else Policy.Reliability.BestEffort
    )
    durability = (
        Policy.Durability.TransientLocal if qos.durability is Durability.TRANSIENT_LOCAL else Policy.Durability.Volatile
    )
    user_data = f"typehash={messages.type_hash(type_name)};".encode()
    return Qos(
        reliability,
        durability,
        Policy.History.KeepLast(qos.depth),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Userdata(data=user_data),
    )


QOS_DISCOVERY = QoS(depth=1, durability=Durability.TRANSIENT_LOCAL)


def write_raw(writer: Any, cdr: bytes | memoryview, topic: str) -> None:
    """Write one CDR sample (encapsulation header included), padded to 4 bytes as Cyclone expects."""
    from cyclonedds._clayer import ddspy_write

    data = bytes(cdr)
    if len(data) % 4:
        data += b"\0" * (4 - len(data) % 4)
    result = ddspy_write(writer._ref, data)
    if result < 0:
        raise MiddlewareError(f"DDS write on '{topic}' failed with code {result}")


class EmbeddedPublisher:
    """Writes CDR samples to one topic."""

    def __init__(self, type_name: str, topic: str, qos: QoS) -> None:
        from cyclonedds.pub import DataWriter

        participant = Participant.get()
        self.type_name = type_name
        self.topic_name = topic
        self._writer = DataWriter(participant.dp, participant.topic(topic, type_name), dds_qos(qos, type_name))

    @property
    def guid(self) -> bytes:
        """The writer's GUID (its ROS gid)."""
        return self._writer.guid.bytes

    def publish_raw(self, cdr: bytes | memoryview) -> None:
        """Write one sample given as CDR bytes (encapsulation header included)."""
        writer = self._writer
        if writer is None:
            raise MiddlewareError(f"publisher on '{self.topic_name}' was destroyed; nothing written")
        write_raw(writer, cdr, self.topic_name)

    def matched_count(self) -> int:
        """How many readers are matched."""
        return len(self._writer.get_matched_subscriptions())

    def wait_for_all_acked(self, timeout_s: float) -> bool:
        """Block until every matched reliable reader acknowledged what was written, or the timeout; True if they did."""
        writer = self._writer
        return writer is None or writer.wait_for_acks(max(int(timeout_s * 1e9), 0))

    def destroy(self) -> None:
        """Delete the writer."""
        self._writer = None


class DataWatcher:
    """One thread per process that waits on a Cyclone waitset until a reader has data, then tells its node.

    Cyclone never calls into Python here (no listeners): a listener runs on Cyclone's own threads and needs the
    interpreter lock, which cyclonedds-python keeps held through dds_write; a reliable writer waiting for
    acknowledgements could then wait for a receive thread that waits for the lock (seen as a node's worker stuck in a
    write). A reader's condition leaves the waitset once it has fired and returns when its node has taken the data.
    """

    _instance: "DataWatcher | None" = None
    _lock = threading.Lock()

    def __init__(self, participant: Participant) -> None:
        from cyclonedds.core import GuardCondition, WaitSet

        self._waitset = WaitSet(participant.dp)
        self._wake = GuardCondition(participant.dp)  # (re)attached conditions are looked at at once
        self._waitset.attach(self._wake)
        self._watched: dict[int, tuple[Any, Callable[[], None]]] = {}
        self._guard = threading.Lock()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="dds-data-watcher", daemon=True)
        self._thread.start()

    @classmethod
    def get(cls) -> "DataWatcher":
        """The process-wide watcher."""
        with cls._lock:
            if cls._instance is None:
                cls._instance = DataWatcher(Participant.get())
            return cls._instance

    def watch(self, condition: Any, on_data: Callable[[], None]) -> None:
        """Call on_data (once) when the condition triggers."""
        with self._guard:
            if self._stopped:
                return
            self._waitset.attach(condition)
            self._watched[condition._ref] = (condition, on_data)
            self._wake.set(True)

    def forget(self, condition: Any) -> None:
        """Stop watching a condition."""
        with self._guard:
            if self._watched.pop(condition._ref, None) is not None and not self._stopped:
                self._waitset.detach(condition)

    def close(self) -> None:
        """Stop the thread and let go of every condition and of the waitset."""
        with self._guard:
            if self._stopped:
                return
            self._stopped = True
        self._wake.set(True)
        self._thread.join(timeout=2.0)
        with self._guard:
            for condition, _on_data in self._watched.values():
                self._waitset.detach(condition)
            self._watched.clear()
            self._waitset = self._wake = None  # they hold the participant, which must go for its readers to leave

    @classmethod
    def shutdown(cls) -> None:
        """Close the process's watcher, if any (before the participant is deleted)."""
        with cls._lock:
            instance, cls._instance = cls._instance, None
        if instance is not None:
            instance.close()

    def _run(self) -> None:
        from cyclonedds.util import duration

        while True:
            self._waitset.wait(duration(seconds=1))  # a ctypes call: the interpreter lock is free meanwhile
            with self._guard:
                if self._stopped:
                    return
                self._wake.set(False)
                fired = [(condition, on_data) for condition, on_data in self._watched.values() if condition.triggered]
                for condition, _on_data in fired:
                    self._waitset.detach(condition)
                    del self._watched[condition._ref]
            for _condition, on_data in fired:
                on_data()


class EmbeddedSubscription:
    """Takes raw CDR samples of one topic when the executor asks it to."""

    def __init__(
        self, type_name: str, topic: str, qos: QoS, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]
    ) -> None:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
        from cyclonedds.sub import DataReader

        participant = Participant.get()
        self.type_name = type_name
        self.topic_name = topic
        self._on_raw = on_raw
        self._mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self._reader = DataReader(participant.dp, participant.topic(topic, type_name), dds_qos(qos, type_name))
        self._has_data = ReadCondition(self._reader, self._mask)
        self._notify = lambda: notify(self)
        self._watcher = DataWatcher.get()
        self._watcher.watch(self._has_data, self._notify)

    def drain(self) -> None:
        """Take every waiting sample and hand each valid one to the callback; then wait for more."""
        from cyclonedds._clayer import ddspy_take

        reader = self._reader
        if reader is None:
            return
        try:
            while True:
                samples = ddspy_take(reader._ref, self._mask, _TAKE_BATCH)
                if isinstance(samples, int) or not samples:
                    return
                for data, info in samples:
                    if info.valid_data:  # invalid samples only announce a writer leaving
                        self._on_raw(data)
                if len(samples) < _TAKE_BATCH:
                    return
        finally:
            condition = self._has_data  # destroy() may run on another thread meanwhile
            if self._reader is not None and condition is not None:
                self._watcher.watch(condition, self._notify)

    @property
    def guid(self) -> bytes:
        """The reader's GUID (its ROS gid)."""
        return self._reader.guid.bytes

    def matched_count(self) -> int:
        """How many writers are matched."""
        return len(self._reader.get_matched_publications()) if self._reader is not None else 0

    def destroy(self) -> None:
        """Delete the reader."""
        condition = self._has_data
        if condition is not None:
            self._watcher.forget(condition)
        self._has_data = self._reader = None  # the condition holds the reader


class EmbeddedBackend:
    """One node's transport on the process's participant; events go to the node's executor."""

    name = "dds"

    def __init__(self, node_name: str, namespace: str) -> None:
        self._participant = Participant.get()
        self._node = (namespace, node_name)
        self._readers: list[bytes] = []
        self._writers: list[bytes] = []
        self._participant.update_node(namespace, node_name, self._readers, self._writers)

    def create_publisher(self, type_name: str, topic: str, qos: QoS) -> EmbeddedPublisher:
        """A raw CDR writer."""
        publisher = EmbeddedPublisher(type_name, topic, qos)
        self._writers.append(publisher.guid)
        self._participant.update_node(*self._node, self._readers, self._writers)
        return publisher

    def create_subscription(
        self, type_name: str, topic: str, qos: QoS, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]
    ) -> EmbeddedSubscription:
        """A raw CDR reader; notify(subscription) is called from a DDS thread when data arrives."""
        subscription = EmbeddedSubscription(type_name, topic, qos, on_raw, notify)
        self._readers.append(subscription.guid)
        self._participant.update_node(*self._node, self._readers, self._writers)
        return subscription

    def destroy_node(self) -> None:
        """Announce that the node left."""
        if Participant._instance is self._participant:
            self._participant.remove_node(*self._node)

    def topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """Topics offered on the domain."""
        return Participant.get().topic_names_and_types()
