"""Per-point time from real drivers' fields, in each driver's unit and reference, through PointCloud2 and PCD; derived
from the azimuth for KITTI .bin; one line, and no time, for a field that cannot be one sweep."""

from __future__ import annotations

import numpy as np
import pytest

from ssf_common import messages, pointcloud, scans
from ssf_common.scans.point_time import MAX_SWEEP_S, azimuth_coverage, azimuth_time, point_time

STAMP_NS = 1_713_492_677_464_078_412
PERIOD = 0.1

# the drivers' point layouts, as their PointCloud2 messages carry them
VELODYNE = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],  # velodyne_pointcloud XYZIRT
                     "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                     "offsets": [0, 4, 8, 12, 16, 18], "itemsize": 22})
OUSTER = np.dtype({"names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],  # ouster-ros
                   "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
                   "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32], "itemsize": 48})
NEBULA = np.dtype({"names": ["x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation", "distance",
                             "time_stamp"],  # Autoware's PointXYZIRCAEDT
                   "formats": ["<f4", "<f4", "<f4", "u1", "u1", "<u2", "<f4", "<f4", "<f4", "<u4"],
                   "offsets": [0, 4, 8, 12, 13, 14, 16, 20, 24, 28], "itemsize": 32})
HESAI = np.dtype({"names": ["x", "y", "z", "intensity", "timestamp", "ring"],  # HesaiLidar ROS PointXYZIT
                  "formats": ["<f4", "<f4", "<f4", "<f4", "<f8", "<u2"], "offsets": [0, 4, 8, 16, 24, 32],
                  "itemsize": 48})
LIVOX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("reflectivity", "u1"), ("tag", "u1"), ("line", "u1"),
                  ("offset_time", "<u4")])  # a Livox frame as PointCloud2 (CustomMsg points: offset_time ns)


def sweep(dtype: np.dtype, count: int = 3600, fov_deg: float = 360.0) -> tuple[np.ndarray, np.ndarray]:
    """Points on a ring turning clockwise over one period, and each one's time (s from the start of the sweep)."""
    points = np.zeros(count, dtype)
    phase = np.arange(count) / count
    azimuth = np.radians(fov_deg / 2) - phase * np.radians(fov_deg)  # clockwise
    points["x"], points["y"], points["z"] = 10 * np.cos(azimuth), 10 * np.sin(azimuth), -1.0
    return points, phase * PERIOD


def decoded(points: np.ndarray, stamp_ns: int = STAMP_NS) -> pointcloud.DecodedCloud:
    msg = pointcloud.array_to_cloud(points, messages.header(stamp_ns, "lidar"))
    return pointcloud.decode_cloud(messages.deserialize(messages.serialize(msg), pointcloud.POINTCLOUD2))


@pytest.mark.parametrize(("layout", "field", "written"), [
    (VELODYNE, "time", lambda seconds: (seconds - PERIOD).astype(np.float32)),  # s, <= 0: the stamp ends the sweep
    (OUSTER, "t", lambda seconds: np.round(seconds * 1e9).astype(np.uint32)),  # ns from the first column
    (NEBULA, "time_stamp", lambda seconds: np.round(seconds * 1e9).astype(np.uint32)),  # ns from the stamp
    (LIVOX, "offset_time", lambda seconds: np.round(seconds * 1e9).astype(np.uint32)),  # ns from the first point
], ids=["velodyne", "ouster", "nebula", "livox"])  # fmt: skip
def test_each_drivers_relative_time_field_is_read_in_its_unit(layout, field, written):
    points, seconds = sweep(layout, fov_deg=70.0 if field == "offset_time" else 360.0)
    points[field] = written(seconds)
    expected = points[field].astype(np.float64) * (1.0 if field == "time" else 1e-9)
    cloud = decoded(points)
    assert cloud.time_problem is None and cloud.time.dtype == np.float32
    np.testing.assert_allclose(cloud.time, expected, atol=1e-7)
    assert np.ptp(cloud.time) == pytest.approx(PERIOD, rel=1e-3)


def test_absolute_times_are_made_relative_to_the_stamp_or_else_to_the_earliest_point(tmp_path):
    points, seconds = sweep(HESAI)
    points["timestamp"] = STAMP_NS * 1e-9 + seconds  # Hesai: float64 s since the epoch, the stamp at the first point
    np.testing.assert_allclose(decoded(points).time, seconds, atol=1e-6)
    nanoseconds = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("timestamp", "<u8")])
    for axis in "xyz":
        nanoseconds[axis] = points[axis]
    nanoseconds["timestamp"] = STAMP_NS - 50_000_000 + np.round(seconds * 1e9).astype(np.uint64)  # u64 epoch ns (PCD)
    exact = point_time(nanoseconds, np.c_[points["x"], points["y"], points["z"]], STAMP_NS).time
    np.testing.assert_allclose(exact, seconds - 0.05, atol=1e-8)  # integer arithmetic: no float rounding of epochs
    scans.write_pcd(tmp_path / "hesai.pcd", points)  # a file has no stamp: from the earliest point
    np.testing.assert_allclose(scans.read_scan_with_time(tmp_path / "hesai.pcd").time, seconds, atol=1e-6)


def test_livox_ros_driver2s_float_timestamp_is_relative_nanoseconds():
    points, seconds = sweep(LIVOX, fov_deg=70.0)
    livox = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("reflectivity", "<f4"), ("tag", "u1"),
                                   ("line", "u1"), ("timestamp", "<f8")])  # its PointCloud2: offset_time as a double
    for axis in "xyz":
        livox[axis] = points[axis]
    livox["timestamp"] = np.round(seconds * 1e9)
    np.testing.assert_allclose(decoded(livox).time, seconds, atol=1e-9)


def test_a_field_in_another_unit_than_its_drivers_is_read_in_the_one_that_makes_a_sweep():
    points, seconds = sweep(VELODYNE)
    points["time"] = seconds * 1e3  # milliseconds in a field whose driver writes seconds
    np.testing.assert_allclose(decoded(points).time, seconds, atol=1e-6)
    ouster, _ = sweep(OUSTER)
    ouster["t"] = np.round(seconds * 1e6).astype(np.uint32)  # microseconds
    np.testing.assert_allclose(decoded(ouster).time, seconds, atol=1e-6)


@pytest.mark.parametrize(("case", "problem"), [
    ("constant", "gives all 3600 points the same time (0.05)"),
    ("nan", "has 1 of 3600 points with a NaN or infinite time"),
    ("too_long", "in no unit (s, ms, µs, ns) is that one sweep"),
    ("per_packet", "over 360° of azimuth: in no unit"),
    ("another_clock", "absolute times up to 3.6e+03 s from the header stamp"),
])  # fmt: skip
def test_a_field_that_cannot_be_one_sweep_gives_one_line_and_no_time(case, problem):
    points, seconds = sweep(VELODYNE)
    points["time"] = {"constant": np.full(len(points), 0.05), "nan": np.r_[seconds[:-1], np.nan],
                      "too_long": seconds * 20, "per_packet": np.mod(seconds, 0.0013), "another_clock": 0.0}[case]
    if case == "another_clock":  # float64 s since the epoch, an hour off the header stamp
        wide = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("time", "<f8")])
        for name in ("x", "y", "z"):
            wide[name] = points[name]
        wide["time"], points = STAMP_NS * 1e-9 + 3600 + seconds, wide
    cloud = decoded(points)
    assert cloud.time is None and len(cloud.xyz) == len(points)  # the cloud itself is fine
    assert problem in cloud.time_problem and "'time'" in cloud.time_problem and "\n" not in cloud.time_problem


def test_an_instant_sweep_and_a_cloud_without_a_time_field_have_no_time_quietly():
    points, _ = sweep(VELODYNE)
    assert decoded(points).time is None and decoded(points).time_problem is None  # every time 0: taken at once
    bare = np.zeros(10, [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    assert decoded(bare).time is None and decoded(bare).time_problem is None
    counted = np.zeros(10, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4", (2,))])
    assert "one number per point" in decoded(counted).time_problem


def test_time_follows_the_kept_points_when_some_coordinates_are_not_finite():
    points, seconds = sweep(VELODYNE)
    points["time"] = seconds
    points["x"][::7] = np.nan
    cloud = decoded(points)
    np.testing.assert_array_equal(cloud.time, seconds[cloud.indices].astype(np.float32))
    assert len(cloud.time) == len(cloud.xyz) < len(points)


def test_a_pcd_file_with_a_driver_field_reads_its_time(tmp_path):
    points, seconds = sweep(NEBULA)
    points["time_stamp"] = np.round(seconds * 1e9).astype(np.uint32)
    points["x"][5] = np.inf  # dropped, and its time with it
    scans.write_pcd(tmp_path / "nebula.pcd", points)
    read = scans.read_scan_with_time(tmp_path / "nebula.pcd", warn=None)
    assert len(read.points) == len(read.time) == len(points) - 1
    np.testing.assert_allclose(read.time, np.delete(seconds, 5), atol=1e-7)
    assert scans.load_scan(tmp_path / "nebula.pcd").time_source == "time_stamp"


def test_a_kitti_bin_has_its_time_from_the_azimuth_clockwise_from_behind(tmp_path):
    angles = np.radians([179.0, 90.0, 0.0, -90.0, -179.0])  # behind-left, left, ahead, right, behind-right
    xyz = np.c_[10 * np.cos(angles), 10 * np.sin(angles), np.zeros(5)]
    scans.write_bin(tmp_path / "000000.bin", xyz)
    read = scans.read_scan_with_time(tmp_path / "000000.bin")
    np.testing.assert_allclose(read.time, [-0.0497, -0.025, 0.0, 0.025, 0.0497], atol=1e-4)  # KITTI's stamp: ahead
    assert scans.load_scan(tmp_path / "000000.bin").time_source == "azimuth"
    np.testing.assert_allclose(scans.read_scan_with_time(tmp_path / "000000.bin", sweep_period=0.05).time,
                               read.time / 2, atol=1e-7)
    with pytest.raises(scans.DataError, match="sweep_period"):
        scans.load_scan(tmp_path / "000000.bin", sweep_period=float("nan"))


def test_azimuth_coverage_of_a_ring_and_of_an_arc_across_the_seam():
    full, _ = sweep(VELODYNE)
    arc, _ = sweep(VELODYNE, fov_deg=70.0)
    assert np.degrees(azimuth_coverage(np.c_[full["x"], full["y"]])) == pytest.approx(360.0, abs=1.0)
    behind = np.c_[-arc["x"], -arc["y"]]  # the same arc centred behind: across the +-180 degree seam
    assert np.degrees(azimuth_coverage(behind)) == pytest.approx(70.0, abs=2.0)


def test_real_scans(shared_data):
    folder = shared_data / "lidar_scans"
    vlp16 = scans.load_scan(folder / "vlp16_1673400472138016708.pcd")
    # nebula wrote time_stamp per packet here: it restarts every ~1.3 ms, so it is not the time within the sweep
    assert vlp16.time is None and vlp16.time_source == "time_stamp"
    assert "'time_stamp' spans" in vlp16.time_problem and "of azimuth" in vlp16.time_problem
    raw = scans.read_points(folder / "vlp16_1673400472138016708.pcd")
    restarts = np.flatnonzero(np.diff(raw["time_stamp"].astype(np.int64)) < 0)
    assert len(restarts) > 100 and raw["time_stamp"].max() * 1e-9 < MAX_SWEEP_S / 100
    vlp32 = scans.load_scan(folder / "vlp32_1713492677464078412.pcd")
    assert vlp32.time is None and vlp32.time_source == "" and vlp32.time_problem is None
    # KISS-ICP's time from the azimuth agrees with the sensor's own encoder angle (nebula: clockwise from ahead)
    derived = azimuth_time(vlp16.points[:, :3])
    encoder = np.angle(np.exp(1j * raw["azimuth"].astype(np.float64)))
    np.testing.assert_allclose(derived, encoder / (2 * np.pi) * PERIOD, atol=1e-5)
    assert point_time(raw, vlp16.points[:, :3]).problem == vlp16.time_problem
