"""Spinning multi-beam LiDAR by ray casting (Open3D): static scene built once, moving agents per frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_bridge.meshes import TriangleSoup
from sim_bridge.scenario import LidarConfig
from sim_bridge.world import PointClass

SCAN_PERIOD = 0.1
REFLECTIVITY = np.array([0.25, 0.45, 0.6, 0.3, 0.8, 0.8, 0.35], np.float32)  # indexed by PointClass


@dataclass(frozen=True)
class Scan:
    """One LiDAR sweep in the sensor frame, with per-point ground-truth labels."""

    points: np.ndarray  # (N, 3) float32, sensor frame
    intensity: np.ndarray  # (N,) float32, 0..255
    ring: np.ndarray  # (N,) uint16, 0 = lowest beam
    time: np.ndarray  # (N,) float32, firing time offset within the sweep, s
    label: np.ndarray  # (N,) uint8 PointClass
    instance: np.ndarray  # (N,) int32 agent instance id, 0 for static surfaces

    def __len__(self) -> int:
        return len(self.points)


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


class Lidar:
    """A spinning LiDAR that casts beams x columns rays against a static and a per-frame dynamic scene."""

    def __init__(self, cfg: LidarConfig, static: TriangleSoup):
        self.cfg = cfg
        elevation = np.radians(np.linspace(cfg.fov_down, cfg.fov_up, cfg.beams))
        azimuth = 2 * np.pi * np.arange(cfg.columns) / cfg.columns
        el, az = np.meshgrid(elevation, azimuth, indexing="ij")
        self.directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
        self._directions32 = self.directions.astype(np.float32)
        self.ring = np.repeat(np.arange(cfg.beams, dtype=np.uint16), cfg.columns)
        self.time = np.tile((np.arange(cfg.columns) / cfg.columns * SCAN_PERIOD).astype(np.float32), cfg.beams)
        self.static = static
        self._static_scene = raycasting_scene(static)

    def scan(self, pose: np.ndarray, dynamic: TriangleSoup, rng: np.random.Generator) -> Scan:
        """Cast every beam from pose (world <- sensor), nearest hit of static and dynamic geometry."""
        o3d = _import_open3d()
        # einsum, not @: BLAS worker threads stall for tens of ms right after Open3D's parallel ray casts
        world_dirs = np.einsum("ij,kj->ik", self._directions32, pose[:3, :3].astype(np.float32))
        rays = np.empty((len(world_dirs), 6), np.float32)
        rays[:, :3] = pose[:3, 3]
        rays[:, 3:] = world_dirs
        rays_tensor = o3d.core.Tensor(rays)
        hit_static = self._static_scene.cast_rays(rays_tensor)
        distance = hit_static["t_hit"].numpy()
        if len(dynamic.triangles):
            hit_dynamic = raycasting_scene(dynamic).cast_rays(rays_tensor)
            distance_dynamic = hit_dynamic["t_hit"].numpy()
            from_dynamic = distance_dynamic < distance
            distance = np.minimum(distance, distance_dynamic)
        else:
            from_dynamic = np.zeros(len(rays), bool)
        keep = (distance <= self.cfg.max_range) & (distance >= self.cfg.min_range)
        if self.cfg.dropout > 0:
            keep &= rng.random(len(rays)) >= self.cfg.dropout
        index = np.flatnonzero(keep)
        distance = distance[index]
        if self.cfg.range_noise > 0:
            noise = rng.standard_normal(len(index), dtype=np.float32)
            distance = np.maximum(distance + np.float32(self.cfg.range_noise) * noise, np.float32(0.0))
        dynamic_hit = from_dynamic[index]
        label = self.static.labels[np.where(dynamic_hit, 0, hit_static["primitive_ids"].numpy()[index])]
        owner = np.full(len(index), -1, np.int32)
        normals = hit_static["primitive_normals"].numpy()[index]
        if dynamic_hit.any():
            which = index[dynamic_hit]
            triangle = hit_dynamic["primitive_ids"].numpy()[which]
            label[dynamic_hit] = dynamic.labels[triangle]
            owner[dynamic_hit] = dynamic.owners[triangle]
            normals[dynamic_hit] = hit_dynamic["primitive_normals"].numpy()[which]
        incidence = np.abs(np.einsum("ij,ij->i", normals, world_dirs[index]))
        falloff = np.clip(np.float32(1.5) - distance / np.float32(2 * self.cfg.max_range), 0.0, 1.0)
        intensity = np.float32(255.0) * REFLECTIVITY[label] * (np.float32(0.3) + np.float32(0.7) * incidence) * falloff
        return Scan(
            self._directions32[index] * distance[:, None],
            np.clip(intensity, 0, 255).astype(np.float32),
            self.ring[index],
            self.time[index],
            label.astype(np.uint8),
            (owner + 1).astype(np.int32),
        )


def surface_distance(soup: TriangleSoup, points_world: np.ndarray) -> np.ndarray:
    """Unsigned distance from world points to a triangle soup."""
    o3d = _import_open3d()
    return raycasting_scene(soup).compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()


__all__ = ["Lidar", "Scan", "PointClass", "surface_distance", "raycasting_scene"]
