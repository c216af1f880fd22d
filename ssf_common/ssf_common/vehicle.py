"""The vehicle around the sensor: where the sensor is mounted (a parameter until /tf says: `pose_msgs.mount_from_tf`)
and what the vehicle measured of its own motion (wheel speed and yaw-rate gyro, geometry_msgs/TwistStamped)."""

from __future__ import annotations

import collections
import threading

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.kinematics import measured_motion, measured_sweep

TWISTS_KEPT = 6000  # measured twists kept: a minute at 100 Hz


class MountConfig(Section):
    """Where the sensor sits on the vehicle."""

    base_frame: str = "base_link"
    mount: tuple[float, float, float, float, float, float] = Field(
        (0.0, 0.0, 1.8, 0.0, 0.0, 0.0), description="base_link -> sensor: x y z roll pitch yaw (m, rad), until /tf says")
    mount_from_tf: bool = Field(True, description="take base_link -> sensor from /tf when it is published there")


def mount_matrix(values: tuple[float, ...]) -> np.ndarray:
    """4x4 base_link <- sensor of x y z roll pitch yaw."""
    from scipy.spatial.transform import Rotation

    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("xyz", values[3:]).as_matrix()
    matrix[:3, 3] = values[:3]
    return matrix


class MeasuredTwists:
    """The vehicle's measurements of its speed and yaw rate, kept for its motion between two scans (thread-safe: a
    subscription adds while a worker reads)."""

    def __init__(self, kept: int = TWISTS_KEPT) -> None:
        self.samples: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=kept)
        self._lock = threading.Lock()

    def add(self, stamp_ns: int, linear: float, angular: float) -> None:
        """One measurement of speed and yaw rate; the same sample again is skipped, stamps gone back forget the older."""
        with self._lock:
            if self.samples and stamp_ns <= self.samples[-1][0]:
                if stamp_ns == self.samples[-1][0]:
                    return
                self.samples.clear()
            self.samples.append((stamp_ns, linear, angular))

    def motion(self, start_ns: int | None, end_ns: int, mount: np.ndarray) -> tuple[np.ndarray | None, int | None]:
        """The sensor's motion from start_ns to end_ns as the measurements give it (the frame then <- the frame now;
        None without a start, without measurements, or when they stopped), and the newest measurement's stamp (None:
        none came)."""
        if start_ns is None:
            return None, None
        samples = self.snapshot()
        return measured_motion(samples, start_ns, end_ns, mount), (samples[-1][0] if samples else None)

    def sweep(self, start_ns: int, end_ns: int, mount: np.ndarray) -> np.ndarray | None:
        """The sensor's measured motion over a sweep from start_ns to end_ns as the flow deskews with it
        (`measured_sweep`), or None."""
        return measured_sweep(self.snapshot(), start_ns, end_ns, mount)

    def snapshot(self) -> list[tuple[int, float, float]]:
        """The measurements kept, (stamp, speed, yaw rate), as they are now."""
        with self._lock:
            return list(self.samples)
