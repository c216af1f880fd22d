"""Offered QoS profiles as rosbag2 stores them: YAML text or lists, integer (v4-v8) or named (v9) policies."""

from __future__ import annotations

from enum import Enum
from typing import Any

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from ssf_common.config import load_yaml_text
from ssf_common.errors import BagError, ConfigError

__all__ = ["Qos", "parse_profiles", "profiles_to_dicts", "profiles_to_yaml", "default_profile"]

_ZERO = QosTime(0, 0)


def default_profile(*, reliable: bool = True, depth: int = 10) -> Qos:
    """The ROS default profile (reliable) or the sensor-data one (best effort), keep last `depth`."""
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.VOLATILE,
        deadline=_ZERO,
        lifespan=_ZERO,
        liveliness=QosLiveliness.SYSTEM_DEFAULT,
        liveliness_lease_duration=_ZERO,
        avoid_ros_namespace_conventions=False,
    )


def parse_profiles(value: Any, where: str) -> tuple[Qos, ...]:
    """Parse offered_qos_profiles given as YAML text or an already-loaded list."""
    if value is None or value == "" or value == []:
        return ()
    if isinstance(value, str):
        try:
            value = load_yaml_text(value, f"{where}: offered_qos_profiles")
        except ConfigError as err:
            raise BagError(str(err)) from None
    if not isinstance(value, list):
        raise BagError(f"{where}: offered_qos_profiles must be a list, got {type(value).__name__}")
    try:
        return tuple(_parse_profile(item) for item in value)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise BagError(f"{where}: malformed offered_qos_profiles entry ({err})") from None


def _parse_profile(item: dict[str, Any]) -> Qos:
    return Qos(
        history=_policy(QosHistory, item.get("history", 0)),
        depth=int(item.get("depth", 0)),
        reliability=_policy(QosReliability, item.get("reliability", 0)),
        durability=_policy(QosDurability, item.get("durability", 0)),
        deadline=_time(item.get("deadline")),
        lifespan=_time(item.get("lifespan")),
        liveliness=_policy(QosLiveliness, item.get("liveliness", 0)),
        liveliness_lease_duration=_time(item.get("liveliness_lease_duration")),
        avoid_ros_namespace_conventions=bool(item.get("avoid_ros_namespace_conventions", False)),
    )


def _policy(enum: type[Enum], value: int | str) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"bad {enum.__name__} {value!r}")
    if isinstance(value, int):
        try:
            return enum(value)
        except ValueError:
            return enum["UNKNOWN"]
    return enum.__members__.get(str(value).upper(), enum["UNKNOWN"])


def _time(value: dict[str, int] | None) -> QosTime:
    if not value:
        return _ZERO
    return QosTime(int(value.get("sec", 0)), int(value.get("nsec", 0)))


def profiles_to_dicts(profiles: tuple[Qos, ...] | list[Qos]) -> list[dict[str, Any]]:
    """Profiles as rosbag2 v9 writes them: policy names in lower case."""
    return [
        {
            "history": p.history.name.lower(),
            "depth": p.depth,
            "reliability": p.reliability.name.lower(),
            "durability": p.durability.name.lower(),
            "deadline": {"sec": p.deadline.sec, "nsec": p.deadline.nsec},
            "lifespan": {"sec": p.lifespan.sec, "nsec": p.lifespan.nsec},
            "liveliness": p.liveliness.name.lower(),
            "liveliness_lease_duration": {
                "sec": p.liveliness_lease_duration.sec,
                "nsec": p.liveliness_lease_duration.nsec,
            },
            "avoid_ros_namespace_conventions": p.avoid_ros_namespace_conventions,
        }
        for p in profiles
    ]


def profiles_to_yaml(profiles: tuple[Qos, ...] | list[Qos]) -> str:
    """The YAML text stored in MCAP channel metadata (empty string for no profiles)."""
    if not profiles:
        return ""
    return yaml.safe_dump(profiles_to_dicts(profiles), sort_keys=False).strip()
