"""Scans of a simulated drive for odometry: whole scans in their sensor frame, true poses, which points move, the
agents around (for the map-trail figure) and the vehicle's own measured motion, streamed frame by frame."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sim_bridge.dataset.export import simulate, warmup_frames
from sim_bridge.ros_messages import agent_obstacles
from sim_bridge.scenario import Scenario, load_scenario
from sim_bridge.simulator import Frame
from ssf_common.geometry.se3 import invert
from ssf_common.records import Obstacles

NEAR_AGENTS = 90.0  # m: agents farther from the ego cannot reach its local map


@dataclass(frozen=True)
class SimScan:
    """Scan t with what the evaluation knows about it: points, true pose, moving points, agents nearby."""

    index: int
    stamp_ns: int
    points: np.ndarray  # (N, 3) float32, sensor frame
    next_points: np.ndarray  # (M, 3) float32, scan t+1 (what the flow points towards)
    dynamic: np.ndarray  # (N,) bool: on an agent that moves between t and t+1
    instance: np.ndarray  # (N,) int32 agent id, 0 static
    pose: np.ndarray  # (4, 4) world <- sensor
    agents: Obstacles  # agents near the ego, world frame
    measured_motion: np.ndarray | None = None  # (4, 4) last scan's sensor frame <- this one's, by the odometer
    time: np.ndarray | None = None  # (N,) float32 each point's time, s relative to the stamp (all 0: an instant sweep)
    next_time: np.ndarray | None = None  # (M,) the same for scan t+1
    next_measured: np.ndarray | None = None  # (4, 4) the sensor's motion over scan t+1's sweep by the odometer, as the
    # flow deskews with it (points of scan t's frame into scan t+1's)


def scenario_of(name: str, agents: int | None = None, overrides: dict | None = None) -> Scenario:
    """A shipped scenario (or YAML file), optionally with another agent count and other dotted settings."""
    changes = {**(overrides or {}), **({"agents.count": agents} if agents is not None else {})}
    return load_scenario(name, changes or None)


def odometer_motion(frame: Frame, dt: float) -> np.ndarray | None:
    """The sensor's motion over the step that ended at `frame` (that step's sensor frame <- this one's) as the
    vehicle's odometer measured it."""
    sweep = frame.measured_sweep(frame.stamp_ns - int(round(dt * 1e9)))
    return None if sweep is None else invert(sweep)


def sim_scans(scenario: Scenario, seed: int, frames: int, warmup_s: float) -> Iterator[SimScan]:
    """`frames` consecutive scans after `warmup_s` simulated seconds, each with the next scan and its truth."""
    skip = warmup_frames(scenario, warmup_s)
    dt = scenario.episode.dt
    previous = None
    for frame in simulate(scenario, seed, frames, skip):
        if previous is not None:
            near = np.linalg.norm(previous.agents.position[:, :2] - previous.pose[:2, 3], axis=1) < NEAR_AGENTS
            yield SimScan(previous.index - skip, previous.stamp_ns, previous.scan.points, frame.scan.points,
                          frame.flow.dynamic, previous.scan.instance, previous.pose,
                          agent_obstacles(previous.agents.take(near), previous.stamp_ns), odometer_motion(previous, dt),
                          previous.scan.time, frame.scan.time, frame.measured_sweep(previous.stamp_ns))
        previous = frame
