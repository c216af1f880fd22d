"""Obstacles of a scan: an oriented box per moving instance with its velocity from the flow and how sure it is, and
the still part of the scan as boxes standing still (what a planner must not drive into: parked cars, structure)."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.boxes import bounding_boxes
from ssf_common.geometry.clustering import dbscan
from ssf_common.geometry.fitting import weighted_kabsch
from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.labels import label_counts, label_means
from ssf_common.geometry.reductions import column_bounds
from ssf_common.geometry.sampling import voxel_indices
from ssf_common.geometry.se3 import invert, transform_points
from ssf_common.records import ObstacleKind, Obstacles, Segmentation, SemanticFlow


class StillConfig(Section):
    """The still part of a scan as obstacles: DBSCAN clusters of its points above the ground, as minimum-area boxes
    with no velocity (what common LiDAR stacks give a planner, rda_ros style)."""

    enabled: bool = Field(True, description="the fusion node publishes still boxes beside the moving obstacles")
    max_range: float = Field(40.0, gt=0.0, description="points farther from the sensor are ignored (m)")
    cell: float = Field(0.2, gt=0.0, description="one point per ground-plane cell of this edge (m) before clustering")
    ground_cell: float = Field(2.0, gt=0.0, description="grid cell of the ground height estimate (m)")
    min_height: float = Field(0.3, ge=0.0, description="points lower above the ground are ground (m)")
    max_height: float = Field(2.5, gt=0.0, description="points higher above the ground are ignored: canopy, roofs (m)")
    eps: float = Field(0.5, gt=0.0, description="DBSCAN neighbourhood on the ground plane (m)")
    min_samples: int = Field(5, ge=1, description="DBSCAN core point threshold")
    min_points: int = Field(5, ge=1, description="smaller clusters are dropped")
    vehicle_length: float = Field(2.2, gt=0.0, description="boxes at least this long are vehicles, else pedestrians")


class ObstacleConfig(Section):
    """How dynamic instances become obstacles."""

    min_points: int = Field(5, ge=1, description="instances with fewer points are not reported")
    vehicle_length: float = Field(1.2, gt=0.0, description="footprints with a side at least this long (m) are vehicles, "
                                  "else pedestrians (a car seen end-on shows only its width)")
    heading_speed: float = Field(0.5, ge=0.0, description="an object at least this fast (m/s), and clearly moving (see "
                                 "heading_significance), has its heading along its velocity: a vehicle its length along "
                                 "the side of its fitted footprint closest to its velocity (which needs the velocity's "
                                 "direction within 45 degrees: the flow's velocity errors are a few tenths of a m/s)")
    heading_significance: float = Field(3.0, ge=0.0, description="clearly moving: the speed is at least this many "
                                        "standard deviations of the velocity along its direction (from its covariance)")
    fit_step: float = Field(1.0, gt=0.0, le=45.0, description="angle step (degrees) of the footprint fit's search")
    fit_closeness: float = Field(0.05, gt=0.0, description="the footprint fit counts points this close (m) to a side as "
                                 "on it (the floor of the closeness criterion: the points' noise)")
    fit_points: int = Field(256, ge=8, description="the footprint fit looks at most at this many points of an object, "
                            "evenly spread over its points")
    vehicle_size: tuple[float, float] = Field((4.4, 1.8), description="a vehicle's footprint is grown to at least this "
                                              "(length, width; m), away from the sensor (its hidden sides)")
    pedestrian_size: tuple[float, float] = Field((0.6, 0.6), description="the same for pedestrians")
    velocity_noise: float = Field(0.05, ge=0.0, description="floor of the velocity standard deviation (m/s)")
    still: StillConfig = StillConfig()


class SceneObstacles(NamedTuple):
    """Every obstacle of one scan: the moving objects with their velocities, and the still part as boxes."""

    moving: Obstacles
    still: Obstacles

    def all(self) -> Obstacles:
        """Both, the moving ones first (what /ssf/obstacles carries)."""
        return stack(self.moving, self.still)


def scan_obstacles(points: np.ndarray, flow: np.ndarray, segmentation: Segmentation, ego: np.ndarray, dt: float,
                   stamp_ns: int, frame_id: str, config: ObstacleConfig) -> SceneObstacles:
    """The obstacles of scan t in its sensor frame: a box with a velocity per moving instance, and (config.still.enabled)
    the clusters of its still points as boxes standing still (what stands still is in the way too: parked cars,
    structure)."""
    moving = extract_obstacles(points, flow, segmentation, ego, dt, stamp_ns, frame_id, config)
    if not config.still.enabled:
        return SceneObstacles(moving, Obstacles.empty(stamp_ns, frame_id))
    still = np.asarray(points)[~segmentation.dynamic]
    return SceneObstacles(moving, still_clusters(still, stamp_ns, frame_id, config.still).boxes)


def result_obstacles(result: SemanticFlow, config: ObstacleConfig, fallback_dt: float) -> SceneObstacles:
    """The obstacles of a scan the fusion loop finished: moved by the flow estimator's ego motion that came with it,
    or, where none came (a flow from elsewhere), by one fitted to its static flow over `fallback_dt`."""
    if result.ego is None:
        ego = weighted_kabsch(result.points, result.points + result.flow, 1.0 - result.segmentation.dynamic_prob)
        dt = fallback_dt
    else:
        ego, dt = result.ego.transform, result.ego.dt
    return scan_obstacles(result.points, result.flow, result.segmentation, ego, dt, result.stamp_ns, result.frame_id,
                          config)


def extract_obstacles(points: np.ndarray, flow: np.ndarray, segmentation: Segmentation, ego: np.ndarray, dt: float,
                      stamp_ns: int, frame_id: str, config: ObstacleConfig) -> Obstacles:
    """Obstacles of scan t in its sensor frame: boxes at time t, velocities of the objects themselves (ego removed)."""
    instance = np.asarray(segmentation.instance)
    moving = np.flatnonzero(instance > 0)
    moving = moving[np.argsort(instance[moving], kind="stable")]  # the points of each instance together
    instances, starts, counts = np.unique(instance[moving], return_index=True, return_counts=True)
    members = [moving[start:start + count] for start, count in zip(starts, counts) if count >= config.min_points]
    if not members:
        return Obstacles.empty(stamp_ns, frame_id)
    instances, counts = instances[counts >= config.min_points], counts[counts >= config.min_points]
    kept = np.concatenate(members)
    points, flow = np.asarray(points, np.float64)[kept], np.asarray(flow, np.float64)[kept]
    # the object's own displacement in scan t's axes: where it is at t+1, seen from the sensor pose at t, minus where
    # it was (the flow alone also carries the ego motion)
    back = invert(ego)
    own = (points + flow) @ back[:3, :3].T + back[:3, 3] - points
    bounds = np.concatenate([[0], np.cumsum(counts)])
    rows = [describe_object(points[lo:hi], own[lo:hi] / dt, config) for lo, hi in zip(bounds[:-1], bounds[1:])]
    centres, sizes, yaws, kinds, velocities, covariances = (np.array(column) for column in zip(*rows))
    return Obstacles(stamp_ns, frame_id, ids=instances, kinds=kinds, centres=centres, sizes=sizes, yaws=yaws,
                     velocities=velocities, velocity_covariances=covariances, point_counts=counts,
                     confidences=np.array([segmentation.dynamic_prob[member].mean() for member in members]))


def describe_object(points: np.ndarray, velocities: np.ndarray, config: ObstacleConfig):
    """Box (centre, size, yaw), kind, mean velocity and its covariance of one object's points."""
    velocity = velocities.mean(axis=0)
    spread = np.cov(velocities.T) / len(velocities) if len(velocities) > 1 else np.zeros((3, 3))
    covariance = spread + np.eye(3) * config.velocity_noise ** 2
    xy = points[:, :2]
    axis = fit_footprint_axis(xy[:: -(-len(xy) // config.fit_points)], np.radians(config.fit_step), config.fit_closeness)
    moving = clearly_moving(velocity[:2], covariance[:2, :2], config)
    sides = extent_along(xy, axis)[1]
    yaw = axis + (np.pi / 2 if sides[1] > sides[0] else 0.0)  # the longer side is the length, unless it moves
    kind = ObstacleKind.VEHICLE if sides.max() >= config.vehicle_length else ObstacleKind.PEDESTRIAN
    if moving:  # the heading along the motion: a vehicle's along its fitted side closest to it, a pedestrian's exactly
        heading = float(np.arctan2(velocity[1], velocity[0]))
        yaw = heading_of_nearest_side(axis, heading) if kind is ObstacleKind.VEHICLE else heading
    else:
        yaw = float((yaw + np.pi / 2) % np.pi - np.pi / 2)
    centre_xy, sides = extent_along(xy, yaw)
    prior = config.vehicle_size if kind is ObstacleKind.VEHICLE else config.pedestrian_size
    centre_xy, sides = grow_away_from_sensor(centre_xy, sides, yaw, np.array(prior))
    low, high = points[:, 2].min(), points[:, 2].max()
    return (np.array([centre_xy[0], centre_xy[1], (low + high) / 2]), np.array([sides[0], sides[1], high - low]),
            yaw, int(kind), velocity, covariance)


def fit_footprint_axis(xy: np.ndarray, step: float, closeness: float) -> float:
    """Heading in [0, pi/2) of the rectangle whose sides the points hug most (L-shape closeness, Zhang et al. 2017)."""
    angles = np.arange(0.0, np.pi / 2, step)
    c, s = np.cos(angles), np.sin(angles)
    u, v = np.stack([c, s]).T @ xy.T, np.stack([-s, c]).T @ xy.T  # (angles, points): reduced along rows, fast
    to_u = np.minimum(u.max(axis=1, keepdims=True) - u, u - u.min(axis=1, keepdims=True))
    to_v = np.minimum(v.max(axis=1, keepdims=True) - v, v - v.min(axis=1, keepdims=True))
    score = (1.0 / np.maximum(np.minimum(to_u, to_v), closeness)).sum(axis=1)
    return float(angles[int(np.argmax(score))])


def extent_along(xy: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) and sides (along yaw, across) of the rectangle at heading yaw around the points."""
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
    uv = xy @ axes.T
    low, high = column_bounds(uv)
    return (low + high) / 2 @ axes, high - low


def clearly_moving(velocity: np.ndarray, covariance: np.ndarray, config: ObstacleConfig) -> bool:
    """Whether a velocity (2,) is fast enough, and that many sigmas of its covariance (2, 2) along it, to tell a heading."""
    speed = float(np.hypot(*velocity))
    if speed == 0.0 or speed < config.heading_speed:
        return False
    direction = velocity / speed
    return speed >= config.heading_significance * float(np.sqrt(direction @ covariance @ direction))


def heading_of_nearest_side(axis: float, heading: float) -> float:
    """The direction of the rectangle side (at axis, axis + pi/2, ...) closest to the heading, in [-pi, pi)."""
    sides = axis + np.arange(4) * np.pi / 2
    nearest = sides[int(np.argmin(np.abs((sides - heading + np.pi) % (2 * np.pi) - np.pi)))]
    return float((nearest + np.pi) % (2 * np.pi) - np.pi)


def grow_away_from_sensor(centre: np.ndarray, sides: np.ndarray, yaw: float, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grow a footprint to at least the prior size on the sides hidden from the sensor (at the origin); both ways along
    an axis the sensor lies within."""
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # rows: length axis, width axis
    grown = np.maximum(sides, prior)
    shift = np.zeros(2)
    for axis in range(2):
        extra = (grown[axis] - sides[axis]) / 2
        along = axes[axis] @ centre  # the sensor is at -along from the centre on this axis
        away = np.sign(along) if abs(along) > sides[axis] / 2 else 0.0  # the far side along this axis
        shift += away * extra * axes[axis]
    return centre + shift, grown


class StillClusters(NamedTuple):
    """The still clusters of a scan as boxes, and the mean of each cluster's points (steadier than a box's centre as
    the view changes, for tracking)."""

    boxes: Obstacles
    means: np.ndarray  # (M, 2)


def still_clusters(points: np.ndarray, stamp_ns: int, frame_id: str, config: StillConfig,
                   to_frame: np.ndarray | None = None) -> StillClusters:
    """DBSCAN clusters of a scan's points (sensor frame) above the ground as still boxes, in `frame_id`: the sensor
    frame, or the frame `to_frame` (frame_id <- sensor) moves the points into before they are clustered."""
    points = clustered_points(points, config)
    if to_frame is not None:
        points = transform_points(to_frame, points).astype(np.float64)
    labels, count = dbscan(points[:, :2], config.eps, config.min_samples)
    sizes_of = label_counts(labels[labels >= 0], count)
    keep = np.flatnonzero(sizes_of >= config.min_points)
    renumbered = np.full(count + 1, -1)
    renumbered[keep] = np.arange(len(keep))
    kept = renumbered[labels] >= 0  # labels -1 (noise) read the last entry: -1
    points, labels = points[kept], renumbered[labels[kept]]
    centres, sizes, yaws = bounding_boxes(points, labels, len(keep))
    kinds = np.where(sizes[:, 0] >= config.vehicle_length, ObstacleKind.VEHICLE, ObstacleKind.PEDESTRIAN)
    found = Obstacles(stamp_ns, frame_id, ids=np.zeros(len(keep), np.int64), kinds=kinds, centres=centres,
                      sizes=sizes, yaws=yaws, velocities=np.zeros((len(keep), 3)), point_counts=sizes_of[keep])
    return StillClusters(found, label_means(points[:, :2], labels, len(keep)))


def clustered_points(points: np.ndarray, config: StillConfig) -> np.ndarray:
    """The scan points (sensor frame) the clustering looks at: within range, above the ground, below the canopy, one
    per ground-plane cell (a bird's-eye view, like the 2-D scans rda_ros clusters)."""
    points = np.asarray(points, dtype=np.float64)[:, :3]
    points = points[np.hypot(points[:, 0], points[:, 1]) <= config.max_range]
    height = height_above_ground(points, config.ground_cell)
    points = points[(height >= config.min_height) & (height <= config.max_height)]
    return points[voxel_indices(points[:, :2], config.cell)] if len(points) else points


def stack(first: Obstacles, second: Obstacles) -> Obstacles:
    """The obstacles of both (same frame), with the first's stamp."""
    columns = ("ids", "kinds", "centres", "sizes", "yaws", "velocities", "velocity_covariances", "yaw_rates",
               "point_counts", "confidences")
    return replace(first, **{name: np.concatenate([getattr(first, name), getattr(second, name)]) for name in columns})
