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
        if instance is not None:
            instance._topics.clear()
            instance._publications = None
            del instance.dp

    def topic(self, topic: str, type_name: str) -> Any:
        """The DDS topic for a ROS topic and type (created once)."""
        from cyclonedds.topic import Topic

        from ssf_common.middleware.dds_types import idl_struct

        key = ros_topic_to_dds(topic)
        existing = self._topics.get(key)
        if existing is not None:
            if existing[1] != type_name:
                raise MiddlewareError(f"topic '{topic}' is already used with type {existing[1]}, not {type_name}")
            return existing[0]
        dds_topic = Topic(self.dp, key, idl_struct(type_name))
        self._topics[key] = (dds_topic, type_name)
        return dds_topic

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


class EmbeddedPublisher:
    """Writes CDR samples to one topic."""

    def __init__(self, type_name: str, topic: str, qos: QoS) -> None:
        from cyclonedds.pub import DataWriter

        participant = Participant.get()
        self.type_name = type_name
        self.topic_name = topic
        self._writer = DataWriter(participant.dp, participant.topic(topic, type_name), dds_qos(qos, type_name))

    def publish_raw(self, cdr: bytes | memoryview) -> None:
        """Write one sample given as CDR bytes (encapsulation header included)."""
        from cyclonedds._clayer import ddspy_write

        data = bytes(cdr)
        if len(data) % 4:
            data += b"\0" * (4 - len(data) % 4)
        result = ddspy_write(self._writer._ref, data)
        if result < 0:
            raise MiddlewareError(f"DDS write on '{self.topic_name}' failed with code {result}")

    def matched_count(self) -> int:
        """How many readers are matched."""
        return len(self._writer.get_matched_subscriptions())

    def destroy(self) -> None:
        """Delete the writer."""
        self._writer = None


class EmbeddedSubscription:
    """Takes raw CDR samples of one topic when the executor asks it to."""

    def __init__(
        self, type_name: str, topic: str, qos: QoS, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]
    ) -> None:
        from cyclonedds.core import InstanceState, Listener, SampleState, ViewState
        from cyclonedds.sub import DataReader

        participant = Participant.get()
        self.type_name = type_name
        self.topic_name = topic
        self._on_raw = on_raw
        self._mask = SampleState.Any | ViewState.Any | InstanceState.Any
        listener = Listener(on_data_available=lambda _reader: notify(self))
        self._reader = DataReader(
            participant.dp, participant.topic(topic, type_name), dds_qos(qos, type_name), listener=listener
        )

    def drain(self) -> None:
        """Take every waiting sample and hand each valid one to the callback."""
        from cyclonedds._clayer import ddspy_take

        reader = self._reader
        if reader is None:
            return
        while True:
            samples = ddspy_take(reader._ref, self._mask, _TAKE_BATCH)
            if isinstance(samples, int) or not samples:
                return
            for data, info in samples:
                if info.valid_data:  # invalid samples only announce a writer leaving
                    self._on_raw(data)
            if len(samples) < _TAKE_BATCH:
                return

    def matched_count(self) -> int:
        """How many writers are matched."""
        return len(self._reader.get_matched_publications()) if self._reader is not None else 0

    def destroy(self) -> None:
        """Delete the reader."""
        self._reader = None


class EmbeddedBackend:
    """Creates embedded publishers and subscriptions; events go to the node's executor."""

    name = "dds"

    def create_publisher(self, type_name: str, topic: str, qos: QoS) -> EmbeddedPublisher:
        """A raw CDR writer."""
        return EmbeddedPublisher(type_name, topic, qos)

    def create_subscription(
        self, type_name: str, topic: str, qos: QoS, on_raw: Callable[[bytes], None], notify: Callable[[Any], None]
    ) -> EmbeddedSubscription:
        """A raw CDR reader; notify(subscription) is called from a DDS thread when data arrives."""
        return EmbeddedSubscription(type_name, topic, qos, on_raw, notify)

    def topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """Topics offered on the domain."""
        return Participant.get().topic_names_and_types()

    def shutdown(self) -> None:
        """Leave the DDS domain."""
        Participant.close()
