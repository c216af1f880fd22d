"""PointCloud2 <-> numpy round trips for real-world layouts, real scans, and each kind of malformed cloud."""

import struct
from types import SimpleNamespace

import numpy as np
import pytest

from ssf_common import messages, pointcloud, scans
from ssf_common.errors import MessageError
from ssf_common.middleware import Node
from support import random_points

HEADER = messages.header(1_673_400_472_138_016_708, "lidar_top")

VELODYNE_XYZIRT = np.dtype({  # point_step 22, unaligned ring and time
    "names": ["x", "y", "z", "intensity", "ring", "time"],
    "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
    "offsets": [0, 4, 8, 12, 16, 18], "itemsize": 22,
})  # fmt: skip
AUTOWARE_XYZIRCAEDT = np.dtype({  # nebula's PointXYZIRCAEDT, point_step 32
    "names": ["x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation", "distance", "time_stamp"],
    "formats": ["<f4", "<f4", "<f4", "u1", "u1", "<u2", "<f4", "<f4", "<f4", "<u4"],
    "offsets": [0, 4, 8, 12, 13, 14, 16, 20, 24, 28], "itemsize": 32,
})  # fmt: skip
PCL_PADDED = np.dtype({  # PCL PointXYZI: xyz padded to 16 bytes, intensity at 16, point_step 32
    "names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 16], "itemsize": 32,
})  # fmt: skip
WITH_COUNTS = np.dtype(
    [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("normal", "<f4", (3,)), ("rgba", "u1", (4,)), ("label", "<i2")]
)
BIG_ENDIAN = np.dtype([("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("intensity", ">u2"), ("t", ">f8"), ("flag", "i1")])
LAYOUTS = {
    "velodyne_xyzirt": VELODYNE_XYZIRT,
    "autoware_xyzircaedt": AUTOWARE_XYZIRCAEDT,
    "pcl_padded": PCL_PADDED,
    "count_gt_1": WITH_COUNTS,
    "big_endian": BIG_ENDIAN,
}


def through_cdr(msg):
    return messages.deserialize(messages.serialize(msg), pointcloud.POINTCLOUD2)


def field_table(msg):
    return [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("shape", [(257,), (4, 33)], ids=["flat", "organized"])
def test_every_layout_survives_array_cloud_cdr_array(layout, shape):
    dtype = LAYOUTS[layout]
    points = random_points(dtype, shape)
    msg = pointcloud.array_to_cloud(points, HEADER)
    back = through_cdr(msg)
    assert (back.height, back.width) == ((1, 257) if len(shape) == 1 else shape)
    assert back.point_step == dtype.itemsize and back.row_step == back.width * dtype.itemsize
    assert back.is_bigendian == (layout == "big_endian")
    array = pointcloud.cloud_to_array(back, organized=True)
    assert array.dtype == dtype.newbyteorder(">" if back.is_bigendian else "<")
    assert array.tobytes() == points.tobytes()
    flat = pointcloud.cloud_to_array(back)
    for name in dtype.names:
        np.testing.assert_array_equal(flat[name], points[name].reshape(flat.shape + points[name].shape[len(shape):]))
    expected_xyz = np.stack([points[axis].reshape(-1) for axis in "xyz"], axis=1).astype(np.float32)
    np.testing.assert_array_equal(pointcloud.cloud_xyz(back), expected_xyz)


def test_layouts_are_described_as_the_drivers_publish_them():
    velodyne = pointcloud.array_to_cloud(random_points(VELODYNE_XYZIRT, 3), HEADER)
    assert field_table(velodyne) == [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1),
                                     ("ring", 16, 4, 1), ("time", 18, 7, 1)]  # fmt: skip
    autoware = pointcloud.array_to_cloud(random_points(AUTOWARE_XYZIRCAEDT, 3), HEADER)
    assert field_table(autoware)[3:6] == [("intensity", 12, 2, 1), ("return_type", 13, 2, 1), ("channel", 14, 4, 1)]
    assert autoware.point_step == 32
    counts = pointcloud.array_to_cloud(random_points(WITH_COUNTS, 3), HEADER)
    assert field_table(counts)[3:] == [("normal", 24, 7, 3), ("rgba", 36, 2, 4), ("label", 40, 3, 1)]


def test_hand_packed_velodyne_bytes_read_correctly():
    PointField = messages.msg_type(pointcloud.POINTFIELD)
    layout = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("ring", 16, 4), ("time", 18, 7)]
    rows = [(1.5, -2.25, 0.125, 17.0, 3, 0.001), (-40.0, 7.75, -1.0, 250.0, 15, 0.099)]
    data = b"".join(struct.pack("<ffffHf", *row) for row in rows)
    msg = messages.msg_type(pointcloud.POINTCLOUD2)(
        header=HEADER, height=1, width=2,
        fields=[PointField(name=n, offset=o, datatype=d, count=1) for n, o, d in layout],
        is_bigendian=False, point_step=22, row_step=44, data=np.frombuffer(data, np.uint8), is_dense=True,
    )  # fmt: skip
    array = pointcloud.cloud_to_array(through_cdr(msg))
    assert array["ring"].tolist() == [3, 15]
    np.testing.assert_array_equal(array["time"], np.float32([0.001, 0.099]))
    np.testing.assert_array_equal(pointcloud.cloud_xyz(msg), np.float32([row[:3] for row in rows]))


def test_padded_rows_are_skipped():
    points = random_points(AUTOWARE_XYZIRCAEDT, (3, 5))
    row_step = 5 * 32 + 12
    data = np.full((3, row_step), 0xAB, dtype=np.uint8)
    data[:, : 5 * 32] = points.view(np.uint8).reshape(3, 5 * 32)
    msg = pointcloud.array_to_cloud(points, HEADER)
    msg.row_step, msg.data = row_step, data.reshape(-1)
    back = through_cdr(msg)
    organized = pointcloud.cloud_to_array(back, organized=True)
    assert organized.shape == (3, 5) and organized.tobytes() == points.tobytes()
    assert pointcloud.cloud_to_array(back).tobytes() == points.tobytes()
    np.testing.assert_array_equal(pointcloud.cloud_xyz(back)[:, 2], points["z"].reshape(-1))


def test_data_given_as_bytes_is_read_like_an_array():
    points = random_points(VELODYNE_XYZIRT, 9)
    msg = pointcloud.array_to_cloud(points, HEADER)
    msg.data = points.tobytes()
    assert pointcloud.cloud_to_array(msg).tobytes() == points.tobytes()


def test_cloud_to_array_is_a_view_of_the_message_data():
    msg = through_cdr(pointcloud.array_to_cloud(random_points(PCL_PADDED, 100), HEADER))
    assert np.shares_memory(pointcloud.cloud_to_array(msg), msg.data)


def test_nan_points_are_skipped_and_their_indices_kept():
    xyz = np.random.default_rng(1).normal(size=(6, 8, 3)).astype(np.float32)
    xyz[0, 1] = np.nan
    xyz[2, 3, 1] = np.inf
    xyz[5, 7, 2] = np.nan
    msg = pointcloud.xyz_to_cloud(xyz, HEADER, intensity=np.ones((6, 8), np.float32))
    assert not msg.is_dense and (msg.height, msg.width) == (6, 8)
    back = through_cdr(msg)
    kept, indices = pointcloud.cloud_xyz(back, with_indices=True)
    flat = xyz.reshape(-1, 3)
    assert indices.tolist() == [i for i in range(48) if i not in (1, 19, 47)]
    np.testing.assert_array_equal(kept, flat[indices])
    everything = pointcloud.cloud_xyz(back, skip_nans=False)
    np.testing.assert_array_equal(everything, flat)
    decoded = pointcloud.decode_cloud(back)
    assert decoded.indices.tolist() == indices.tolist() and decoded.points.shape == (48,)
    assert pointcloud.xyz_to_cloud(np.nan_to_num(xyz), HEADER).is_dense


def test_xyz_to_cloud_carries_flow_labels_and_counts():
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(50, 3))
    flow = rng.normal(size=(50, 3)).astype(np.float32)
    msg = pointcloud.xyz_to_cloud(
        xyz, HEADER, flow_x=flow[:, 0], flow_y=flow[:, 1], flow_z=flow[:, 2],
        label=np.arange(50) % 3, instance=np.arange(50, dtype=np.uint64), dynamic=np.arange(50) > 20,
        probabilities=rng.random((50, 4)),
    )  # fmt: skip
    datatypes = {f.name: (f.datatype, f.count) for f in msg.fields}
    assert datatypes == {"x": (7, 1), "y": (7, 1), "z": (7, 1), "flow_x": (7, 1), "flow_y": (7, 1), "flow_z": (7, 1),
                         "label": (5, 1), "instance": (6, 1), "dynamic": (2, 1), "probabilities": (8, 4)}  # fmt: skip
    covered = np.zeros(msg.point_step, bool)
    for field in msg.fields:
        covered[field.offset : field.offset + field.count * pointcloud.cloud_dtype(msg)[field.name].base.itemsize] = True
    assert not covered.all() and not msg.data.reshape(50, -1)[:, ~covered].any()  # padding is zeroed
    array = pointcloud.cloud_to_array(through_cdr(msg))
    np.testing.assert_array_equal(array["flow_y"], flow[:, 1])
    assert array["label"].tolist() == (np.arange(50) % 3).tolist() and array["dynamic"].sum() == 29
    np.testing.assert_array_equal(pointcloud.cloud_xyz(msg), xyz.astype(np.float32))


@pytest.mark.parametrize(
    "kwargs, problem",
    [
        ({"label": np.arange(49)}, "shape"),
        ({"x": np.zeros(50)}, "clashes"),
        ({"big": np.full(50, 2**40)}, "64-bit"),
        ({"text": np.array(["a"] * 50)}, "cannot carry"),
    ],
)
def test_xyz_to_cloud_rejects_fields_a_pointfield_cannot_carry(kwargs, problem):
    with pytest.raises(MessageError, match=problem):
        pointcloud.xyz_to_cloud(np.zeros((50, 3)), HEADER, **kwargs)


def test_array_to_cloud_rejects_what_pointfield_cannot_carry():
    with pytest.raises(MessageError, match="structured"):
        pointcloud.array_to_cloud(np.zeros((4, 3), np.float32), HEADER)
    with pytest.raises(MessageError, match="int64"):
        pointcloud.array_to_cloud(np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("t", "i8")]), HEADER)


@pytest.mark.parametrize("name", ["vlp16_1673400472138016708.pcd", "vlp32_1713492677464078412.pcd"])
def test_real_scans_survive_pcd_cloud_cdr_cloud_bit_exact(shared_data, name):
    path = shared_data / "lidar_scans" / name
    points = scans.read_points(path)
    raw = path.read_bytes()
    file_data = raw[len(raw) - points.size * points.dtype.itemsize :]
    assert points.tobytes() == file_data  # the reader kept every byte of the binary PCD
    back = through_cdr(pointcloud.array_to_cloud(points, HEADER))
    assert back.data.tobytes() == file_data
    array = pointcloud.cloud_to_array(back)
    assert array.dtype.names == points.dtype.names
    for field in points.dtype.names:
        assert array[field].tobytes() == points[field].tobytes(), field
    if name.startswith("vlp16"):
        assert back.point_step == 32
        assert field_table(back)[3:6] == [("intensity", 12, 2, 1), ("return_type", 13, 2, 1), ("channel", 14, 4, 1)]
    np.testing.assert_array_equal(pointcloud.decode_cloud(back).xyz, scans.read_scan(path)[:, :3])


def good_cloud():
    xyz = np.arange(24, dtype=np.float32).reshape(8, 3)
    return pointcloud.xyz_to_cloud(xyz, HEADER, intensity=np.ones(8, np.float32))


def with_fields(msg, *changes):
    PointField = messages.msg_type(pointcloud.POINTFIELD)
    fields = {f.name: (f.offset, f.datatype, f.count) for f in msg.fields}
    for name, value in changes:
        if value is None:
            fields.pop(name)
        else:
            fields[name] = value
    msg.fields = [PointField(name=n, offset=o, datatype=d, count=c) for n, (o, d, c) in fields.items()]
    return msg


def all_nan(msg):
    msg.data = np.full(msg.data.size // 4, np.nan, dtype=np.float32).view(np.uint8)
    return msg


def truncate(msg):
    msg.data = msg.data[:-3]
    return msg


def empty(msg):
    msg.width, msg.row_step, msg.data = 0, 0, np.zeros(0, np.uint8)
    return msg


def set_attrs(**attrs):
    def change(msg):
        for key, value in attrs.items():
            setattr(msg, key, value)
        return msg

    return change


BAD_CLOUDS = {
    "data_too_short": (truncate, "data holds 125 bytes, expected height 1 × row_step 128"),
    "row_step_too_small": (set_attrs(row_step=100), "row_step 100 is smaller than width 8 × point_step 16"),
    "data_not_height_rows": (
        set_attrs(height=2, width=4, row_step=64, data=np.zeros(100, np.uint8)),
        "data holds 100 bytes, expected height 2 × row_step 64 = 128",
    ),
    "unknown_datatype": (lambda m: with_fields(m, ("intensity", (12, 9, 1))), "'intensity' has unknown datatype 9"),
    "no_z": (lambda m: with_fields(m, ("z", None)), "no z field"),
    "no_xyz": (lambda m: with_fields(m, ("x", None), ("y", None), ("z", None)), "no x/y/z field"),
    "all_nan": (all_nan, "all 8 points have NaN/Inf"),
    "empty": (empty, "empty"),
    "overlap": (lambda m: with_fields(m, ("intensity", (10, 7, 1))), "'z' .* and 'intensity' .* overlap"),
    "outside_point_step": (lambda m: with_fields(m, ("intensity", (14, 7, 1))), "'intensity' .* outside point_step 16"),
    "count_zero": (lambda m: with_fields(m, ("intensity", (12, 7, 0))), "count 0"),
    "xyz_count_3": (lambda m: with_fields(m, ("intensity", None), ("z", (8, 7, 2))), "'z' has count > 1"),
    "zero_point_step": (set_attrs(point_step=0), "point_step is 0"),
}


@pytest.mark.parametrize("case", BAD_CLOUDS)
def test_each_malformed_cloud_gets_one_line_naming_the_problem(case):
    corrupt, problem = BAD_CLOUDS[case]
    msg = corrupt(through_cdr(good_cloud()))
    with pytest.raises(MessageError, match=problem) as caught:
        pointcloud.validate_cloud(msg)
    assert "\n" not in str(caught.value)


class ListLogger:
    def __init__(self):
        self.lines = []

    def warning(self, message):
        self.lines.append(message)


def test_subscriber_helper_logs_one_line_per_bad_cloud_and_keeps_going():
    logger = ListLogger()
    node = SimpleNamespace(_logger=logger)  # Node.decoded needs only the node's logger
    results = [Node.decoded(node, pointcloud.decode_cloud, corrupt(through_cdr(good_cloud())), "/lidar/points")
               for corrupt, _ in BAD_CLOUDS.values()]  # fmt: skip
    assert results == [None] * len(BAD_CLOUDS)
    assert len(logger.lines) == len(BAD_CLOUDS)
    assert all(line.startswith("dropped a message on /lidar/points: PointCloud2") for line in logger.lines)
    decoded = Node.decoded(node, pointcloud.decode_cloud, through_cdr(good_cloud()), "/lidar/points")
    np.testing.assert_array_equal(decoded.xyz, np.arange(24, dtype=np.float32).reshape(8, 3))
    assert decoded.points["intensity"].tolist() == [1.0] * 8 and len(logger.lines) == len(BAD_CLOUDS)


def test_one_drop_line_for_every_node_with_what_follows_and_other_errors_passing_through():
    logger = ListLogger()
    node = SimpleNamespace(_logger=logger)

    def broken(_msg, size):
        raise MessageError(f"mask of {size} points")

    assert Node.decoded(node, broken, None, "/ssf/mask", 3, consequence="; the pose keeps going") is None
    assert logger.lines == ["dropped a message on /ssf/mask: mask of 3 points; the pose keeps going"]
    with pytest.raises(ValueError):
        Node.decoded(node, lambda _msg: int("x"), None, "/ssf/mask")
