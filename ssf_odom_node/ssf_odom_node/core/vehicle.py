"""The vehicle around the sensor: where the sensor is mounted, the odometry as base_link sees it, and the motion priors
from what the vehicle was told (velocity commands) and what it measured (its twist) between two scans."""

from __future__ import annotations

import collections
import dataclasses
import threading

import numpy as np

from ssf_common.geometry.kinematics import commanded_motion, forward_speed
from ssf_common.geometry.se3 import invert
from ssf_common.records import OdometryEstimate
from ssf_common.vehicle import MeasuredTwists
from ssf_odom_node.core.odometry import OdomStep

COMMANDS_KEPT = 600  # velocity commands kept for the motion prior: a minute at 10 Hz, far longer than any gap


def to_base(step: OdomStep, mount: np.ndarray, odom_frame: str, base_frame: str) -> OdometryEstimate:
    """An odometry step of the sensor (first scan's sensor frame) as base_link in the odom frame (base_link at the
    first scan): pose M P M^-1, covariance and twist rotated into base_link axes."""
    rotation = np.kron(np.eye(2), mount[:3, :3])
    angular = mount[:3, :3] @ step.twist[3:]
    linear = mount[:3, :3] @ step.twist[:3] + np.cross(mount[:3, 3], angular)
    return OdometryEstimate(step.stamp_ns, mount @ step.pose @ invert(mount), rotation @ step.covariance @ rotation.T,
                            np.concatenate([linear, angular]), np.zeros((6, 6)), odom_frame, base_frame)


def next_scan_estimate(estimate: OdometryEstimate, step: OdomStep, next_pose: np.ndarray | None, mount: np.ndarray,
                       period_ns: int | None) -> OdometryEstimate:
    """The pose of the scan the flow reaches (`next_pose`, of the sensor) as base_link, stamped one sensor period after
    the flow's scan; the scan's own `estimate` without a flow or before the period is known."""
    if step.next_motion is None or next_pose is None or period_ns is None:
        return estimate
    return dataclasses.replace(estimate, stamp_ns=step.stamp_ns + period_ns, pose=mount @ next_pose @ invert(mount))


def speed_ahead(step: OdomStep, scan_period: float, mount: np.ndarray, without_flow: float) -> float:
    """base_link's forward speed (m/s) at a scan: its flow's motion ahead over one scan period (the speed at the scan
    itself), `without_flow` where the scan had no flow."""
    if step.next_motion is None:
        return without_flow
    return forward_speed(invert(step.next_motion), scan_period, mount)


def command_prior(commands: list[tuple[int, float, float]], last_stamp_ns: int | None, stamp_ns: int, speed: float,
                  limits: tuple[float, float], mount: np.ndarray) -> np.ndarray | None:
    """The sensor's motion from the last scan to this one (last scan's sensor frame <- this one's) as the commands
    (stamp, speed, yaw rate) drove the vehicle within its acceleration and deceleration `limits`; None before the first
    scan or without commands."""
    if last_stamp_ns is None:
        return None
    return commanded_motion(commands, last_stamp_ns, stamp_ns, speed, *limits, mount)


class VehicleMotion:
    """What the vehicle was told and what it measured, kept for the motion priors between scans (thread-safe: the
    subscriptions add while the odometry's worker reads)."""

    def __init__(self, commands_kept: int = COMMANDS_KEPT) -> None:
        self.commands: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=commands_kept)
        self.twists = MeasuredTwists()
        self._lock = threading.Lock()

    def add_command(self, now_ns: int, linear: float, angular: float) -> None:
        """A velocity command with the time it arrived; a clock gone back (a restarted stream) forgets the older."""
        with self._lock:
            if self.commands and now_ns < self.commands[-1][0]:
                self.commands.clear()
            self.commands.append((now_ns, linear, angular))

    def add_twist(self, stamp_ns: int, linear: float, angular: float) -> None:
        """One measurement of speed and yaw rate (see `MeasuredTwists.add`)."""
        self.twists.add(stamp_ns, linear, angular)

    def commanded(self, last_stamp_ns: int | None, stamp_ns: int, speed: float, limits: tuple[float, float],
                  mount: np.ndarray) -> np.ndarray | None:
        """The commands' motion prior from the last scan to this one (see `command_prior`)."""
        with self._lock:
            commands = list(self.commands)
        return command_prior(commands, last_stamp_ns, stamp_ns, speed, limits, mount)

    def measured(self, last_stamp_ns: int | None, stamp_ns: int,
                 mount: np.ndarray) -> tuple[np.ndarray | None, int | None]:
        """The sensor's motion from the last scan to this one as the measurements give it (None before the first scan,
        without measurements, or when they stopped), and the newest measurement's stamp (None: none came)."""
        return self.twists.motion(last_stamp_ns, stamp_ns, mount)
