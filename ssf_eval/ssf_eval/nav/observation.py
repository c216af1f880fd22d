"""What every perception source of the navigation benchmark takes each tick and what it is: one frame in, obstacles
in the odometry frame out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_bridge.simulator import Frame
from ssf_common.records import Obstacles

ODOM_FRAME = "odom"


@dataclass(frozen=True)
class Observation:
    """What perception gets each tick: the simulator frame and where the sensor is in the odometry frame."""

    frame: Frame
    lidar_pose: np.ndarray  # (4, 4) odom <- lidar at the frame's stamp
    world_to_odom: np.ndarray  # (4, 4) odom <- world (ground truth, for `gt` only)


class NavPerception(Protocol):
    """A perception source: obstacles (odometry frame, with velocities) from each frame in turn."""

    name: str
    reads_scan: bool

    def observe(self, observation: Observation) -> Obstacles:
        """Obstacles seen in this frame (stamped when they were seen)."""
