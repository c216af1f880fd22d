"""The agents as the rest of the simulator sees them: kinds, a snapshot of their states, the ego's footprint as
they avoid it, and the triangles the LiDAR hits."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from sim_bridge.meshes import BOX, CYLINDER, TriangleSoup, instances
from ssf_common.dataset.pairs import PointClass


class AgentKind(IntEnum):
    """Agent kind, numbered like ssf_interfaces/Obstacle KIND_*."""

    VEHICLE = 1
    PEDESTRIAN = 2


@dataclass(frozen=True)
class AgentStates:
    """Every agent at one instant; positions are footprint centres on the ground, world frame."""

    ids: np.ndarray  # (N,) int32 instance ids, 1..N
    kind: np.ndarray  # (N,) uint8 AgentKind
    position: np.ndarray  # (N, 3)
    yaw: np.ndarray  # (N,)
    velocity: np.ndarray  # (N, 2) world frame, m/s
    yaw_rate: np.ndarray  # (N,) rad/s
    size: np.ndarray  # (N, 3) length, width, height (pedestrians: diameter, diameter, height)

    def __len__(self) -> int:
        return len(self.ids)

    def take(self, mask: np.ndarray) -> AgentStates:
        """The agents selected by a boolean mask or index array."""
        return AgentStates(
            self.ids[mask],
            self.kind[mask],
            self.position[mask],
            self.yaw[mask],
            self.velocity[mask],
            self.yaw_rate[mask],
            self.size[mask],
        )

    def poses(self) -> np.ndarray:
        """World <- agent transforms (N, 4, 4)."""
        return planar_poses(self.position, self.yaw)

    @staticmethod
    def empty() -> AgentStates:
        """No agents."""
        return AgentStates(np.zeros(0, np.int32), np.zeros(0, np.uint8), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2)),
                           np.zeros(0), np.zeros((0, 3)))


def planar_poses(position: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """World <- agent transforms (N, 4, 4) of agents at positions (N, 3) turned by yaw (N,) about z."""
    poses = np.tile(np.eye(4), (len(yaw), 1, 1))
    cos, sin = np.cos(yaw), np.sin(yaw)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = cos, -sin, sin, cos
    poses[:, :3, 3] = position
    return poses


def template_scales(states: AgentStates) -> np.ndarray:
    """(N, 3) scale of each agent's template: a vehicle's box is its size, a pedestrian's unit cylinder gets the
    radius half its diameter."""
    people = states.kind == AgentKind.PEDESTRIAN
    return np.where(people[:, None], np.c_[states.size[:, :1] / 2, states.size[:, :1] / 2, states.size[:, 2]],
                    states.size)


@dataclass(frozen=True)
class EgoFootprint:
    """The ego vehicle as the agents see it: a rectangle and its velocity."""

    centre: np.ndarray  # (2,)
    yaw: float
    length: float
    width: float
    velocity: np.ndarray  # (2,)


def agent_mesh(states: AgentStates, centre: np.ndarray, radius: float):
    """Triangles of every agent within radius of centre (x, y); owners are agent indices."""
    near = np.linalg.norm(states.position[:, :2] - centre, axis=1) <= radius + 3.0
    vehicles = np.flatnonzero(near & (states.kind == AgentKind.VEHICLE))
    people = np.flatnonzero(near & (states.kind == AgentKind.PEDESTRIAN))
    scales = template_scales(states)
    return TriangleSoup.merge(
        [
            instances(
                BOX, scales[vehicles], states.yaw[vehicles], states.position[vehicles], PointClass.VEHICLE, vehicles
            ),
            instances(
                CYLINDER, scales[people], states.yaw[people], states.position[people], PointClass.PEDESTRIAN, people
            ),
        ]
    )
