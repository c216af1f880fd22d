"""CDR of every published type is byte-identical to independent ROS 2 serialisers; RIHS01 hashes match Jazzy."""

import hashlib
import json
import random
import types

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
from mcap_ros2._vendor.rosidl_adapter.parser import parse_message_string
from rosbags.interfaces import Nodetype

from ssf_common import messages, pointcloud
from support import Header_ as Header
from support import PointCloud2_ as PointCloud2
from support import PointField_ as PointField
from support import Time_ as Time
from support import Twist_ as Twist
from support import Vector3_ as Vector3

NUMPY_OF = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "octet": np.uint8,
    "int8": np.int8, "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16,
    "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
    "float32": np.float32, "float64": np.float64,
}  # fmt: skip
TEXT = "abcdefghijklmnopqrstuvwxyz_/é"


def random_value(spec: tuple, rng: random.Random, type_name: str, field_name: str):
    """A non-trivial value for one field: varied string lengths, array lengths and signed values."""
    node, detail = spec
    if node == Nodetype.NAME:
        return random_message(detail, rng)
    if node == Nodetype.BASE:
        return random_scalar(detail[0], rng, type_name, field_name)
    (sub_node, sub_detail), size = detail
    length = size if node == Nodetype.ARRAY else rng.randint(0, 3 if sub_node == Nodetype.NAME else 9)
    if sub_node == Nodetype.BASE and sub_detail[0] in NUMPY_OF:
        values = [random_scalar(sub_detail[0], rng, type_name, field_name) for _ in range(length)]
        return np.array(values, dtype=NUMPY_OF[sub_detail[0]])
    return [random_value((sub_node, sub_detail), rng, type_name, field_name) for _ in range(length)]


def random_scalar(base: str, rng: random.Random, type_name: str, field_name: str):
    if base == "string":
        return "".join(rng.choice(TEXT) for _ in range(rng.randint(0, 11)))
    if base == "bool":
        return rng.random() < 0.5
    if base.startswith("float"):
        value = rng.uniform(-1e4, 1e4)
        return float(np.float32(value)) if base == "float32" else value
    info = np.iinfo(NUMPY_OF[base])
    low = 0 if type_name.startswith("builtin_interfaces/") else info.min  # mcap_ros2 reads Time.sec as uint32
    return rng.randint(low, int(info.max))


def random_message(type_name: str, rng: random.Random):
    _, fields = messages.typestore().fielddefs[type_name]
    values = {name: random_value(spec, rng, type_name, name) for name, spec in fields}
    return messages.msg_type(type_name)(**values)


def short_name(type_name: str) -> str:
    pkg, _, name = type_name.split("/")
    return f"{pkg}/{name}"


def plain(msg, type_name: str) -> types.SimpleNamespace:
    """The message as namespaces and Python lists, the input mcap_ros2's serialiser takes."""
    _, fields = messages.typestore().fielddefs[type_name]
    values = {}
    for name, (node, detail) in fields:
        value = getattr(msg, name)
        if node == Nodetype.NAME:
            value = plain(value, detail)
        elif node != Nodetype.BASE and detail[0][0] == Nodetype.NAME:
            value = [plain(item, detail[0][1]) for item in value]
        elif isinstance(value, np.ndarray):
            value = value.tolist()
        values[name] = value
    return types.SimpleNamespace(**values)


def mcap_serialize(msg) -> bytes:
    name = messages.type_name_of(msg)
    return serialize_dynamic(short_name(name), messages.msgdef(name))[short_name(name)](plain(msg, name))


def mcap_deserialize(raw: bytes, name: str) -> types.SimpleNamespace:
    return generate_dynamic(short_name(name), messages.msgdef(name))[short_name(name)](raw)


def assert_same_values(ours, theirs, type_name: str, path: str = "") -> None:
    """Field-by-field equality of a rosbags message and a decoded mcap_ros2 namespace."""
    _, fields = messages.typestore().fielddefs[type_name]
    for name, (node, detail) in fields:
        a, b = getattr(ours, name), getattr(theirs, name)
        where = f"{path}.{name}"
        if node == Nodetype.NAME:
            assert_same_values(a, b, detail, where)
        elif node == Nodetype.BASE:
            assert a == b, where
        elif detail[0][0] == Nodetype.NAME:
            assert len(a) == len(b), where
            for index, (item_a, item_b) in enumerate(zip(a, b)):
                assert_same_values(item_a, item_b, detail[0][1], f"{where}[{index}]")
        else:
            assert list(a) == list(b), where


def example_cloud():
    xyz = np.random.default_rng(3).normal(size=(37, 3)).astype(np.float32)
    return pointcloud.xyz_to_cloud(
        xyz, messages.header(1_700_000_000_123_456_789, "velodyne_top"),
        intensity=np.linspace(0, 1, 37, dtype=np.float32), ring=np.arange(37, dtype=np.uint16) % 16,
    )  # fmt: skip


@pytest.mark.parametrize("type_name", messages.PUBLISHED_TYPES)
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_cdr_is_byte_identical_to_mcap_ros2(type_name, seed):
    msg = random_message(type_name, random.Random(f"{type_name}{seed}"))
    ours = messages.serialize(msg)
    assert ours[:4] == b"\x00\x01\x00\x00"
    assert ours == mcap_serialize(msg)


@pytest.mark.parametrize("type_name", messages.PUBLISHED_TYPES)
def test_bytes_of_the_independent_serialiser_decode_back(type_name):
    msg = random_message(type_name, random.Random(type_name))
    theirs = mcap_serialize(msg)
    ours_decoded = messages.deserialize(theirs, type_name)
    assert messages.serialize(ours_decoded) == theirs
    assert_same_values(ours_decoded, mcap_deserialize(messages.serialize(msg), type_name), type_name)


def test_pointcloud_from_numpy_is_byte_identical_and_decodes():
    cloud = example_cloud()
    raw = messages.serialize(cloud)
    assert raw == mcap_serialize(cloud)
    decoded = mcap_deserialize(raw, pointcloud.POINTCLOUD2)
    assert bytes(decoded.data) == cloud.data.tobytes()
    assert [(f.name, f.offset, f.datatype, f.count) for f in decoded.fields] == [
        ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1), ("ring", 16, 4, 1)
    ]  # fmt: skip


def test_pointcloud_cdr_is_byte_identical_to_cyclonedds():
    cloud = example_cloud()
    theirs = PointCloud2(
        header=Header(Time(cloud.header.stamp.sec, cloud.header.stamp.nanosec), cloud.header.frame_id),
        height=cloud.height, width=cloud.width,
        fields=[PointField(f.name, f.offset, f.datatype, f.count) for f in cloud.fields],
        is_bigendian=cloud.is_bigendian, point_step=cloud.point_step, row_step=cloud.row_step,
        data=cloud.data.tolist(), is_dense=cloud.is_dense,
    )  # fmt: skip
    raw = messages.serialize(cloud)
    assert raw == theirs.serialize()
    back = PointCloud2.deserialize(raw)
    assert bytes(back.data) == cloud.data.tobytes() and back.header.frame_id == "velodyne_top"


def test_twist_cdr_is_byte_identical_to_cyclonedds():
    twist = random_message("geometry_msgs/msg/Twist", random.Random(7))
    theirs = Twist(Vector3(twist.linear.x, twist.linear.y, twist.linear.z),
                   Vector3(twist.angular.x, twist.angular.y, twist.angular.z))  # fmt: skip
    assert messages.serialize(twist) == theirs.serialize()


def test_dds_type_names_follow_rmw_cyclonedds():
    assert messages.dds_type_name("sensor_msgs/msg/PointCloud2") == PointCloud2.__idl_typename__
    assert messages.ros_type_from_dds("geometry_msgs::msg::dds_::Twist_") == "geometry_msgs/msg/Twist"


# RIHS01: Jazzy's published values, and an independent computation per REP-2016.

JAZZY_HASHES = {  # from `ros2 topic info -v` and rcl's test_type_hash.cpp on Jazzy
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "geometry_msgs/msg/Twist": "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "sensor_msgs/msg/PointCloud2": "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    "sensor_msgs/msg/PointField": "RIHS01_5c6a4750728c2bcfbbf7037225b20b02d4429634732146b742dee1726637ef01",
}
FIELD_TYPE_IDS = {
    "int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8, "uint64": 9,
    "float32": 10, "float64": 11, "char": 3, "bool": 15, "byte": 16, "string": 17, "wstring": 18,
}  # fmt: skip


def rihs01(type_name: str) -> str:
    """REP-2016 hash from the msgdef text, parsed by the rosidl parser vendored in mcap_ros2."""
    text_of = {short_name(type_name): messages.msgdef(type_name).split("=" * 80 + "\n")[0]}
    for section in messages.msgdef(type_name).split("=" * 80 + "\n")[1:]:
        first, _, body = section.partition("\n")
        text_of[first.removeprefix("MSG: ").strip()] = body

    def description(short: str) -> dict:
        pkg, name = short.split("/")
        fields = []
        for field in parse_message_string(pkg, name, text_of[short]).fields:
            kind = field.type
            nested = "" if kind.is_primitive_type() else f"{kind.pkg_name}/msg/{kind.type}"
            type_id = 1 if nested else FIELD_TYPE_IDS[kind.type] + (4 if kind.string_upper_bound else 0)
            if kind.is_array:
                type_id += 48 if not kind.is_upper_bound and kind.array_size else 96 if kind.is_upper_bound else 144
            fields.append({"name": field.name, "type": {
                "type_id": type_id, "capacity": kind.array_size or 0,
                "string_capacity": kind.string_upper_bound or 0, "nested_type_name": nested}})  # fmt: skip
        if not fields:
            fields = [{"name": "structure_needs_at_least_one_member", "type": {
                "type_id": 3, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}]  # fmt: skip
        return {"type_name": f"{pkg}/msg/{name}", "fields": fields}

    referenced = sorted((description(short) for short in text_of if short != short_name(type_name)),
                        key=lambda item: item["type_name"])  # fmt: skip
    document = {"type_description": description(short_name(type_name)), "referenced_type_descriptions": referenced}
    return "RIHS01_" + hashlib.sha256(json.dumps(document).encode()).hexdigest()


@pytest.mark.parametrize("type_name", sorted(JAZZY_HASHES))
def test_type_hash_matches_jazzy(type_name):
    assert messages.type_hash(type_name) == JAZZY_HASHES[type_name]


@pytest.mark.parametrize("type_name", [*sorted(JAZZY_HASHES), *messages.PUBLISHED_TYPES])
def test_type_hash_matches_an_independent_rep2016_computation(type_name):
    assert rihs01(type_name) == messages.type_hash(type_name)
