"""Sweeps that take their period to turn: each point moved from the sensor frame of its own time to the frame at its
scan's stamp (deskew), and back (reskew), at constant velocity within the sweep.

A point's `time` is seconds relative to its scan's header stamp (<= 0 where the stamp marks the sweep's end, >= 0
where it marks the start; the readers give either). The sensor's motion is given as the flow's ego motion over one
period: the transform that maps static points of the frame at a stamp into the frame one period later, (L_T)^-1 L_0.
At constant velocity the frame at time t relative to the stamp is reached by that motion raised to -t / period, so a
point taken at t lies at motion^(-t / period) p in the stamp's frame (se3.interpolate_poses, a constant-twist motion).
Flow and odometry deskew with the motion along the ground only (`planar`): a car's height, roll and pitch follow the
road's bumps, which change within a period and which no constant velocity predicts; the odometry fits the sensor's
rise or fall over each sweep with the scan's pose instead (ssf_odom_node registration, `shares`)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from ssf_common.errors import DataError
from ssf_common.geometry.compiled import posed_points
from ssf_common.geometry.se3 import interpolate_poses, invert, make_pose, yaw_of

STEPS = 4096  # shares of a period between the poses the points take: at 10 Hz and 30 m/s, 0.4 mm apart at most


class PairTimes(NamedTuple):
    """Per-point time of scan t and of scan t+1 (s relative to each one's stamp; empty: an instant sweep), the time
    between the stamps, and the sensor's motion over scan t+1's sweep where the vehicle measured it."""

    time1: np.ndarray
    time2: np.ndarray
    period: float
    measured: np.ndarray | None = None  # (4, 4) scan t's sensor frame -> scan t+1's, the flow's ego motion convention


def timed(time: np.ndarray | None) -> bool:
    """Whether a scan's per-point time says anything: given, and not an instant sweep (all zero)."""
    return time is not None and bool(np.any(np.asarray(time)))


def pair_times(time1: np.ndarray | None, time2: np.ndarray | None, period: float,
               measured: np.ndarray | None = None) -> PairTimes | None:
    """The pair's times when either scan took its period to turn (a scan without time then counts as instant), and the
    sensor's motion between the stamps as the vehicle's own sensors measured it (wheel speed and gyro:
    `measured_sweep`), which deskews scan t+1 and guides the ego motion where given; None: neither, nothing to
    deskew."""
    if not (timed(time1) or timed(time2)) and measured is None:
        return None
    return PairTimes(*(np.zeros(0, np.float32) if time is None else np.asarray(time, np.float32)
                       for time in (time1, time2)), float(period), None if measured is None else np.asarray(measured, np.float64))


def check_time(time: np.ndarray, count: int, name: str) -> np.ndarray:
    """A scan's per-point time as float64 (an empty array: an instant sweep of `count` points); DataError names a
    mismatch."""
    time = np.asarray(time, dtype=np.float64).reshape(-1)
    if time.size == 0:
        return np.zeros(count)
    if time.shape != (count,) or not np.isfinite(time).all():
        raise DataError(f"{name}: expected {count} finite per-point times, got {time.size} values"
                        + ("" if time.shape != (count,) else " with NaN/Inf"))
    return time


def deskew(points: np.ndarray, time: np.ndarray, motion: np.ndarray, period: float) -> np.ndarray:
    """Points (N, 3) each in the sensor frame of its time, moved into the frame at the stamp (float32)."""
    return _move(points, time, motion, period, back=False)


def reskew(points: np.ndarray, time: np.ndarray, motion: np.ndarray, period: float) -> np.ndarray:
    """Points (N, 3) in the frame at the stamp, each moved into the sensor frame of its time: deskew undone."""
    return _move(points, time, motion, period, back=True)


def planar(motion: np.ndarray) -> np.ndarray:
    """A sweep's motion along the ground (x, y, yaw): what constant velocity carries across a sweep. Height, roll and
    pitch change with each bump of the road within a period and are left as the sweep took them."""
    motion = np.asarray(motion, dtype=np.float64)
    return make_pose(motion[0, 3], motion[1, 3], 0.0, yaw_of(motion))


def _move(points: np.ndarray, time: np.ndarray, motion: np.ndarray, period: float, back: bool) -> np.ndarray:
    """Each point through motion^(-time / period), or its inverse (`back`); poses taken at STEPS shares a period."""
    points = np.asarray(points)[:, :3]
    if points.dtype not in (np.float32, np.float64):
        points = points.astype(np.float64)
    if period <= 0 or not np.isfinite(period):
        raise DataError(f"a sweep's period must be a positive number of seconds, got {period}")
    steps = np.rint(-check_time(time, len(points), "sweep") / period * STEPS).astype(np.int64)
    if not len(points) or not steps.any():
        return points.astype(np.float32)
    low = int(steps.min())
    table = _pose_table(np.asarray(motion, dtype=np.float64).tobytes(), low, int(steps.max()), back)
    return posed_points(np.ascontiguousarray(points), steps, low, table)  # a 3x4 pose per point, in float64


@functools.lru_cache(maxsize=8)
def _pose_table(motion: bytes, low: int, high: int, back: bool) -> np.ndarray:
    """The poses (K, 12: the top three rows) at steps low..high of a motion given as its float64 bytes, or their
    inverses: one sweep's table serves every scan moved with the same motion (deskewed, then carried back)."""
    motion = np.frombuffer(motion).reshape(4, 4)
    shares = np.arange(low, high + 1) / STEPS
    poses = arc_poses(motion, shares) if is_planar(motion) else interpolate_poses(np.eye(4), motion, shares)
    table = (invert(poses) if back else poses)[:, :3, :].reshape(-1, 12).copy()
    table.flags.writeable = False
    return table


def is_planar(motion: np.ndarray) -> bool:
    """Whether a motion is one along the ground: a turn about z and a move in x and y only (what `planar` gives)."""
    return bool(motion[2, 3] == 0.0 and motion[2, 2] == 1.0 and not motion[2, :2].any() and not motion[:2, 2].any())


def arc_poses(motion: np.ndarray, shares: np.ndarray) -> np.ndarray:
    """Poses (K, 4, 4) at `shares` of a constant-twist motion along the ground from the identity to `motion`: the
    closed form of se3.interpolate_poses for a turn about z (a sweep's 4097 poses in 0.15 ms against 2.2; on the arc
    to 1e-12 m, where interpolate_poses' arccos loses digits on gentle turns). With a turn of angle a, a share s turns
    by s a and moves by s V(s a) V(a)^-1 t, V the turn's left Jacobian."""
    angle = float(np.arctan2(motion[1, 0], motion[0, 0]))
    poses = np.zeros((len(shares), 4, 4))
    turned = shares * angle
    cosine, sine = np.cos(turned), np.sin(turned)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = cosine, -sine, sine, cosine
    poses[:, 2, 2] = poses[:, 3, 3] = 1.0
    if abs(angle) < 1e-9:  # a straight move: a share of the way
        poses[:, :2, 3] = shares[:, None] * motion[:2, 3]
        return poses
    # s V(s a) = [[sin(s a), -(1 - cos(s a))], [1 - cos(s a), sin(s a)]] / a; the 1 / a cancels against V(a)^-1's a
    versine = 2.0 * np.sin(turned / 2.0) ** 2  # 1 - cos, without cancellation
    whole = np.array([[np.sin(angle), -2.0 * np.sin(angle / 2.0) ** 2], [2.0 * np.sin(angle / 2.0) ** 2, np.sin(angle)]])
    twist = np.linalg.solve(whole, motion[:2, 3])  # V(a)^-1 t / a
    poses[:, 0, 3] = sine * twist[0] - versine * twist[1]
    poses[:, 1, 3] = versine * twist[0] + sine * twist[1]
    return poses


__all__ = ["PairTimes", "check_time", "deskew", "pair_times", "planar", "reskew", "timed"]
