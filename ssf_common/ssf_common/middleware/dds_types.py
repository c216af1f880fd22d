"""IDL types for Cyclone DDS generated from the project's type store, named as rmw_cyclonedds names them."""

from __future__ import annotations

import functools
from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl
from rosbags.typesys.store import Nodetype

from ssf_common import messages

_BASE_TYPES: dict[str, Any] = {
    "bool": bool,
    "byte": idl.uint8,
    "char": idl.uint8,
    "int8": idl.int8,
    "uint8": idl.uint8,
    "int16": idl.int16,
    "uint16": idl.uint16,
    "int32": idl.int32,
    "uint32": idl.uint32,
    "int64": idl.int64,
    "uint64": idl.uint64,
    "float32": idl.float32,
    "float64": idl.float64,
    "string": str,
}


@functools.cache
def idl_struct(type_name: str) -> type[IdlStruct]:
    """A final (XCDR1), keyless IdlStruct with the ROS 2 DDS type name, e.g. sensor_msgs::msg::dds_::Time_."""
    type_name = messages.normalize_type_name(type_name)
    _, fields = messages.typestore().fielddefs[type_name]
    members = {name: _idl_member(desc) for name, desc in fields}
    if not members:  # ROS gives empty messages one uint8 member
        members = {"structure_needs_at_least_one_member": idl.uint8}
    class_name = type_name.replace("/", "_")
    return make_idl_struct(class_name, messages.dds_type_name(type_name), members)


def _idl_member(desc: tuple) -> Any:
    nodetype, detail = desc
    if nodetype == Nodetype.BASE:
        base, bound = detail
        if base == "string" and bound:
            return idl.bounded_str[bound]
        return _BASE_TYPES[base]
    if nodetype == Nodetype.NAME:
        return idl_struct(detail)
    element, size = detail
    element_type = _idl_member(element)
    if nodetype == Nodetype.ARRAY:
        return idl.array[element_type, size]
    if size:
        return idl.sequence[element_type, size]
    return idl.sequence[element_type]
