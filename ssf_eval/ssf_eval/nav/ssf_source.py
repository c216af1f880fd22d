"""The `ssf` perception source and the `ssf` pose source of the navigation loop, on one run of the SSF chain per
scan (`ssf_eval.pipeline`, what the graph's nodes run): semantic scene flow from the previous whole scan towards this
one, its obstacles (every moving instance with its velocity, the still part clustered into still boxes) and the pose
from the SSF odometry core with the flow's ego motion, as the graph's odometry node gives it."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from ssf_common.config import build
from ssf_common.geometry.se3 import invert
from ssf_common.records import Obstacles
from ssf_eval.nav.observation import ODOM_FRAME, Observation
from ssf_eval.pipeline import PerceptionChain, PerceptionConfig, ScanPerception
from ssf_flow_node.core.estimator import WHOLE_SCAN
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry
from ssf_odom_node.core.vehicle import command_prior, speed_ahead


def whole_scan_config(loop_iterations: int | None = None) -> PerceptionConfig:
    """The pipeline as the graph's nodes run it on whole scans (`loop_iterations`: the fusion loop's N_iter, else its
    default)."""
    loop = {} if loop_iterations is None else {"fusion": {"max_iterations": loop_iterations}}
    return build(PerceptionConfig, {"flow": WHOLE_SCAN, **loop}, source="ssf perception")


class PerceivedPair(NamedTuple):
    """Semantic scene flow of the previous scan (its stamp and points) towards the newest one."""

    stamp_ns: int
    points: np.ndarray  # (N, 3) the previous scan, sensor frame
    seen: ScanPerception
    time: np.ndarray | None = None  # (N,) each point's time, s relative to its stamp (None: an instant sweep)


class ConsecutiveScans:
    """The SSF pipeline over consecutive scans, run once per scan however many consumers ask; with `every` > 1 only on
    every n-th scan (the previous scan towards it), as a busy graph answers the newest pair and drops the others."""

    def __init__(self, config: PerceptionConfig | None = None, device: str = "cpu", every: int = 1) -> None:
        self.pipeline = PerceptionChain(config or whole_scan_config(), device)
        self.every = every
        self._added = 0  # scans added so far
        self._newest: tuple[int, np.ndarray, np.ndarray | None] | None = None
        self._pair: PerceivedPair | None = None
        self.iterations: list[int] = []

    @property
    def latest(self) -> PerceivedPair | None:
        """The pair perceived for the newest scan (None before the second scan)."""
        return self._pair

    def add(self, stamp_ns: int, points: np.ndarray, time: np.ndarray | None = None,
            measured_since: Callable[[int], np.ndarray | None] | None = None) -> PerceivedPair | None:
        """The previous scan perceived towards this one (None for the first scan); a scan added twice runs once.
        time: each point's (s relative to the stamp), where the sweep took its period to turn; measured_since: the
        sensor's measured motion from a stamp to this scan (`Frame.measured_sweep`), which deskews it."""
        if self._newest is not None and self._newest[0] == stamp_ns:
            return self._pair
        previous, self._newest = self._newest, (stamp_ns, np.ascontiguousarray(points[:, :3], dtype=np.float32), time)
        index, self._added = self._added, self._added + 1
        if previous is None or index % self.every:  # the first scan, or one a busy graph drops
            self._pair = None
            return None
        measured = None if measured_since is None else measured_since(previous[0])
        seen = self.pipeline.perceive(previous[1], self._newest[1], stamp_ns=previous[0], frame_id="lidar", follows=True,
                                      next_stamp_ns=stamp_ns, time1=previous[2], time2=time, measured=measured)
        self.iterations.append(seen.fusion.iterations)
        self._pair = PerceivedPair(previous[0], previous[1], seen, previous[2])
        return self._pair


class SsfPerception:
    """Semantic scene flow between the previous scan and this one; its obstacles, moving and still."""

    name = "ssf"
    reads_scan = True

    def __init__(self, config: PerceptionConfig | None = None, device: str = "cpu",
                 scans: ConsecutiveScans | None = None) -> None:
        self.scans = scans or ConsecutiveScans(config, device)
        self._previous_pose: np.ndarray | None = None  # odom <- lidar of the previous scan

    @property
    def iterations(self) -> list[int]:
        """Fusion-loop iterations per perceived pair."""
        return self.scans.iterations

    def observe(self, observation: Observation) -> Obstacles:
        """Obstacles of the previous scan (stamped then), from its flow towards this scan."""
        frame = observation.frame
        pair = self.scans.add(frame.stamp_ns, frame.scan.points, frame.scan.time, frame.measured_sweep)
        pose1, self._previous_pose = self._previous_pose, observation.lidar_pose
        if pair is None or pose1 is None:
            return Obstacles.empty(frame.stamp_ns, ODOM_FRAME)
        return pair.seen.obstacles.transformed(pose1, ODOM_FRAME)


class SsfPose:
    """The ego pose from SSF odometry: each scan's odometry once the next scan gave it its semantic flow (as the odometry
    node publishes it, one scan late), carried to the newest scan by that flow's motion; scans without an answer (a
    busy graph's) move it on by the last motion, at constant velocity. Like the node, the odometry takes the motion the
    commands sent drove as its prior across skipped scans."""

    def __init__(self, mount: np.ndarray, scans: ConsecutiveScans, config: OdomConfig | None = None,
                 limits: tuple[float, float] = (3.0, 6.0)) -> None:
        self.mount = mount  # base_link <- lidar
        self.scans = scans
        self.odometry = make_odometry("ssf", config)
        self.limits = limits  # the vehicle's acceleration and deceleration (m/s^2) for the commands' motion
        self.lidar_pose = mount.copy()  # odom <- lidar of the newest scan; odom is the first scan's base_link
        self.speed = 0.0  # forward speed (m/s) at the newest answered scan: its flow's motion ahead (else the twist)
        self.motion = np.eye(4)  # lidar(previous scan) <- lidar(this scan) over the last period

    def update(self, stamp_ns: int, points: np.ndarray, commands: Sequence[tuple[int, Any]] = (),
               time: np.ndarray | None = None,
               measured_since: Callable[[int], np.ndarray | None] | None = None) -> np.ndarray:
        """odom <- lidar at this scan: the previous scan's odometry pose carried forward by its flow; `commands`
        (stamp, command with linear and angular) are those sent so far; `time` each point's (None: an instant sweep);
        measured_since as `ConsecutiveScans.add` takes it."""
        pair = self.scans.add(stamp_ns, points, time, measured_since)
        if pair is None:
            if self.odometry.steps:  # no answer for this scan: on by the last period's motion
                self.lidar_pose = self.lidar_pose @ self.motion
            return self.lidar_pose
        fusion = pair.seen.fusion
        prior = command_prior([(stamp, command.linear, command.angular) for stamp, command in commands],
                              self.odometry.stamp_ns, pair.stamp_ns, self.speed, self.limits, self.mount)
        step = self.odometry.step(OdomInput(pair.stamp_ns, pair.points, fusion.flow, fusion.segmentation.dynamic_prob,
                                            prior, ego=fusion.ego, time=pair.time))
        ahead = np.eye(4) if step.next_motion is None else invert(step.next_motion)
        self.motion = ahead
        self.lidar_pose = self.mount @ step.pose @ ahead
        self.speed = speed_ahead(step, self.odometry.config.scan_period, self.mount, without_flow=float(step.twist[0]))
        return self.lidar_pose

    @property
    def base_pose(self) -> np.ndarray:
        """odom <- base_link of the newest scan."""
        return self.lidar_pose @ invert(self.mount)
