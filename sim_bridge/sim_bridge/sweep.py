"""One sweep in time: where the sensor and every agent are while the LiDAR turns.

A scan's stamp marks the end of its sweep, as velodyne_driver stamps a scan with its last packet: the last column
fires at the stamp, the first one period earlier, and a point's `time` is seconds relative to the stamp (-period <
time <= 0). The simulator steps once per sweep, so a sweep spans the step that ends at its stamp: the sensor moves
along the constant-twist (screw) motion between the previous step's pose and the stamp's (the ego's unicycle arc),
each agent along a straight line turning at a constant rate (as the traffic model moves it). Both are exact at the
stamp, so an instant sweep (every time 0) is the scan of the stamp's state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_bridge.agents import AgentStates, planar_poses
from ssf_common.geometry.se3 import interpolate_poses


@dataclass(frozen=True)
class Sweep:
    """The sensor's and the agents' states one period before a stamp and at it, and the motion between."""

    period: float  # s
    pose_start: np.ndarray  # (4, 4) world <- lidar one period before the stamp
    pose: np.ndarray  # (4, 4) world <- lidar at the stamp
    agents_start: AgentStates  # the same agents, in the same order, one period before the stamp
    agents: AgentStates  # at the stamp

    def __post_init__(self) -> None:
        if not np.array_equal(self.agents_start.ids, self.agents.ids):
            raise ValueError("a sweep's agents must be the same at its start and at its stamp")

    @staticmethod
    def still(pose: np.ndarray, agents: AgentStates, period: float) -> Sweep:
        """A sweep during which nothing moves (the first of an episode: nothing is known before it)."""
        return Sweep(period, pose, pose, agents, agents)

    def shares(self, times: np.ndarray) -> np.ndarray:
        """How far through the sweep each time (s relative to the stamp) lies: 0 at its start, 1 at the stamp."""
        return 1.0 + np.asarray(times, dtype=np.float64) / self.period

    def sensor_poses(self, times: np.ndarray) -> np.ndarray:
        """World <- lidar (K, 4, 4) at times (K,) relative to the stamp."""
        return interpolate_poses(self.pose_start, self.pose, self.shares(times))

    def agent_states(self, index: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (K, 3) and headings (K,) of agents index (K,) at times (K,) relative to the stamp."""
        back = self.shares(times) - 1.0  # <= 0: measured back from the stamp, so exact there
        start, end = self.agents_start, self.agents
        moved = end.position - start.position
        turn = np.angle(np.exp(1j * (end.yaw - start.yaw)))  # the shorter way round
        return end.position[index] + back[:, None] * moved[index], end.yaw[index] + back * turn[index]

    def agent_poses(self, index: np.ndarray, times: np.ndarray) -> np.ndarray:
        """World <- agent (K, 4, 4) of agents index (K,) at times (K,) relative to the stamp."""
        return planar_poses(*self.agent_states(index, times))


__all__ = ["Sweep"]
