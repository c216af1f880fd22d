"""Perception sources of the navigation benchmark, all feeding the same planner: the simulator's boxes (`gt`),
DBSCAN clusters of the scan tracked between frames (`dbscan`) or standing still (`dbscan0`), and semantic scene
flow (`ssf`: the flow <-> segmentation loop, obstacles from the moving instances). Each turns one simulator frame
into obstacles in the odometry frame; only `dbscan*` and `ssf` read the LiDAR scan. Still things (structure,
parked or queuing cars) are obstacles for every source: `dbscan*` and `ssf` cluster what they see as still, `gt`
knows every agent (moving or not; the simulator's structure stays off the road)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from pydantic import Field

from sim_bridge.ros_messages import WORLD_FRAME, agent_obstacles
from sim_bridge.world import World
from ssf_common.dataset.pairs import PointClass
from ssf_common.errors import ConfigError
from ssf_common.records import ObstacleKind, Obstacles
from ssf_eval.nav.observation import ODOM_FRAME, NavPerception, Observation
from ssf_seg_node.core.obstacles import StillClusters, StillConfig, still_clusters


class DbscanTrackerConfig(StillConfig):
    """LiDAR clustering as common stacks do it (rda_ros: DBSCAN, minimum-area rectangles), and tracking."""

    gate: float = Field(1.5, gt=0.0, description="tracking: a cluster continues the track whose predicted centre is "
                        "nearest, within this distance (m)")
    smoothing: float = Field(0.5, gt=0.0, le=1.0, description="tracking: weight of the newest velocity measurement")
    max_speed: float = Field(15.0, gt=0.0, description="tracking: faster measurements are association errors (m/s)")
    static_extent: float = Field(8.0, gt=0.0, description="clusters longer than this (m) are structure: velocity 0")


class GroundTruthPerception:
    """The simulator's agents as boxes with their exact velocities, and its parked cars (no LiDAR)."""

    name = "gt"
    reads_scan = False

    def __init__(self, max_range: float = 60.0) -> None:
        self.max_range = max_range
        self.parked = Obstacles.empty(0, WORLD_FRAME)

    def know(self, world: World) -> None:
        """Take the world's parked cars: still boxes beside the lanes, which the car must not swing into."""
        self.parked = parked_cars(world)

    def observe(self, observation: Observation) -> Obstacles:
        """Every agent and parked car within range, in the odometry frame."""
        frame = observation.frame
        agents = agent_obstacles(frame.agents, frame.stamp_ns).joined(replace(self.parked, stamp_ns=frame.stamp_ns))
        near = np.linalg.norm(agents.centres[:, :2] - frame.base_pose[:2, 3], axis=1) <= self.max_range
        return agents.take(near).transformed(observation.world_to_odom, ODOM_FRAME)


def parked_cars(world: World) -> Obstacles:
    """The world's parked cars as still vehicle boxes in the world frame (track id 0: not agents)."""
    structure = world.structure
    boxes = structure.boxes[structure.box_classes == PointClass.PARKED_CAR]
    count = len(boxes)
    ground = world.ground.height(boxes[:, 0], boxes[:, 1]) if count else np.zeros(0)
    return Obstacles(0, WORLD_FRAME, ids=np.zeros(count, np.int64), kinds=np.full(count, ObstacleKind.VEHICLE),
                     centres=np.c_[boxes[:, :2], ground + boxes[:, 5] / 2], sizes=boxes[:, 3:6], yaws=boxes[:, 2],
                     velocities=np.zeros((count, 3)))


@dataclass
class _Tracks:
    """Cluster tracks in the odometry frame: centres, velocities, ages, ids."""

    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    velocities: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    ages: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    stamp_ns: int = -1


class DbscanPerception:
    """Non-ground points -> DBSCAN clusters -> minimum-area boxes; velocity from nearest-centre tracking between
    frames (gated, smoothed), or zero for the `dbscan0` variant."""

    reads_scan = True

    def __init__(self, config: DbscanTrackerConfig, track: bool = True) -> None:
        self.config = config
        self.track = track
        self.name = "dbscan" if track else "dbscan0"
        self._tracks = _Tracks()
        self._next_id = 1

    def observe(self, observation: Observation) -> Obstacles:
        """Clusters of this scan as boxes in the odometry frame, with tracked velocities."""
        frame = observation.frame
        found = cluster_boxes(frame.scan.points, observation.lidar_pose, frame.stamp_ns, self.config)
        velocities, ids = self._velocities(found.means, found.boxes.sizes, frame.stamp_ns)
        return replace(found.boxes, ids=ids, velocities=np.c_[velocities, np.zeros(len(ids))])

    def _velocities(self, centres: np.ndarray, sizes: np.ndarray, stamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Associate clusters with the previous frame's tracks; velocities (M, 2) and track ids (M,)."""
        cfg, tracks = self.config, self._tracks
        count = len(centres)
        velocities, ids, ages = np.zeros((count, 2)), np.zeros(count, np.int64), np.zeros(count, np.int64)
        dt = (stamp_ns - tracks.stamp_ns) * 1e-9 if tracks.stamp_ns >= 0 else 0.0
        matched = match_nearest(tracks.centres + tracks.velocities * dt, centres, cfg.gate) if dt > 0 else \
            np.full(count, -1)
        for i, previous in enumerate(matched):
            if previous < 0:
                ids[i], self._next_id = self._next_id, self._next_id + 1
                continue
            ids[i], ages[i] = tracks.ids[previous], tracks.ages[previous] + 1
            measured = (centres[i] - tracks.centres[previous]) / dt
            if np.linalg.norm(measured) <= cfg.max_speed:
                velocities[i] = cfg.smoothing * measured + (1 - cfg.smoothing) * tracks.velocities[previous]
        velocities[sizes[:, 0] > cfg.static_extent] = 0.0
        self._tracks = _Tracks(centres, velocities, ages, ids, stamp_ns)
        if not self.track:
            return np.zeros((count, 2)), ids
        return np.where(ages[:, None] >= 2, velocities, 0.0), ids


def cluster_boxes(points: np.ndarray, lidar_pose: np.ndarray, stamp_ns: int,
                  config: DbscanTrackerConfig) -> StillClusters:
    """The DBSCAN clusters of a scan's points (sensor frame) above the ground, as boxes in the odometry frame."""
    return still_clusters(points, stamp_ns, ODOM_FRAME, config, lidar_pose)


def match_nearest(predicted: np.ndarray, centres: np.ndarray, gate: float) -> np.ndarray:
    """For each centre the index of the predicted track it continues (-1: new), nearest pairs first, one-to-one."""
    matched = np.full(len(centres), -1)
    if not len(predicted) or not len(centres):
        return matched
    distance = np.linalg.norm(centres[:, None, :] - predicted[None, :, :], axis=2)
    used = np.zeros(len(predicted), bool)
    for flat in np.argsort(distance, axis=None):
        i, j = divmod(int(flat), len(predicted))
        if distance[i, j] > gate:
            break
        if matched[i] < 0 and not used[j]:
            matched[i], used[j] = j, True
    return matched


def make_perception(name: str, **settings) -> NavPerception:
    """The perception source called `name` (gt | dbscan | dbscan0 | ssf)."""
    if name == "gt":
        return GroundTruthPerception()
    if name in ("dbscan", "dbscan0"):
        return DbscanPerception(settings.get("dbscan", DbscanTrackerConfig()), track=name == "dbscan")
    if name == "ssf":
        from ssf_eval.nav.ssf_source import SsfPerception

        return SsfPerception(settings.get("ssf"), scans=settings.get("scans"))
    raise ConfigError(f"unknown perception '{name}'; choose one of gt, dbscan, dbscan0, ssf (or follower)")
