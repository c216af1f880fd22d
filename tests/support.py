"""Helpers shared by tests: ROS 2 types written by hand from the IDL (no project code), and polling."""

import time
from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as idl

# cyclonedds-python IdlStruct types written from the ROS 2 IDL, sharing no code with the project:
# what any other ROS 2 participant would use to read or write these topics.


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: idl.int32
    nanosec: idl.uint32


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_
    frame_id: str


@dataclass
class PointField_(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: idl.uint32
    datatype: idl.uint8
    count: idl.uint32


@dataclass
class PointCloud2_(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header_
    height: idl.uint32
    width: idl.uint32
    fields: idl.sequence[PointField_]
    is_bigendian: bool
    point_step: idl.uint32
    row_step: idl.uint32
    data: idl.sequence[idl.uint8]
    is_dense: bool


@dataclass
class Vector3_(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: idl.float64
    y: idl.float64
    z: idl.float64


@dataclass
class Twist_(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3_
    angular: Vector3_


def wait_until(predicate, timeout_s: float = 20.0) -> bool:
    """Poll predicate until it holds or the timeout passes; return its last value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.02)
    return bool(predicate())
