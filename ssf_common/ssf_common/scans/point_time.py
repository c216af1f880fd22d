"""Per-point time of a LiDAR sweep: read from the field a real driver writes, or derived from the azimuth.

The drivers' fields, first found first read:

| field | driver | as written |
| --- | --- | --- |
| `time` | velodyne_pointcloud (ROS 1 and 2), LIO-SAM's layout | float32 s relative to the stamp, which marks the last packet |
| `t` | ouster-ros | uint32 ns since the header stamp, the scan's first column |
| `timestamp` | Hesai's ROS drivers, rslidar_sdk; livox_ros_driver2 | float64 s, absolute; Livox: ns, relative |
| `time_stamp` | nebula (Autoware, Hesai / Velodyne / Robosense) | uint32 ns relative to the header stamp, the scan's start |
| `offset_time` | Livox (livox_ros_driver2 frames) | uint32 ns since the frame's first point |

Units and reference are checked, not trusted: the field's own unit when its span makes one plausible sweep (at most
MAX_SWEEP_S; for a spinning sensor at least MIN_TURN_S per full turn of the azimuth it covers), else the one unit
of s, ms, µs and ns that does. Values within a second of zero are relative to the stamp; larger ones are absolute
and are made relative to the stamp (or, without one, to the earliest point). A field that fails gives no time and
one line saying why; so does a constant one, except all zeros: an instant sweep, which needs no deskew (quiet).

A KITTI .bin has no time: `azimuth_time` derives it as KISS-ICP does, assuming the HDL-64E turned clockwise from
behind over one period, relative to the moment it faced forward (KITTI's timestamp, when the cameras fire).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

MAX_SWEEP_S = 0.25  # the slowest drivers turn at 5 Hz (0.2 s); a longer span is not one sweep
MIN_TURN_S = 0.025  # no spinning LiDAR turns faster than 20 Hz (0.05 s per turn): half that is the floor
RELATIVE_WITHIN_S = 1.0  # values within this of zero are offsets from the stamp; beyond, absolute times
KITTI_PERIOD_S = 0.1  # KITTI's HDL-64E turns at 10 Hz
UNIT_EXPONENTS = {0: "s", 3: "ms", 6: "µs", 9: "ns"}  # values per second = 10 ** exponent


class TimeField(NamedTuple):
    """A driver's per-point time field as its driver writes it."""

    name: str
    exponent: int  # of the driver's unit: values per second = 10 ** exponent
    spinning: bool  # written by a spinning LiDAR: a full turn of azimuth takes at least MIN_TURN_S


TIME_FIELDS = (
    TimeField("time", 0, True),
    TimeField("t", 9, True),
    TimeField("timestamp", 0, True),
    TimeField("time_stamp", 9, True),
    TimeField("offset_time", 9, False),
)


class PointTime(NamedTuple):
    """Per-point time of a sweep and where it came from."""

    time: np.ndarray | None  # float32 (N,), s relative to the stamp; None: no usable time
    source: str  # the field read, "azimuth" when derived from it, "" when there is none
    problem: str | None = None  # one line: why a time field that is there gives no time


def point_time(points: np.ndarray, xyz: np.ndarray, stamp_ns: int | None = None,
               indices: np.ndarray | None = None) -> PointTime:
    """Per-point time of structured points (their rows `indices`, xyz (N, 3) of those rows) from the first driver
    time field they have, in s relative to the stamp (or, with no stamp and absolute times, the earliest point)."""
    names = points.dtype.names or ()
    field = next((field for field in TIME_FIELDS if field.name in names), None)
    if field is None:
        return PointTime(None, "")
    values = points[field.name]
    if points.dtype[field.name].shape or values.dtype.kind not in "iuf":
        return _refused(field, f"holds {points.dtype[field.name]} values, not one number per point")
    values = values.reshape(-1) if indices is None else values.reshape(-1)[indices]
    if not len(values):
        return PointTime(None, field.name)
    if values.dtype.kind == "f":
        values = values.astype(np.float64)
        bad = int((~np.isfinite(values)).sum())
        if bad:
            return _refused(field, f"has {bad} of {len(values)} points with a NaN or infinite time")
    elif values.dtype == np.uint64 and values.max() > np.iinfo(np.int64).max:
        return _refused(field, "holds integers beyond 2**63: not nanoseconds of this era")
    else:
        values = values.astype(np.int64)  # absolute nanoseconds fit until 2262
    low, high = values.min(), values.max()
    if low == high:
        return PointTime(None, field.name) if low == 0 else _refused(field, f"gives all {len(values)} points the same "
                                                                            f"time ({float(low):g})")
    span = float(high) - float(low)  # floats: the span of huge integers must not wrap round
    exponent = _sweep_unit(field, span, xyz)
    if exponent is None:
        return _refused(field, _no_unit(field, span, xyz))
    with np.errstate(over="ignore", invalid="ignore"):  # absurd values are judged, not computed with
        return _relative(field, values, exponent, stamp_ns)


def azimuth_time(xyz: np.ndarray, period: float = KITTI_PERIOD_S) -> np.ndarray:
    """float32 (N,) time of each point of a sweep from its azimuth (KISS-ICP's KITTI reading): clockwise from behind
    over one period, s relative to the moment the sensor faced forward (-period / 2 behind on the left ... +period / 2
    behind on the right)."""
    xyz = np.asarray(xyz)
    return (-np.arctan2(xyz[:, 1], xyz[:, 0]) / (2 * np.pi) * period).astype(np.float32)


def _refused(field: TimeField, why: str) -> PointTime:
    return PointTime(None, field.name, f"time field '{field.name}' {why}; no per-point time")


def _sweep_unit(field: TimeField, span: float, xyz: np.ndarray) -> int | None:
    """The unit exponent that makes a span one sweep: the field's own first, then s, ms, µs, ns; None if none."""
    shortest = None  # the least a spinning sensor takes over the azimuth the cloud covers (computed when needed)
    for exponent in (field.exponent, *UNIT_EXPONENTS):
        seconds = span * 10.0**-exponent
        if seconds > MAX_SWEEP_S:
            continue
        if seconds >= MIN_TURN_S or not field.spinning:
            return exponent
        if shortest is None:
            shortest = MIN_TURN_S * azimuth_coverage(xyz) / (2 * np.pi)
        if seconds >= shortest:
            return exponent
    return None


def _no_unit(field: TimeField, span: float, xyz: np.ndarray) -> str:
    """Why no unit makes a span one sweep (the middle of the one-line refusal)."""
    as_written = f"spans {span:g} {UNIT_EXPONENTS[field.exponent]}"
    if field.exponent:
        as_written += f" ({span * 10.0 ** -field.exponent:.3g} s)"
    if not field.spinning:
        return f"{as_written}: in no unit (s, ms, µs, ns) is that one sweep of at most {MAX_SWEEP_S:g} s"
    return (f"{as_written} over {np.degrees(azimuth_coverage(xyz)):.0f}° of azimuth: in no unit (s, ms, µs, ns) is "
            f"that one sweep (a turn takes {MIN_TURN_S:g} to {MAX_SWEEP_S:g} s; times per packet?)")


def _relative(field: TimeField, values: np.ndarray, exponent: int, stamp_ns: int | None) -> PointTime:
    """Seconds relative to the stamp: as they are when near zero; absolute ones less the stamp (or the earliest)."""
    per_second = 10.0**exponent
    if max(abs(float(values.min())), abs(float(values.max()))) / per_second <= RELATIVE_WITHIN_S:
        return PointTime((values / per_second).astype(np.float32), field.name)
    if stamp_ns is None:
        return PointTime(((values - values.min()) / per_second).astype(np.float32), field.name)
    if values.dtype.kind == "f":
        seconds = values / per_second - stamp_ns * 1e-9
    else:  # integers: subtract exactly (absolute nanoseconds do not fit a float64's mantissa)
        seconds = (values - stamp_ns * 10**exponent // 10**9) / per_second
    off = float(np.max(np.abs(seconds)))
    if off > RELATIVE_WITHIN_S:
        return _refused(field, f"holds absolute times up to {off:.3g} s from the header stamp (another clock?)")
    return PointTime(seconds.astype(np.float32), field.name)


def azimuth_coverage(xyz: np.ndarray, sample: int = 8192, bins: int = 360) -> float:
    """Radians of azimuth that a cloud covers: the full turn less its widest empty gap (on a sample of points)."""
    xyz = np.asarray(xyz)
    if not len(xyz):
        return 0.0
    step = max(1, len(xyz) // sample)
    azimuth = np.arctan2(xyz[::step, 1], xyz[::step, 0])
    occupied = np.bincount(((azimuth + np.pi) / (2 * np.pi) * bins).astype(np.int64) % bins, minlength=bins) > 0
    empty = np.flatnonzero(~np.r_[occupied, occupied])  # twice round, so a gap across the seam is one run
    if not len(empty):
        return 2 * np.pi
    runs = np.split(empty, np.flatnonzero(np.diff(empty) > 1) + 1)
    widest = min(max(len(run) for run in runs), bins)
    return 2 * np.pi * (bins - widest) / bins


__all__ = ["KITTI_PERIOD_S", "MAX_SWEEP_S", "MIN_TURN_S", "TIME_FIELDS", "PointTime", "TimeField", "azimuth_coverage",
           "azimuth_time", "point_time"]
