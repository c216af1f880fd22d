"""Spinning multi-beam LiDARs by ray casting (Open3D): static scene built once, moving agents per sweep.

An instant sweep (`lidar.rolling_shutter: false`, the default) is cast whole from the pose at its stamp against the
agents there; every point's `time` is 0. With a rolling shutter each column fires at its own time within the
period (SensorSpec.column_times: clockwise from behind, the last column at the stamp, which marks the sweep's end),
from where the sensor is then, against every agent where it is then (agent_rays.py; the motion within a sweep is
sweep.py's); `time` is that firing time, s relative to the stamp, and each point is in the sensor frame of its own
time, as a driver reports it (not deskewed). Every sensor model is a set of rays (origin and direction in the
`lidar` frame, ring, column) built from its datasheet layout; a rig of several sensors casts each from its own
origin into one merged cloud.

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

from sim_bridge.agent_rays import AgentHits, MovingAgentCaster
from sim_bridge.agents import AgentStates, agent_mesh
from sim_bridge.meshes import TriangleSoup, import_open3d, raycasting_scene
from sim_bridge.scenario import LidarConfig
from sim_bridge.sensors import SensorSpec
from sim_bridge.sweep import Sweep
from sim_bridge.world import PointClass

REFLECTIVITY = np.array([0.25, 0.45, 0.6, 0.3, 0.8, 0.8, 0.35], np.float32)  # indexed by PointClass
MIXED_GAP = (0.3, 2.0)  # depth steps (m) whose two echoes merge into one (a pulse of a few ns), so a mixed point


@dataclass(frozen=True)
class Scan:
    """One LiDAR sweep in the sensor (rig) frame, with per-point ground-truth labels."""

    points: np.ndarray  # (N, 3) float32, sensor frame
    intensity: np.ndarray  # (N,) float32, 0..255
    ring: np.ndarray  # (N,) uint16, beam of its sensor, 0 = that sensor's lowest beam
    time: np.ndarray  # (N,) float32, firing time, s relative to the stamp (the sweep's end): <= 0, all 0 if instant
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


@dataclass(frozen=True)
class RayFan:
    """Every ray of one sweep in the lidar frame, sensor by sensor, beam by beam, column by column."""

    origins: np.ndarray | None  # (R, 3) float32, None when every ray starts at the frame origin
    directions: np.ndarray  # (R, 3) float32 unit vectors
    ring: np.ndarray  # (R,) uint16
    sensor: np.ndarray | None  # (R,) uint8, None for a single sensor
    time: np.ndarray  # (R,) float32, firing time, s relative to the stamp
    column_time: np.ndarray  # (columns,) float32, the firing time of each column
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
    column_time = spec.column_times().astype(np.float32)
    time = np.tile(column_time, beams * spec.sensors)
    row_start = np.arange(spec.rays) // columns * columns
    column = np.arange(spec.rays) - row_start
    return RayFan(origins, directions.astype(np.float32), ring, sensor, time, column_time,
                  row_start + (column - 1) % columns, row_start + (column + 1) % columns)


class Lidar:
    """A spinning LiDAR (or rig) that casts its rays against a static scene and the agents of each sweep."""

    def __init__(self, cfg: LidarConfig, static: TriangleSoup):
        self.cfg = cfg
        self.spec = cfg.spec()
        self.rays = ray_fan(self.spec)
        self.directions = self.rays.directions.astype(np.float64)
        self.ring = self.rays.ring
        self.time = self.rays.time
        self.static = static
        self._static_scene = raycasting_scene(static)
        mount_radius = 0.0 if self.rays.origins is None else float(np.linalg.norm(self.rays.origins, axis=1).max())
        self._moving_agents = (MovingAgentCaster(self.spec.max_range, self.spec.columns, mount_radius)
                               if self.spec.rolling_shutter else None)

    def scan(self, sweep: Sweep, rng: np.random.Generator) -> Scan:
        """Cast every beam from where the sensor is when it fires, nearest hit of the static scene and the agents where
        they are then, sensor effects."""
        o3d = import_open3d()
        spec, fan = self.spec, self.rays
        rays = self.world_rays(sweep)
        rays_tensor = o3d.core.Tensor(rays)
        hit_static = self._static_scene.cast_rays(rays_tensor)
        agents = self._cast_agents(sweep, rays, rays_tensor)
        distance = hit_static["t_hit"].numpy()
        from_agent = agents.distance < distance
        distance = np.minimum(distance, agents.distance)
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
        agent_hit = from_agent[hit]
        label = np.zeros(len(index), np.uint8)
        label[~agent_hit] = self.static.labels[hit_static["primitive_ids"].numpy()[hit[~agent_hit]]]
        owner = np.full(len(index), -1, np.int32)
        normals = hit_static["primitive_normals"].numpy()[hit]
        if agent_hit.any():
            which = hit[agent_hit]
            label[agent_hit] = agents.label[which]
            owner[agent_hit] = agents.owner[which]
            normals[agent_hit] = agents.normal[which]
        incidence = np.abs(np.einsum("ij,ij->i", normals, rays[index, 3:]))
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

    def world_rays(self, sweep: Sweep) -> np.ndarray:
        """(R, 6) float32 world rays, origin then unit direction, of every beam from where the sensor is when it
        fires."""
        fan = self.rays
        rays = np.empty((len(fan.directions), 6), np.float32)
        if not self.spec.rolling_shutter:
            rotation = sweep.pose[:3, :3].astype(np.float32)
            # einsum, not @: BLAS worker threads stall for tens of ms right after Open3D's parallel ray casts
            rays[:, 3:] = np.einsum("ij,kj->ik", fan.directions, rotation)
            rays[:, :3] = sweep.pose[:3, 3]
            if fan.origins is not None:
                rays[:, :3] += np.einsum("ij,kj->ik", fan.origins, rotation)
            return rays
        columns = len(fan.column_time)
        poses = sweep.sensor_poses(fan.column_time)  # one pose per column: its firing time
        rotation = poses[:, :3, :3].astype(np.float32)
        by_column = rays.reshape(-1, columns, 6)  # rows (sensor, beam) x columns
        by_column[:, :, 3:] = _rotate_columns(rotation, fan.directions.reshape(-1, columns, 3))
        by_column[:, :, :3] = poses[:, :3, 3]
        if fan.origins is not None:
            by_column[:, :, :3] += _rotate_columns(rotation, fan.origins.reshape(-1, columns, 3))
        return rays

    def _cast_agents(self, sweep: Sweep, rays: np.ndarray, rays_tensor) -> AgentHits:
        """The nearest agent along each ray: exactly where each agent is when the ray fires (rolling shutter), or
        all of them at the stamp in one scene."""
        if self._moving_agents is not None:
            return self._moving_agents.cast(sweep, rays, self.rays.time)
        return self._cast_agent_mesh(sweep.agents, sweep.pose, rays_tensor, len(rays))

    def _cast_agent_mesh(self, agents: AgentStates, pose: np.ndarray, rays_tensor, count: int) -> AgentHits:
        """Every ray against the agents' triangles within range of pose."""
        hits = AgentHits.none(count)
        dynamic = agent_mesh(agents, pose[:2, 3], self.spec.max_range)
        if not len(dynamic.triangles):
            return hits
        cast = raycasting_scene(dynamic).cast_rays(rays_tensor)
        distance = cast["t_hit"].numpy()
        met = np.flatnonzero(np.isfinite(distance))
        triangle = cast["primitive_ids"].numpy()[met]
        hits.distance[met] = distance[met]
        hits.owner[met] = dynamic.owners[triangle]
        hits.label[met] = dynamic.labels[triangle]
        hits.normal[met] = cast["primitive_normals"].numpy()[met]
        return hits

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


def _rotate_columns(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """rotation[c] @ vectors[r, c] for rotations (C, 3, 3) and vectors (rows, C, 3), one component at a time (several
    times faster than einsum here, and no BLAS)."""
    out = np.empty_like(vectors)
    for axis in range(3):
        out[..., axis] = (rotation[:, axis, 0] * vectors[..., 0] + rotation[:, axis, 1] * vectors[..., 1]
                          + rotation[:, axis, 2] * vectors[..., 2])
    return out


def soup_distance(soup: TriangleSoup, points_world: np.ndarray) -> np.ndarray:
    """Unsigned distance from world points to a triangle soup."""
    o3d = import_open3d()
    return raycasting_scene(soup).compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()


__all__ = ["Lidar", "MIXED_GAP", "RayFan", "Scan", "PointClass", "ray_fan", "soup_distance", "raycasting_scene"]
