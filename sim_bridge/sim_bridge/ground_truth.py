"""Exact per-point scene flow for scan t (FlowNet3D / Argoverse 2 convention, ego motion included).

A point is taken at its own `time` (s relative to the stamp, 0 for an instant sweep), in the sensor frame of that
moment. Its flow goes to where the same surface point is one period later, in the sensor frame of that moment: the
same time in the next sweep, when the sensor fires the same column again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_bridge.sweep import Sweep
from ssf_common.geometry.se3 import relative_pose

MOVING_THRESHOLD = 1e-4


@dataclass(frozen=True)
class FlowTruth:
    """Ground truth for the points of scan t: pc_t + flow lies on the surfaces seen at t+1."""

    flow: np.ndarray  # (N, 3) float32, sensor frame of scan t+1 at each point's time, minus the point
    dynamic: np.ndarray  # (N,) bool, point on an agent that moved between its time and one period later


def scene_flow(points: np.ndarray, instance: np.ndarray, time: np.ndarray, sweep: Sweep, following: Sweep) -> FlowTruth:
    """Flow of the points of a sweep: static p -> T(t).p - p with T(t) the sensor's motion over one period from the
    point's time t; a point on agent k also carries k's rigid motion over that period.

    instance holds agent index + 1 (0 = static); time is each point's, s relative to its sweep's stamp."""
    p = points.astype(np.float64)
    times, slot_of_time = _firing_times(np.asarray(time, np.float32))
    sensor_t, sensor_next = sweep.sensor_poses(times), following.sensor_poses(times)
    to_next = relative_pose(sensor_t, sensor_next)  # (T, 4, 4) sensor at t -> sensor one period later
    if len(times) == 1:  # einsum, not @: BLAS threads stall after Open3D
        flow = np.einsum("ij,kj->ik", p, to_next[0, :3, :3]) + to_next[0, :3, 3] - p
    else:
        flow = _apply_each(to_next, slot_of_time, p) - p
    dynamic = np.zeros(len(p), bool)
    on_agent = np.flatnonzero(instance > 0)
    if len(on_agent):
        key = (instance[on_agent].astype(np.int64) - 1) * len(times) + slot_of_time[on_agent]
        used, slot = np.unique(key, return_inverse=True)  # one (agent, time) per row
        agent, at = used // len(times), used % len(times)
        motion = following.agent_poses(agent, times[at]) @ np.linalg.inv(sweep.agent_poses(agent, times[at]))
        sensor_motion = np.linalg.inv(sensor_next[at]) @ motion @ sensor_t[at]  # sensor_t -> sensor_{t+1}, per row
        q = p[on_agent]
        moved_points = np.einsum("nij,nj->ni", sensor_motion[slot, :3, :3], q) + sensor_motion[slot, :3, 3]
        flow[on_agent] = moved_points - q
        moved = np.abs(motion - np.eye(4)).max(axis=(1, 2)) > MOVING_THRESHOLD
        dynamic[on_agent] = moved[slot]
    return FlowTruth(flow.astype(np.float32), dynamic)


def _firing_times(time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct times (T,) float64 of a sweep's points (a column's share one) and each point's slot among them."""
    if not len(time) or time.min() == time.max():  # an instant sweep: no sort
        return time[:1].astype(np.float64) if len(time) else np.zeros(1), np.zeros(len(time), np.int64)
    times, slot = np.unique(time, return_inverse=True)
    return times.astype(np.float64), slot


def _apply_each(transforms: np.ndarray, slot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """transforms[slot[n]] applied to points[n] (N, 3): the 12 entries gathered as contiguous rows (several times faster
    than an (N, 3, 3) gather and einsum)."""
    entries = np.take(transforms[:, :3, :].reshape(len(transforms), 12).T, slot, axis=1)  # (12, N)
    x, y, z = points.T.copy()
    out = np.empty_like(points)
    for axis in range(3):
        row = entries[4 * axis : 4 * axis + 4]
        out[:, axis] = row[0] * x + row[1] * y + row[2] * z + row[3]
    return out
