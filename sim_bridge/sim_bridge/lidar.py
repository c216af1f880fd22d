"""Spinning multi-beam LiDARs by ray casting (Open3D): static scene built once, moving agents per frame.

One sweep is cast from the pose at its stamp (no motion distortion within the sweep; `time` says when each column
would fire). Every sensor model is a set of rays (origin and direction in the `lidar` frame, ring, column) built
from its datasheet layout; a rig of several sensors casts each from its own origin into one merged cloud.

Sensor effects: Gaussian range noise, random dropout of returns, and mixed points at depth edges. A beam next to
a depth edge (its neighbour in the same ring hits a surface MIXED_GAP[0] to MIXED_GAP[1] metres nearer or
farther) has the edge inside its footprint with the model's `straddle_share` (from its beam divergence and azimuth
step); such a beam returns, with probability `mixed_points`, one merged echo: a point somewhere between the two
surfaces along the beam. Farther apart, the two echoes separate and the sensor reports one surface. A mixed
point's ground truth is that of the surface nearer to it along the beam: that surface's class and instance, and
its rigid motion (see ground_truth.py), so its flow keeps its distance to that surface exactly although the point
itself lies on neither.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_bridge.meshes import TriangleSoup
from sim_bridge.scenario import LidarConfig
from sim_bridge.sensors import SensorSpec
from sim_bridge.world import PointClass

REFLECTIVITY = np.array([0.25, 0.45, 0.6, 0.3, 0.8, 0.8, 0.35], np.float32)  # indexed by PointClass
MIXED_GAP = (0.3, 2.0)  # depth steps (m) whose two echoes merge into one (a pulse of a few ns), so a mixed point


@dataclass(frozen=True)
class Scan:
    """One LiDAR sweep in the sensor (rig) frame, with per-point ground-truth labels."""

    points: np.ndarray  # (N, 3) float32, sensor frame
    intensity: np.ndarray  # (N,) float32, 0..255
    ring: np.ndarray  # (N,) uint16, beam of its sensor, 0 = that sensor's lowest beam
    time: np.ndarray  # (N,) float32, firing time offset within the sweep, s
    label: np.ndarray  # (N,) uint8 PointClass
    instance: np.ndarray  # (N,) int32 agent instance id, 0 for static surfaces
    sensor: np.ndarray | None = None  # (N,) uint8 sensor of a rig that took the point (None: a single sensor)
    mixed: np.ndarray | None = None  # (N,) bool, a mixed return between two surfaces (None: none in this scan)

    def __len__(self) -> int:
        return len(self.points)


def empty_scan() -> Scan:
    """A scan without points (a simulator run without scans)."""
    return Scan(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.uint16), np.zeros(0, np.float32),
                np.zeros(0, np.uint8), np.zeros(0, np.int32))


def _import_open3d():
    import open3d as o3d

    return o3d


def raycasting_scene(soup: TriangleSoup):
    """An Open3D RaycastingScene holding one triangle soup (one geometry)."""
    o3d = _import_open3d()
    scene = o3d.t.geometry.RaycastingScene(nthreads=0)
    if len(soup.triangles):
        scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(soup.vertices, np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(soup.triangles, np.uint32)),
        )
    return scene


@dataclass(frozen=True)
class RayFan:
    """Every ray of one sweep in the lidar frame, sensor by sensor, beam by beam, column by column."""

    origins: np.ndarray | None  # (R, 3) float32, None when every ray starts at the frame origin
    directions: np.ndarray  # (R, 3) float32 unit vectors
    ring: np.ndarray  # (R,) uint16
    sensor: np.ndarray | None  # (R,) uint8, None for a single sensor
    time: np.ndarray  # (R,) float32
    left: np.ndarray  # (R,) index of the previous column's ray in the same ring (wrapping)
    right: np.ndarray  # (R,) index of the next column's ray in the same ring (wrapping)


def ray_fan(spec: SensorSpec) -> RayFan:
    """The rays of a sensor model: its beam elevations x columns, for each sensor of the rig from its mount."""
    beams, columns = spec.beams, spec.columns
    elevation = np.radians(spec.elevations)
    azimuth = 2 * np.pi * np.arange(columns) / columns
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    mounts = [mount.matrix() for mount in spec.mounts]
    directions = np.concatenate([local @ mount[:3, :3].T for mount in mounts])
    per_sensor = beams * columns
    at_origin = all(not mount[:3, 3].any() for mount in mounts)
    origins = None if at_origin else np.repeat(np.stack([m[:3, 3] for m in mounts]), per_sensor, 0).astype(np.float32)
    ring = np.tile(np.repeat(np.arange(beams, dtype=np.uint16), columns), spec.sensors)
    sensor = None if spec.sensors == 1 else np.repeat(np.arange(spec.sensors, dtype=np.uint8), per_sensor)
    time = np.tile((np.arange(columns) / columns * spec.period).astype(np.float32), beams * spec.sensors)
    row_start = np.arange(spec.rays) // columns * columns
    column = np.arange(spec.rays) - row_start
    return RayFan(origins, directions.astype(np.float32), ring, sensor, time,
                  row_start + (column - 1) % columns, row_start + (column + 1) % columns)


class Lidar:
    """A spinning LiDAR (or rig) that casts its rays against a static and a per-frame dynamic scene."""

    def __init__(self, cfg: LidarConfig, static: TriangleSoup):
        self.cfg = cfg
        self.spec = cfg.spec()
        self.rays = ray_fan(self.spec)
        self.directions = self.rays.directions.astype(np.float64)
        self.ring = self.rays.ring
        self.time = self.rays.time
        self.static = static
        self._static_scene = raycasting_scene(static)

    def scan(self, pose: np.ndarray, dynamic: TriangleSoup, rng: np.random.Generator) -> Scan:
        """Cast every beam from pose (world <- lidar), nearest hit of static and dynamic geometry, sensor effects."""
        o3d = _import_open3d()
        spec, fan = self.spec, self.rays
        rotation = pose[:3, :3].astype(np.float32)
        # einsum, not @: BLAS worker threads stall for tens of ms right after Open3D's parallel ray casts
        world_dirs = np.einsum("ij,kj->ik", fan.directions, rotation)
        rays = np.empty((len(world_dirs), 6), np.float32)
        rays[:, :3] = pose[:3, 3]
        if fan.origins is not None:
            rays[:, :3] += np.einsum("ij,kj->ik", fan.origins, rotation)
        rays[:, 3:] = world_dirs
        rays_tensor = o3d.core.Tensor(rays)
        hit_static = self._static_scene.cast_rays(rays_tensor)
        distance = hit_static["t_hit"].numpy()
        hit_dynamic = None
        if len(dynamic.triangles):
            hit_dynamic = raycasting_scene(dynamic).cast_rays(rays_tensor)
            distance_dynamic = hit_dynamic["t_hit"].numpy()
            from_dynamic = distance_dynamic < distance
            distance = np.minimum(distance, distance_dynamic)
        else:
            from_dynamic = np.zeros(len(rays), bool)
        surface, distance, mixed = self._mix_edges(distance, rng)
        keep = (distance <= spec.max_range) & (distance >= spec.min_range)
        if spec.dropout > 0:
            keep &= rng.random(len(rays)) >= spec.dropout
        index = np.flatnonzero(keep)
        distance = distance[index]
        if spec.range_noise > 0:
            noise = rng.standard_normal(len(index), dtype=np.float32)
            distance = np.maximum(distance + np.float32(spec.range_noise) * noise, np.float32(0.0))
        hit = index if surface is None else surface[index]  # the ray whose surface each point belongs to
        dynamic_hit = from_dynamic[hit]
        label = self.static.labels[np.where(dynamic_hit, 0, hit_static["primitive_ids"].numpy()[hit])]
        owner = np.full(len(index), -1, np.int32)
        normals = hit_static["primitive_normals"].numpy()[hit]
        if dynamic_hit.any():
            which = hit[dynamic_hit]
            triangle = hit_dynamic["primitive_ids"].numpy()[which]
            label[dynamic_hit] = dynamic.labels[triangle]
            owner[dynamic_hit] = dynamic.owners[triangle]
            normals[dynamic_hit] = hit_dynamic["primitive_normals"].numpy()[which]
        incidence = np.abs(np.einsum("ij,ij->i", normals, world_dirs[index]))
        falloff = np.clip(np.float32(1.5) - distance / np.float32(2 * spec.max_range), 0.0, 1.0)
        intensity = np.float32(255.0) * REFLECTIVITY[label] * (np.float32(0.3) + np.float32(0.7) * incidence) * falloff
        points = fan.directions[index] * distance[:, None]
        if fan.origins is not None:
            points += fan.origins[index]
        return Scan(
            points,
            np.clip(intensity, 0, 255).astype(np.float32),
            fan.ring[index],
            fan.time[index],
            label.astype(np.uint8),
            (owner + 1).astype(np.int32),
            None if fan.sensor is None else fan.sensor[index],
            None if mixed is None else mixed[index],
        )

    def _mix_edges(self, distance: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray | None, np.ndarray, np.ndarray | None]:
        """Mixed returns at depth edges: per ray, the ray whose surface it belongs to, its range, and the mixed flag.

        Returns (None, distance, None) when the model makes no mixed points (and draws no random numbers)."""
        if self.spec.mixed_points <= 0:
            return None, distance, None
        fan = self.rays
        neighbour = np.where(rng.random(len(distance)) < 0.5, fan.left, fan.right)
        with np.errstate(invalid="ignore"):  # inf - inf where neither ray hits anything
            gap = np.abs(distance[neighbour] - distance)
        edge = np.isfinite(gap) & (gap >= MIXED_GAP[0]) & (gap <= MIXED_GAP[1])
        mixed = edge & (rng.random(len(distance)) < self.spec.mixed_points * self.spec.straddle_share)
        where = np.flatnonzero(mixed)
        blend = rng.random(len(where)).astype(np.float32)
        distance = distance.copy()
        distance[where] += blend * (distance[neighbour[where]] - distance[where])
        surface = np.arange(len(distance))
        surface[where] = np.where(blend > 0.5, neighbour[where], where)  # the surface nearer along the beam
        return surface, distance, mixed


def surface_distance(soup: TriangleSoup, points_world: np.ndarray) -> np.ndarray:
    """Unsigned distance from world points to a triangle soup."""
    o3d = _import_open3d()
    return raycasting_scene(soup).compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()


__all__ = ["Lidar", "MIXED_GAP", "RayFan", "Scan", "PointClass", "ray_fan", "surface_distance", "raycasting_scene"]
