"""QoS profiles with the ROS 2 defaults, independent of the backend."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Reliability(Enum):
    """Delivery guarantee."""

    RELIABLE = "reliable"
    BEST_EFFORT = "best_effort"


class Durability(Enum):
    """Whether late joiners get past samples."""

    VOLATILE = "volatile"
    TRANSIENT_LOCAL = "transient_local"


@dataclass(frozen=True)
class QoS:
    """The QoS settings the project uses (history is always keep-last)."""

    depth: int = 10
    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE


QOS_DEFAULT = QoS()
QOS_SENSOR_DATA = QoS(depth=5, reliability=Reliability.BEST_EFFORT)
QOS_LATCHED = QoS(depth=1, durability=Durability.TRANSIENT_LOCAL)
QOS_CLOCK = QoS(depth=1, reliability=Reliability.BEST_EFFORT)


def qos_from_rosbag2(profile: dict) -> QoS:
    """QoS from one entry of rosbag2's offered_qos_profiles (numbers or names, as ROS writes them)."""
    reliability = str(profile.get("reliability", 1)).lower()
    durability = str(profile.get("durability", 2)).lower()
    depth = int(profile.get("depth", 10) or 10)
    return QoS(
        depth=max(depth, 1),
        reliability=Reliability.BEST_EFFORT if reliability in ("2", "best_effort") else Reliability.RELIABLE,
        durability=Durability.TRANSIENT_LOCAL if durability in ("1", "transient_local") else Durability.VOLATILE,
    )


def qos_to_rosbag2(qos: QoS) -> dict:
    """One offered_qos_profiles entry in the form rosbag2 (Jazzy) writes."""
    infinite = {"sec": 2147483647, "nsec": 4294967295}
    return {
        "history": 1,  # keep last
        "depth": qos.depth,
        "reliability": 2 if qos.reliability is Reliability.BEST_EFFORT else 1,
        "durability": 1 if qos.durability is Durability.TRANSIENT_LOCAL else 2,
        "deadline": dict(infinite),
        "lifespan": dict(infinite),
        "liveliness": 1,
        "liveliness_lease_duration": dict(infinite),
        "avoid_ros_namespace_conventions": False,
    }
