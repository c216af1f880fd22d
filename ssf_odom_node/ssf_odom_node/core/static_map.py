"""The static map: one point (with its normal) per voxel, in the odometry frame, bounded to a local window around
the vehicle and to a voxel cap, so its memory never grows with the route."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_odom_node.core.registration import PlaneTarget

KEY_BITS = 21  # per axis: +-1M voxels, packed into one int64 code
KEY_OFFSET = 1 << (KEY_BITS - 1)
BYTES_PER_VOXEL = 3 * 4 + 3 * 4 + 8  # float32 point, float32 normal, int64 code


class MapConfig(Section):
    """Voxel size and the bounds of the local static map."""

    voxel: float = Field(0.8, gt=0.0, description="voxel edge (m): the map keeps one point per voxel")
    radius: float = Field(60.0, gt=0.0, description="voxels farther than this from the vehicle are dropped (m)")
    max_voxels: int = Field(60000, ge=100, description="cap on stored voxels (the farthest go first)")
    refresh: float = Field(0.1, ge=0.0, le=1.0, description="the registration target (KD-tree) is rebuilt once this "
                           "share of the map is new since the last build (0: every scan)")

    @property
    def max_bytes(self) -> int:
        """The memory the map may hold at most."""
        return self.max_voxels * BYTES_PER_VOXEL


def voxel_codes(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 code per point naming its voxel."""
    keys = np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64) + KEY_OFFSET
    keys = np.clip(keys, 0, (1 << KEY_BITS) - 1)
    return (keys[:, 0] << (2 * KEY_BITS)) | (keys[:, 1] << KEY_BITS) | keys[:, 2]


class VoxelMap:
    """A local voxel map of points with normals; `target()` is what a scan is registered against."""

    def __init__(self, config: MapConfig) -> None:
        self.config = config
        self.points = np.zeros((0, 3), np.float32)
        self.normals = np.zeros((0, 3), np.float32)
        self.codes = np.zeros(0, np.int64)
        self._target: PlaneTarget | None = None
        self._added_since_build = 0

    def __len__(self) -> int:
        return len(self.codes)

    @property
    def nbytes(self) -> int:
        """Memory held by the map's arrays."""
        return self.points.nbytes + self.normals.nbytes + self.codes.nbytes

    def new_voxels(self, points: np.ndarray) -> np.ndarray:
        """Indices of the points (odometry frame) that fall in voxels the map does not hold yet, one per voxel."""
        codes, first = np.unique(voxel_codes(points, self.config.voxel), return_index=True)
        return first[~np.isin(codes, self.codes, assume_unique=True)]

    def insert(self, points: np.ndarray, normals: np.ndarray, centre: np.ndarray) -> int:
        """Add points (odometry frame) with their normals in voxels not yet occupied, then crop to the window
        around `centre`; returns how many voxels were added."""
        new = self.new_voxels(points)
        if len(new):
            self.points = np.concatenate([self.points, np.asarray(points, np.float32)[new]])
            self.normals = np.concatenate([self.normals, np.asarray(normals, np.float32)[new]])
            self.codes = np.concatenate([self.codes, voxel_codes(np.asarray(points)[new], self.config.voxel)])
        self.crop(centre)
        self._added_since_build += len(new)
        return len(new)

    def crop(self, centre: np.ndarray) -> None:
        """Keep the voxels within the radius of `centre`, and at most max_voxels of them (nearest first)."""
        distance = np.linalg.norm(self.points[:, :2] - np.asarray(centre, np.float32)[:2], axis=1)
        keep = distance <= self.config.radius
        if keep.sum() > self.config.max_voxels:
            keep = np.zeros(len(distance), bool)
            keep[np.argpartition(distance, self.config.max_voxels - 1)[: self.config.max_voxels]] = True
        if not keep.all():
            self.points, self.normals, self.codes = self.points[keep], self.normals[keep], self.codes[keep]

    def target(self) -> PlaneTarget:
        """The map as a registration target; its KD-tree is rebuilt once `refresh` of the map is new (voxels that
        left the window stay in it until then: they are still true surfaces)."""
        if self._target is None or self._added_since_build > self.config.refresh * max(len(self._target), 1):
            self._target = PlaneTarget.build(self.points, self.normals)
            self._added_since_build = 0
        return self._target
