"""The odometry evaluation: every method on the very same scans, streamed frame by frame (flow and segmentation
computed once per scan and shared), KISS-ICP beside them, map trails sampled along the way."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

from ssf_common.dataset.masks import noisy_mask
from ssf_common.dataset.pairs import make_pair
from ssf_common.geometry.sampling import voxel_indices
from ssf_common.geometry.se3 import invert, transform_points
from ssf_common.geometry.sweep import pair_times, timed
from ssf_eval.odom.metrics import OdomScores, score
from ssf_eval.odom.sequence import SimScan
from ssf_common.records import Obstacles
from ssf_eval.odom.trails import MapPlacement, SweptPaths, left_behind, world_from_odometry
from ssf_odom_node.core.odometry import OdomConfig, OdomInput, make_odometry

KISS_ICP = "kiss-icp"
SSF_TWIST = "ssf+twist"  # ssf with the vehicle's measured motion (wheel speed, yaw-rate gyro): the paper's "+ IMU" row
METHODS = ("points", "flow", "ssf", SSF_TWIST)


class OdomMaskSource(str, Enum):
    """Where the static mask comes from: the segmentation (fusion loop), or ground-truth stand-ins for ablations."""

    SEG = "seg"
    GT = "gt"
    AGENTS = "agents"  # every point on an agent, moving or standing: a map of the world without any traffic in it
    NOISY = "noisy"


@dataclass(frozen=True)
class Perceived:
    """What perception hands the odometry for one scan."""

    flow_plain: np.ndarray | None  # flow without any mask (the 'flow' variant: no segmentation); None when not asked
    flow: np.ndarray  # flow with the static mask (ssf)
    dynamic_prob: np.ndarray  # (N,) probability that each point moves
    ms: float
    ego: np.ndarray | None = None  # (4, 4) the flow estimator's ego motion of the masked flow (None: not known)


class OdomPerception:
    """Scene flow from the project's estimator on whole scans and the static mask from the chosen source.

    With masks from the segmentation, the flow without a mask comes from an estimator of its own (`plain`), so that
    the loop's estimator carries from pair to pair exactly what the graph's flow node does."""

    def __init__(self, masks: OdomMaskSource, estimator, pipeline=None, seed: int = 0, plain=None,
                 period: float = 0.1) -> None:
        self.masks = OdomMaskSource(masks)
        self.period = period  # s between scans: the span of a sweep that takes its period to turn
        self.estimator = estimator
        self.pipeline = pipeline  # ssf_eval.pipeline.PerceptionChain, for masks from the segmentation
        self.plain = plain  # estimator of the maskless flow; None: the 'flow' variant is not asked for
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """A new sequence starts: no segmentation to carry over."""
        if self.pipeline is not None:
            self.pipeline.reset()

    def __call__(self, scan: SimScan) -> Perceived:
        """Flow (without and with the mask) and the dynamic probability of every point of the scan."""
        started = time.perf_counter()
        measured = self.pipeline is None or self.pipeline.config.measured_motion
        sweeps = pair_times(scan.time, scan.next_time, self.period, scan.next_measured if measured else None)
        timed = {} if sweeps is None else {"sweeps": sweeps}
        plain = None if self.plain is None else self.plain.estimate(scan.points, scan.next_points, **timed).flow
        if self.masks is OdomMaskSource.SEG:
            result = self.pipeline.perceive(scan.points, scan.next_points, follows=True, time1=scan.time,
                                            time2=scan.next_time, measured=scan.next_measured).fusion  # consecutive
            return Perceived(plain, result.flow, result.segmentation.dynamic_prob, (time.perf_counter() - started) * 1e3,
                             result.ego)
        if self.masks is OdomMaskSource.GT:
            mask = scan.dynamic.astype(np.float32)
        elif self.masks is OdomMaskSource.AGENTS:
            mask = (scan.instance > 0).astype(np.float32)
        else:
            pair = make_pair(scan.points, scan.next_points, np.zeros_like(scan.points), scan.dynamic, scan.instance)
            mask = noisy_mask(pair, self.rng)
        masked = self.estimator.estimate(scan.points, scan.next_points, mask, **timed)  # last: the stream carries its motions
        return Perceived(plain, masked.flow, mask, (time.perf_counter() - started) * 1e3, masked.ego)


class KissIcpBaseline:
    """KISS-ICP (PyPI kiss-icp) on whole scans: the external baseline, never our method."""

    name = KISS_ICP

    def __init__(self, max_range: float = 100.0, voxel: float | None = None, threads: int = 1,
                 deskew: bool = True) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP

        config = KISSConfig()
        config.data.max_range = max_range
        config.data.deskew = deskew  # its own, on scans whose points carry time (constant velocity, to the sweep's end)
        config.mapping.voxel_size = voxel or max_range / 100.0  # KISS-ICP's own default rule
        config.registration.max_num_threads = threads
        self.odometry = KissICP(config)

    def step(self, points: np.ndarray, time: np.ndarray | None = None) -> np.ndarray:
        """Register one scan (`time`: each point's, where the sweep took its period to turn); its pose (first scan's
        frame <- this scan)."""
        stamps = np.asarray(time, dtype=np.float64) if timed(time) else np.zeros(0)
        self.odometry.register_frame(np.asarray(points, dtype=np.float64), stamps)
        return self.odometry.last_pose.copy()

    def map_points(self) -> np.ndarray:
        """The local map (odometry frame)."""
        return np.asarray(self.odometry.local_map.point_cloud())


@dataclass
class MethodRun:
    """One method's trajectory, time per scan and map-trail samples."""

    name: str
    poses: list[np.ndarray] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)
    trail_voxels: int = 0  # map voxels on agents' paths (agents standing there now included)
    left_voxels: int = 0  # of those, the voxels where no agent stands at the sample's moment (left behind)
    map_voxels: int = 0
    last_map: np.ndarray | None = None  # (V, 3) world frame, at the last trail sample
    last_trails: np.ndarray | None = None  # (V,) bool

    @property
    def trail_share(self) -> float:
        """Share of map voxels on agents' paths, pooled over the samples."""
        return self.trail_voxels / self.map_voxels if self.map_voxels else float("nan")

    @property
    def left_share(self) -> float:
        """Share of map voxels on agents' paths where no agent stands at the sample's moment, pooled."""
        return self.left_voxels / self.map_voxels if self.map_voxels else float("nan")


@dataclass
class SequenceResult:
    """Every method's run over one sequence, the true poses and what perception cost."""

    truth: list[np.ndarray] = field(default_factory=list)
    stamps_s: list[float] = field(default_factory=list)
    runs: dict[str, MethodRun] = field(default_factory=dict)
    static_world: MethodRun = field(default_factory=lambda: MethodRun("static world"))  # the trails' floor
    perception_ms: list[float] = field(default_factory=list)
    scores: dict[str, OdomScores] = field(default_factory=dict)

    def finish(self) -> SequenceResult:
        """Score every run against the truth (poses relative to the first scan)."""
        truth = np.stack(self.truth)
        truth = invert(truth[0]) @ truth
        stamps = np.asarray(self.stamps_s)
        self.scores = {name: score(truth, np.stack(run.poses), stamps) for name, run in self.runs.items()}
        return self


def write_trajectories(result: SequenceResult, folder: Path, title: str) -> list[Path]:
    """Every method's poses and the truth (first scan's frame) as TUM files: FOLDER/TITLE_METHOD_tum.txt."""
    from ssf_common.dataset.kitti import write_tum

    folder.mkdir(parents=True, exist_ok=True)
    truth = np.stack(result.truth)
    stamps = np.asarray(result.stamps_s)
    trajectories = {"truth": invert(truth[0]) @ truth, **{name: np.stack(run.poses) for name, run in result.runs.items()}}
    written = []
    for name, poses in trajectories.items():
        path = folder / f"{title}_{name}_tum.txt"
        write_tum(path, stamps, poses)
        written.append(path)
    return written


def run_sequence(scans: Iterable[SimScan], methods: list[str], perception: OdomPerception | None, config: OdomConfig,
                 map_voxel: float, trail_every: int = 10, progress: Callable[[int], None] | None = None) -> SequenceResult:
    """Step every method through the scans; sample each map's trails every `trail_every` scans."""
    odometries = {name: make_odometry("ssf" if name == SSF_TWIST else name, config) for name in methods
                  if name != KISS_ICP}
    kiss = KissIcpBaseline(deskew=config.deskew) if KISS_ICP in methods else None
    result = SequenceResult(runs={name: MethodRun(name) for name in methods})
    paths = SweptPaths()
    placements = {name: MapPlacement() for name in methods}
    if perception is not None:
        perception.reset()
    for count, scan in enumerate(scans, 1):
        result.truth.append(scan.pose)
        result.stamps_s.append(scan.stamp_ns * 1e-9)
        paths.add(scan.agents)
        perceived = perception(scan) if perception is not None and set(methods) & {"flow", "ssf", SSF_TWIST} else None
        if perceived is not None:
            result.perception_ms.append(perceived.ms)
        for name, odometry in odometries.items():
            frame = OdomInput(scan.stamp_ns, scan.points, time=scan.time)
            if perceived is not None and name == "flow":
                frame = OdomInput(scan.stamp_ns, scan.points, perceived.flow_plain, time=scan.time)
            elif perceived is not None and name == "ssf":
                frame = OdomInput(scan.stamp_ns, scan.points, perceived.flow, perceived.dynamic_prob, ego=perceived.ego,
                                  time=scan.time)
            elif perceived is not None and name == SSF_TWIST:
                frame = OdomInput(scan.stamp_ns, scan.points, perceived.flow, perceived.dynamic_prob,
                                  measured_motion=scan.measured_motion, ego=perceived.ego, time=scan.time)
            started = time.perf_counter()
            step = odometry.step(frame)
            result.runs[name].ms.append((time.perf_counter() - started) * 1e3)
            result.runs[name].poses.append(step.pose)
        if kiss is not None:
            started = time.perf_counter()
            result.runs[KISS_ICP].poses.append(kiss.step(scan.points, scan.time))
            result.runs[KISS_ICP].ms.append((time.perf_counter() - started) * 1e3)
        if count % trail_every == 0:
            world = static_world(scan, config.ssf_range)
            sample_trails(result.static_world, transform_points(scan.pose, world[voxel_indices(world, map_voxel)]),
                          paths, scan.agents)
            for name, run in result.runs.items():
                odom_map = np.asarray(kiss.map_points() if name == KISS_ICP else odometries[name].map.points)
                placed = placements[name].place(odom_map, world_from_odometry(scan.pose, run.poses[-1]))
                sample_trails(run, placed[voxel_indices(odom_map, map_voxel)], paths, scan.agents)
        if progress is not None:
            progress(count)
    return result.finish()


def static_world(scan: SimScan, reach: float) -> np.ndarray:
    """The scan's points the simulator knows to be static, within `reach` (m) of the sensor: what a perfect static map
    holds there; its share on agents' paths is the floor of the trail figures (agents standing still are static)."""
    points = np.asarray(scan.points, dtype=np.float64)
    keep = ~np.asarray(scan.dynamic, bool) & (np.linalg.norm(points[:, :2], axis=1) <= reach)
    return points[keep]


def sample_trails(run: MethodRun, world: np.ndarray, paths: SweptPaths, agents: Obstacles | None = None) -> None:
    """Count a map's voxels (one world point each), those on agents' paths and those of them where none of `agents`
    (this moment) stands."""
    world = np.asarray(world, dtype=np.float64)
    if len(world) == 0:
        return
    trails, left = left_behind(world, paths, agents if agents is not None else Obstacles.empty())
    run.trail_voxels += int(trails.sum())
    run.left_voxels += int(left.sum())
    run.map_voxels += len(world)
    run.last_map, run.last_trails = world, trails
