"""Moving objects as obstacles: an oriented box per dynamic instance, its velocity from the flow, and how sure it is."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.boxes import min_area_rectangle
from ssf_common.geometry.se3 import invert
from ssf_common.records import ObstacleKind, Obstacles, Segmentation


class ObstacleConfig(Section):
    """How dynamic instances become obstacles."""

    min_points: int = Field(5, ge=1, description="instances with fewer points are not reported")
    vehicle_length: float = Field(1.2, gt=0.0, description="footprints with a side at least this long (m) are vehicles, "
                                  "else pedestrians (a car seen end-on shows only its width)")
    heading_speed: float = Field(1.0, ge=0.0, description="a vehicle this fast (m/s) has its length along the side of its "
                                 "footprint closest to its velocity")
    vehicle_size: tuple[float, float] = Field((4.4, 1.8), description="a vehicle's footprint is grown to at least this "
                                              "(length, width; m), away from the sensor (its hidden sides)")
    pedestrian_size: tuple[float, float] = Field((0.6, 0.6), description="the same for pedestrians")
    velocity_noise: float = Field(0.05, ge=0.0, description="floor of the velocity standard deviation (m/s)")


def extract_obstacles(points: np.ndarray, flow: np.ndarray, segmentation: Segmentation, ego: np.ndarray, dt: float,
                      stamp_ns: int, frame_id: str, config: ObstacleConfig) -> Obstacles:
    """Obstacles of scan t in its sensor frame: boxes at time t, velocities of the objects themselves (ego removed)."""
    points, flow = np.asarray(points, np.float64), np.asarray(flow, np.float64)
    instances, counts = np.unique(segmentation.instance[segmentation.instance > 0], return_counts=True)
    instances = instances[counts >= config.min_points]
    # the object's own displacement in scan t's axes: where it is at t+1, seen from the sensor pose at t, minus where
    # it was (the flow alone also carries the ego motion)
    back = invert(ego)
    own = (points + flow) @ back[:3, :3].T + back[:3, 3] - points
    rows = [describe(points[segmentation.instance == k], own[segmentation.instance == k] / dt, config) for k in instances]
    if not rows:
        return Obstacles.empty(stamp_ns, frame_id)
    centres, sizes, yaws, kinds, velocities, covariances = (np.array(column) for column in zip(*rows))
    return Obstacles(stamp_ns, frame_id, ids=instances, kinds=kinds, centres=centres, sizes=sizes, yaws=yaws,
                     velocities=velocities, velocity_covariances=covariances,
                     point_counts=np.array([np.count_nonzero(segmentation.instance == k) for k in instances]),
                     confidences=np.array([segmentation.dynamic_prob[segmentation.instance == k].mean() for k in instances]))


def describe(points: np.ndarray, velocities: np.ndarray, config: ObstacleConfig):
    """Box (centre, size, yaw), kind, mean velocity and its covariance of one object's points."""
    velocity = velocities.mean(axis=0)
    centre_xy, sides, yaw = min_area_rectangle(points[:, :2])
    kind = ObstacleKind.VEHICLE if sides[0] >= config.vehicle_length else ObstacleKind.PEDESTRIAN
    if kind is ObstacleKind.VEHICLE and np.hypot(*velocity[:2]) >= config.heading_speed:
        sides, yaw = along_velocity(sides, yaw, velocity[:2])
    prior = config.vehicle_size if kind is ObstacleKind.VEHICLE else config.pedestrian_size
    centre_xy, sides = grow_away_from_sensor(centre_xy, sides, yaw, np.array(prior))
    low, high = points[:, 2].min(), points[:, 2].max()
    spread = np.cov(velocities.T) / len(velocities) if len(velocities) > 1 else np.zeros((3, 3))
    covariance = spread + np.eye(3) * config.velocity_noise ** 2
    return (np.array([centre_xy[0], centre_xy[1], (low + high) / 2]), np.array([sides[0], sides[1], high - low]),
            yaw, int(kind), velocity, covariance)


def along_velocity(sides: np.ndarray, yaw: float, velocity: np.ndarray) -> tuple[np.ndarray, float]:
    """The footprint's sides and heading with the length axis the one closer to the direction of travel (a vehicle
    seen end-on shows a face as wide as it is, across its motion)."""
    across = abs(np.cos(yaw) * velocity[1] - np.sin(yaw) * velocity[0]) > abs(np.cos(yaw) * velocity[0] + np.sin(yaw) * velocity[1])
    return (sides[::-1].copy(), float((yaw + np.pi) % np.pi - np.pi / 2)) if across else (sides, yaw)


def grow_away_from_sensor(centre: np.ndarray, sides: np.ndarray, yaw: float, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grow a footprint seen from the sensor (at the origin) to at least the prior size, on its far sides: the
    LiDAR sees only the faces turned towards it."""
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # rows: length axis, width axis
    grown = np.maximum(sides, prior)
    shift = np.zeros(2)
    for axis in range(2):
        extra = (grown[axis] - sides[axis]) / 2
        away = np.sign(axes[axis] @ centre) or 1.0  # the far side along this axis
        shift += away * extra * axes[axis]
    return centre + shift, grown
