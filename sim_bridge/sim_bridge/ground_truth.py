"""Exact per-point scene flow for scan t (FlowNet3D / Argoverse 2 convention, ego motion included)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ssf_common.geometry.se3 import relative_pose

MOVING_THRESHOLD = 1e-4


@dataclass(frozen=True)
class FlowTruth:
    """Ground truth for the points of scan t: pc_t + flow lies on the surfaces seen at t+1."""

    flow: np.ndarray  # (N, 3) float32, sensor frame of scan t
    dynamic: np.ndarray  # (N,) bool, point on an agent that moved between t and t+1


def scene_flow(
    points: np.ndarray,
    instance: np.ndarray,
    pose_t: np.ndarray,
    pose_next: np.ndarray,
    agent_poses_t: np.ndarray,
    agent_poses_next: np.ndarray,
) -> FlowTruth:
    """Flow of scan-t points: static p -> T.p - p; a point on agent k also carries k's rigid motion.

    instance holds agent index + 1 (0 = static); agent poses are world <- agent (M, 4, 4) at t and t+1.
    """
    p = points.astype(np.float64)
    to_next = relative_pose(pose_t, pose_next)
    flow = np.einsum("ij,kj->ik", p, to_next[:3, :3]) + to_next[:3, 3] - p  # einsum: BLAS threads stall after Open3D
    dynamic = np.zeros(len(p), bool)
    on_agent = np.flatnonzero(instance > 0)
    if len(on_agent):
        agent = instance[on_agent] - 1
        used = np.unique(agent)
        motion = agent_poses_next[used] @ np.linalg.inv(agent_poses_t[used])  # world_t -> world_{t+1}
        sensor_motion = np.linalg.inv(pose_next) @ motion @ pose_t  # sensor_t -> sensor_{t+1}, per agent
        slot = np.searchsorted(used, agent)
        q = p[on_agent]
        moved_points = np.einsum("nij,nj->ni", sensor_motion[slot, :3, :3], q) + sensor_motion[slot, :3, 3]
        flow[on_agent] = moved_points - q
        moved = np.abs(motion - np.eye(4)).max(axis=(1, 2)) > MOVING_THRESHOLD
        dynamic[on_agent] = moved[slot]
    return FlowTruth(flow.astype(np.float32), dynamic)
