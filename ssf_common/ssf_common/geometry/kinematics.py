"""Planar vehicle motion from velocity commands: where a vehicle that follows each command (forward speed, yaw rate)
within its acceleration limits goes. The planner carries late odometry forward with it; the odometry takes it as the
motion prior across skipped scans. And from the vehicle's own measurements (wheel speed, yaw rate), where it went."""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ssf_common.geometry.se3 import invert, yaw_matrix


class PlanarState(NamedTuple):
    """Position, heading and forward speed on the ground plane."""

    x: float
    y: float
    yaw: float
    speed: float


def driven(start: PlanarState, commands: Sequence[tuple[int, float, float]], start_ns: int, end_ns: int,
           max_accel: float, max_decel: float, step_s: float = 0.02) -> PlanarState:
    """The state at end_ns of a vehicle in `start` at start_ns driven by the commands (stamp, speed, yaw rate; each
    holds until the next one, the one in force at start_ns first), its speed following each command within the
    acceleration limits (m/s^2)."""
    if end_ns <= start_ns:
        return start
    times = [stamp for stamp, _, _ in commands]
    first = max(bisect.bisect_right(times, start_ns) - 1, 0)
    x, y, yaw, speed = start
    t = start_ns
    for index in range(first, len(commands)):
        _, linear, angular = commands[index]
        until = min(commands[index + 1][0] if index + 1 < len(commands) else end_ns, end_ns)
        while t < until:
            dt = min(step_s, (until - t) * 1e-9)
            speed += float(np.clip(linear - speed, -max_decel * dt, max_accel * dt))
            x, y, yaw = _arc(x, y, yaw, speed, angular, dt)
            t += int(round(dt * 1e9))
    return PlanarState(float(x), float(y), float(np.arctan2(np.sin(yaw), np.cos(yaw))), float(speed))


def commanded_motion(commands: Sequence[tuple[int, float, float]], start_ns: int, end_ns: int, speed: float,
                     max_accel: float, max_decel: float, mount: np.ndarray | None = None) -> np.ndarray | None:
    """How the commands moved the vehicle from start_ns (at `speed`) to end_ns: the vehicle frame then <- the vehicle
    frame now (4x4, planar), or of a frame `mount`ed on it (vehicle <- that frame, e.g. a LiDAR); None when no command
    was in force at start_ns (none known yet)."""
    if not commands or commands[0][0] > start_ns:
        return None
    end = driven(PlanarState(0.0, 0.0, 0.0, speed), commands, start_ns, end_ns, max_accel, max_decel)
    return planar_motion(end.x, end.y, end.yaw, mount)


def measured_motion(samples: Sequence[tuple[int, float, float]], start_ns: int, end_ns: int,
                    mount: np.ndarray | None = None, max_age_s: float = 0.5) -> np.ndarray | None:
    """How the vehicle moved from start_ns to end_ns by its measurements (stamp, forward speed, yaw rate; each
    measured over the time since the one before it, the last one holding on to end_ns): the vehicle frame then <- the
    vehicle frame now (4x4, planar), or of a frame `mount`ed on it; None when no sample comes after start_ns, the
    newest is more than `max_age_s` older than end_ns (the sensor stopped), or the first after start_ns comes more
    than that after end_ns (another clock)."""
    if not samples or samples[-1][0] <= start_ns:
        return None
    first = next(stamp for stamp, _, _ in samples if stamp > start_ns)
    if end_ns - samples[-1][0] > max_age_s * 1e9 or first - end_ns > max_age_s * 1e9:
        return None
    x = y = yaw = 0.0
    t = start_ns
    for stamp, speed, yaw_rate in samples:
        if stamp <= start_ns:
            continue
        until = min(stamp, end_ns)
        x, y, yaw = _arc(x, y, yaw, speed, yaw_rate, (until - t) * 1e-9)
        t = until
        if t >= end_ns:
            break
    if t < end_ns:
        x, y, yaw = _arc(x, y, yaw, samples[-1][1], samples[-1][2], (end_ns - t) * 1e-9)
    return planar_motion(x, y, yaw, mount)


def measured_sweep(samples: Sequence[tuple[int, float, float]], start_ns: int, end_ns: int,
                   mount: np.ndarray | None = None) -> np.ndarray | None:
    """The sensor's measured motion from start_ns to end_ns (`measured_motion`) in the ego motion's convention: points
    of the frame then into the frame now (a sweep's deskewing motion); None where `measured_motion` has none."""
    motion = measured_motion(samples, start_ns, end_ns, mount)
    return None if motion is None else invert(motion)


def planar_motion(x: float, y: float, yaw: float, mount: np.ndarray | None = None) -> np.ndarray:
    """The vehicle frame then <- the vehicle frame now (4x4) of a planar move, or of a frame `mount`ed on it."""
    motion = yaw_matrix(yaw)
    motion[:2, 3] = x, y
    return motion if mount is None else invert(mount) @ motion @ mount


def _arc(x: float, y: float, yaw: float, speed: float, yaw_rate: float, seconds: float) -> tuple[float, float, float]:
    """A planar pose moved `seconds` at constant speed and yaw rate (along the chord of its arc)."""
    middle = yaw + 0.5 * yaw_rate * seconds
    return x + speed * np.cos(middle) * seconds, y + speed * np.sin(middle) * seconds, yaw + yaw_rate * seconds


def forward_speed(motion: np.ndarray, seconds: float, mount: np.ndarray | None = None) -> float:
    """The forward speed (m/s) of a vehicle that moved by `motion` (its frame then <- now) in `seconds`, or whose
    `mount`ed frame (vehicle <- that frame, e.g. a LiDAR) did."""
    vehicle = motion if mount is None else mount @ motion @ invert(mount)
    return float(vehicle[0, 3]) / seconds
