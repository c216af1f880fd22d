"""Message types and CDR: ROS 2 Jazzy's standard types plus ssf_interfaces, loaded from .msg text.

Every message in the project is a rosbags dataclass from one type store, serialised to the plain
XCDR1 little-endian CDR that rmw_cyclonedds and rosbag2 use. Both middleware backends carry these
bytes, so cores and nodes see the same types everywhere.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable
from importlib import resources
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

from ssf_common.errors import MessageError

CUSTOM_PACKAGE = "ssf_interfaces"

# Message types the project publishes (tested for byte-equality and recording).
PUBLISHED_TYPES = (
    "sensor_msgs/msg/PointCloud2",
    "nav_msgs/msg/Odometry",
    "nav_msgs/msg/Path",
    "geometry_msgs/msg/Twist",
    "geometry_msgs/msg/PoseStamped",
    "tf2_msgs/msg/TFMessage",
    "rosgraph_msgs/msg/Clock",
    "visualization_msgs/msg/MarkerArray",
    "std_msgs/msg/String",
    "ssf_interfaces/msg/ObstacleArray",
    "ssf_interfaces/msg/FusionState",
    "ssf_interfaces/msg/EpisodeResult",
    "ssf_interfaces/msg/PlannerState",
    "ssf_interfaces/msg/EgoMotion",
)


def _msg_dir_candidates() -> Iterable[Path]:
    """Places where the ssf_interfaces .msg files may be, most specific first."""
    if env := os.environ.get("SSF_INTERFACES_MSG_DIR"):
        yield Path(env)
    yield Path(__file__).resolve().parents[2] / CUSTOM_PACKAGE / "msg"  # source checkout
    try:
        yield Path(str(resources.files("ssf_common.interfaces") / "msg"))  # pip install
    except (ModuleNotFoundError, TypeError):
        pass
    try:  # a colcon-built ROS 2 workspace
        from ament_index_python.packages import get_package_share_directory

        yield Path(get_package_share_directory(CUSTOM_PACKAGE)) / "msg"
    except Exception:  # noqa: BLE001 - ament is optional and raises several types
        pass


def custom_msg_files() -> list[Path]:
    """Find the .msg files of ssf_interfaces."""
    for directory in _msg_dir_candidates():
        files = sorted(directory.glob("*.msg"))
        if files:
            return files
    raise MessageError(f"cannot find the {CUSTOM_PACKAGE} .msg files; set SSF_INTERFACES_MSG_DIR to their folder")


@functools.cache
def typestore() -> Typestore:
    """The project's type store: ROS 2 Jazzy standard types plus ssf_interfaces."""
    store = get_typestore(Stores.ROS2_JAZZY)
    custom: dict[str, Any] = {}
    for path in custom_msg_files():
        custom.update(get_types_from_msg(path.read_text(), f"{CUSTOM_PACKAGE}/msg/{path.stem}"))
    store.register(custom)
    return store


def msg_type(name: str) -> type:
    """Message class for a ROS type name such as 'sensor_msgs/msg/PointCloud2'."""
    name = normalize_type_name(name)
    try:
        return typestore().types[name]
    except KeyError:
        raise MessageError(f"unknown message type '{name}'") from None


def type_name_of(msg: Any) -> str:
    """ROS type name of a message instance."""
    return msg.__msgtype__


def normalize_type_name(name: str) -> str:
    """Accept 'pkg/Type' or 'pkg/msg/Type' and return 'pkg/msg/Type'."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def dds_type_name(name: str) -> str:
    """The DDS type name rmw_cyclonedds uses: 'pkg::msg::dds_::Type_'."""
    pkg, kind, typ = normalize_type_name(name).split("/")
    return f"{pkg}::{kind}::dds_::{typ}_"


def ros_type_from_dds(dds_name: str) -> str:
    """Inverse of dds_type_name."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise MessageError(f"'{dds_name}' is not a ROS 2 DDS type name")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def type_hash(name: str) -> str:
    """RIHS01 type hash as ROS 2 Jazzy computes it."""
    return typestore().hash_rihs01(normalize_type_name(name))


def msgdef(name: str) -> str:
    """The ros2msg schema text (definition plus dependencies) that rosbag2 stores in MCAP."""
    text, _ = typestore().generate_msgdef(normalize_type_name(name), ros_version=2)
    return text


def serialize(msg: Any, type_name: str | None = None) -> bytes:
    """Serialise a message to CDR (4-byte encapsulation header included)."""
    name = type_name or type_name_of(msg)
    try:
        return bytes(typestore().serialize_cdr(msg, name))
    except (AttributeError, TypeError, ValueError, KeyError) as err:
        raise MessageError(f"cannot serialise {name}: {err}") from None


def deserialize(raw: bytes | memoryview, type_name: str) -> Any:
    """Deserialise CDR bytes into a message, raising MessageError on malformed data."""
    try:
        return typestore().deserialize_cdr(raw, type_name)
    except Exception as err:  # noqa: BLE001 - rosbags raises many kinds on corrupt input
        raise MessageError(f"cannot decode {type_name} ({len(raw)} bytes): {err}") from None


def register_definitions(definitions: dict[str, str]) -> None:
    """Register types known only from .msg text (e.g. embedded in a bag) into the project's store."""
    store = typestore()
    for name, text in definitions.items():
        name = normalize_type_name(name)
        if name in store.types:
            continue
        store.register(get_types_from_msg(text, name))


# Constructors of the small messages every node uses.


def stamp(nanoseconds: int) -> Any:
    """builtin_interfaces/Time from integer nanoseconds."""
    sec, nanosec = divmod(int(nanoseconds), 1_000_000_000)
    return msg_type("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def stamp_ns(time_msg: Any) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(time_msg.sec) * 1_000_000_000 + int(time_msg.nanosec)


def header(nanoseconds: int, frame_id: str) -> Any:
    """std_msgs/Header."""
    return msg_type("std_msgs/msg/Header")(stamp=stamp(nanoseconds), frame_id=frame_id)
