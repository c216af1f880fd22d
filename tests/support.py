"""Helpers shared by tests: ROS 2 types written by hand from the IDL (no project code), polling, random point
records and swept scans."""

import time
from dataclasses import dataclass

import numpy as np

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


SWEEP_PERIOD, SWEEP_SPEED = 0.1, 10.0  # s, m/s: a swept sensor drives 1 m while it turns


def random_points(dtype: np.dtype, shape, seed: int = 0, scale: float = 20.0) -> np.ndarray:
    """Random values for every field of a structured dtype (floats normal of `scale`, integers over their whole
    range), padding bytes zero."""
    rng = np.random.default_rng(seed)
    points = np.zeros(shape, dtype=dtype)
    for name in dtype.names:
        field = points[name]
        if field.dtype.kind == "f":
            field[...] = rng.normal(scale=scale, size=field.shape)
        else:
            native = field.dtype.base.newbyteorder("=")
            field[...] = rng.integers(np.iinfo(native).min, np.iinfo(native).max, field.shape, native, endpoint=True)
    return points


def azimuth_times(xyz: np.ndarray) -> np.ndarray:
    """Firing times (s, <= 0, stamp at the sweep's end) of points by azimuth: clockwise from behind."""
    share = np.mod(np.pi - np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * np.pi) / (2 * np.pi)  # 0 behind, growing clockwise
    return ((share - 1.0) * SWEEP_PERIOD).astype(np.float32)


def swept(world: np.ndarray, stamp_x: float, speed: float = SWEEP_SPEED) -> tuple[np.ndarray, np.ndarray]:
    """A sweep of static world points by a sensor driving along x at `speed`, at stamp_x at its stamp: each point in
    the sensor frame of its firing time, and that time."""
    times = azimuth_times(world - [stamp_x, 0, 0])
    for _ in range(3):  # the azimuth a point is seen at depends on where the sensor is then
        times = azimuth_times(world - np.c_[stamp_x + speed * times, np.zeros((len(world), 2))])
    return (world - np.c_[stamp_x + speed * times, np.zeros((len(world), 2))]).astype(np.float32), times


def swept_stream(seed: int, sweeps: int, speeds: list[float] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Consecutive sweeps (points and times) of a street (ground, two facades and an end wall) by a sensor driving
    along it at SWEEP_SPEED, or at speeds[i] during sweep i (it stands at x = 0 at the first stamp)."""
    rng = np.random.default_rng(seed)
    world = np.vstack([np.c_[rng.uniform(-30, 30, (3000, 2)), rng.normal(-1.7, 0.02, 3000)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, 8.0), rng.uniform(-1.7, 3, 1500)],
                       np.c_[np.full(1500, 25.0), rng.uniform(-8, 8, 1500), rng.uniform(-1.7, 3, 1500)],
                       np.c_[rng.uniform(-30, 30, 1500), np.full(1500, -9.0), rng.uniform(-1.7, 3, 1500)]])
    speeds = [SWEEP_SPEED] * sweeps if speeds is None else list(speeds)
    stamps = np.concatenate([[0.0], np.cumsum(np.asarray(speeds[1:]) * SWEEP_PERIOD)])
    return [swept(world, stamp, speed) for stamp, speed in zip(stamps, speeds)]


def swept_pair(seed: int) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Two consecutive sweeps (points and times) of a street by a sensor driving along it at SWEEP_SPEED."""
    first, second = swept_stream(seed, 2)
    return first, second


class FakeTime:
    """A clock and a stop event in one: waiting advances the clock instead of sleeping."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def wait(self, seconds: float) -> bool:
        self.now += seconds
        return False

    def is_set(self) -> bool:
        return False
