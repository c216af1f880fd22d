"""The static map: one point (with its normal) per voxel, in the odometry frame, bounded to a local window around
the vehicle and to a voxel cap, so its memory never grows with the route. Each voxel carries evidence: scans that
observe it static add to it, scans whose beams pass through it (free space) take from it, and a voxel joins the map
only once enough scans confirmed it; what moving objects the segmentation missed leave behind is cleared. The map
also remembers where the segmentation saw moving points (above the local ground): those voxels stay out of the map
for a while, so an agent that stops where it walked or drove is not confirmed, and voxels that a missed agent
confirmed leave when a seen one passes through them."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydantic import Field, model_validator

from ssf_common.config import Section
from ssf_common.geometry.sampling import voxel_keys
from ssf_common.geometry.se3 import invert
from ssf_common.geometry.registration import PlaneTarget

KEY_BITS = 21  # per axis: +-1M voxels, packed into one int64 code
BYTES_PER_VOXEL = 3 * 4 + 3 * 4 + 8 + 2 + 4 + 1  # float32 point and normal, int64 code, evidence, first scan, confirmed
BYTES_PER_MOVING = 8 + 4  # int64 code and last scan of a voxel remembered as holding moving points
MOVING_CLEARANCE = 0.5  # in voxels: moving points this close above the lowest point of their column are its ground
MAX_SLOPE = 20.0  # tan of the most grazing incidence the clearing margin allows for (~87 deg)


class MapConfig(Section):
    """Voxel size, the bounds of the local static map and the evidence a voxel needs to stay in it."""

    voxel: float = Field(0.8, gt=0.0, description="voxel edge (m): the map keeps one point per voxel")
    radius: float = Field(60.0, gt=0.0, description="voxels farther than this from the vehicle are dropped (m)")
    max_voxels: int = Field(60000, ge=100, description="cap on stored voxels, unconfirmed ones included (the "
                            "farthest go first)")
    refresh: float = Field(0.1, ge=0.0, le=1.0, description="the registration target (KD-tree) is rebuilt once this "
                           "share of the map is new since the last build (0: every scan)")
    max_speed: float = Field(0.6, ge=0.0, description="ssf: static points whose own motion (their flow minus the "
                             "ego motion the static flow gives) is faster than this stay out of the map (m/s; 0: off)")
    confirm: int = Field(12, ge=1, description="ssf: scans that must observe a voxel static before it joins the map "
                         "that is published and kept (registration uses every voxel that is held); 1: at once. A "
                         "walker the segmentation misses stands in a voxel for about as long as it takes to cross it "
                         "(0.8 m at 1 m/s: 8 scans, 13 with its body): 12 keeps most of them out")
    confirm_window: int = Field(15, ge=1, description="ssf: an unconfirmed voxel is forgotten this many scans after "
                                "it was first observed")
    max_evidence: int = Field(12, ge=1, description="ssf: a voxel's evidence grows by one per scan that observes it "
                              "static, up to this, and shrinks by one per scan whose beams pass through it; at zero "
                              "it leaves the map")
    clear_cell: float = Field(1.0, ge=0.0, le=10.0, description="ssf: angular cell of the range image that clears "
                              "the map, in units of the scan's mean angular spacing (measured on the first scan): a "
                              "voxel is seen through when the nearest return in its cell lies beyond it by more than "
                              "the voxel and the cell's depth spread on its surface (0: no clearing)")

    miss_weight: int = Field(4, ge=1, description="ssf: evidence a voxel loses per scan whose beams pass through it "
                             "(4: a confirmed voxel leaves after three scans that see through it)")
    moving_memory: float = Field(30.0, ge=0.0, description="ssf: voxels where the segmentation saw moving points "
                                 "(above the local ground) stay out of the published map for this long (s), and "
                                 "confirmed voxels they hold are unconfirmed; longer than agents stop at crossings "
                                 "(0: off)")

    @model_validator(mode="after")
    def _evidence_reaches_confirmation(self) -> MapConfig:
        if self.confirm > self.max_evidence:
            raise ValueError(f"map.confirm ({self.confirm}) must not exceed map.max_evidence ({self.max_evidence})")
        return self

    @property
    def max_bytes(self) -> int:
        """The memory the map may hold at most (voxels and remembered moving voxels, each at most max_voxels)."""
        return self.max_voxels * (BYTES_PER_VOXEL + BYTES_PER_MOVING)


def covered_angular_spacing(points: np.ndarray, cell: float = np.radians(2.0)) -> float:
    """Mean angular spacing (rad) of a scan's returns (sensor frame): the square root of the azimuth x elevation area
    they cover (cells of `cell` that hold a return) per return."""
    if len(points) == 0:
        return cell
    _, index = RangeImage.project(points, cell, int(np.ceil(2 * np.pi / cell)))
    return float(np.sqrt(len(np.unique(index)) * cell ** 2 / len(points)))


def above_ground(moving: np.ndarray, scan: np.ndarray, voxel: float) -> np.ndarray:
    """(M,) bool: moving points higher than half a voxel above the lowest point (of `scan` and `moving`) in their
    column (voxel x voxel, horizontally): a moving agent's body, not the ground under it."""
    if len(moving) == 0:
        return np.zeros(0, bool)
    every = np.concatenate([np.asarray(scan, np.float32)[:, :3], np.asarray(moving, np.float32)[:, :3]])
    columns, inverse = np.unique(voxel_keys(every[:, :2], voxel, KEY_BITS), return_inverse=True)
    lowest = np.full(len(columns), np.inf, np.float32)
    np.minimum.at(lowest, inverse, every[:, 2])
    return moving[:, 2] > lowest[inverse[len(scan):]] + MOVING_CLEARANCE * voxel


def voxel_codes(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 code per point naming its voxel."""
    return voxel_keys(points, voxel, KEY_BITS, clip=True)


class RangeImage(NamedTuple):
    """The nearest return of a scan in each angular cell (azimuth x elevation; 0 where the cell holds none)."""

    nearest: np.ndarray  # (rows * columns,) m
    cell: float  # rad
    columns: int
    farthest: float  # m, the farthest return

    @classmethod
    def build(cls, points: np.ndarray, cell: float) -> RangeImage:
        """The range image of a scan (sensor frame)."""
        columns, rows = int(np.ceil(2 * np.pi / cell)), int(np.ceil(np.pi / cell)) + 1
        distance, index = cls.project(points, cell, columns)
        nearest = np.full(rows * columns, np.inf, np.float32)
        np.minimum.at(nearest, index, distance)
        nearest[np.isinf(nearest)] = 0.0
        return cls(nearest, cell, columns, float(distance.max(initial=0.0)))

    @staticmethod
    def project(points: np.ndarray, cell: float, columns: int) -> tuple[np.ndarray, np.ndarray]:
        """Range of each point (sensor frame) and the index of its cell (float32: the whole scan, every scan)."""
        points = np.asarray(points, dtype=np.float32)
        flat = np.hypot(points[:, 0], points[:, 1])
        distance = np.hypot(flat, points[:, 2])
        per_cell = np.float32(1.0 / cell)
        column = ((np.arctan2(points[:, 1], points[:, 0]) + np.float32(np.pi)) * per_cell).astype(np.int64) % columns
        row = ((np.arctan2(points[:, 2], flat) + np.float32(np.pi / 2)) * per_cell).astype(np.int64)
        return distance, row * columns + column

    def seen_through(self, points: np.ndarray, normals: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: points (sensor frame) whose cell's nearest return lies beyond them by more than `margin` plus
        the depth the cell spans on their surface (normals, sensor frame) at their incidence."""
        distance, index = self.project(points, self.cell, self.columns)
        behind = self.nearest[index]
        incidence = np.abs(np.einsum("ij,ij->i", normals, points)) / np.maximum(distance, 1e-9)
        slope = np.minimum(np.sqrt(np.maximum(1.0 - incidence ** 2, 0.0)) / np.maximum(incidence, 1e-9), MAX_SLOPE)
        return behind > distance + margin + distance * self.cell * slope


class VoxelMap:
    """A local voxel map of points with normals and their evidence; `target()` is what a scan is registered
    against, `points`/`normals` are the confirmed voxels."""

    def __init__(self, config: MapConfig, scan_period: float = 0.1) -> None:
        self.config = config
        self.memory_scans = round(config.moving_memory / scan_period)  # how long moving voxels are remembered
        self.stored_points = np.zeros((0, 3), np.float32)
        self.stored_normals = np.zeros((0, 3), np.float32)
        self.codes = np.zeros(0, np.int64)
        self.evidence = np.zeros(0, np.int16)  # scans that observed the voxel static, less those that saw through it
        self.first = np.zeros(0, np.int32)  # the scan that first observed it
        self.confirmed = np.zeros(0, bool)
        self.scans = 0  # observations so far
        self.cleared = 0  # voxels removed by free-space clearing so far
        self.cell: float | None = None  # rad, the clearing range image's cell (from the first scan cleared with)
        self.moving_codes = np.zeros(0, np.int64)  # voxels that held moving points lately (sorted)
        self.moving_seen = np.zeros(0, np.int32)  # the last observation that saw moving points in each
        self._target: PlaneTarget | None = None
        self._changed_since_build = 0

    def __len__(self) -> int:
        return len(self.codes)

    @property
    def points(self) -> np.ndarray:
        """(V, 3) the confirmed voxels' points (odometry frame)."""
        return self.stored_points if self.confirmed.all() else self.stored_points[self.confirmed]

    @property
    def normals(self) -> np.ndarray:
        """(V, 3) the confirmed voxels' normals."""
        return self.stored_normals if self.confirmed.all() else self.stored_normals[self.confirmed]

    @property
    def nbytes(self) -> int:
        """Memory held by the map's arrays."""
        return sum(array.nbytes for array in (self.stored_points, self.stored_normals, self.codes, self.evidence,
                                              self.first, self.confirmed, self.moving_codes, self.moving_seen))

    def new_voxels(self, points: np.ndarray) -> np.ndarray:
        """Indices of the points (odometry frame) that fall in voxels the map does not hold yet, one per voxel."""
        codes, first = np.unique(voxel_codes(points, self.config.voxel), return_index=True)
        return first[~np.isin(codes, self.codes, assume_unique=True)]

    def observe(self, points: np.ndarray, moving: np.ndarray | None = None) -> np.ndarray:
        """One scan's static points (odometry frame): the voxels they fall in gain evidence (and are confirmed once
        they have enough, unless moving points were seen in them lately); `moving`: the scan's moving points
        (odometry frame, above their ground: see `above_ground`), whose voxels are remembered and unconfirmed.
        Returns the indices of the points in voxels not held yet, one per voxel."""
        self.scans += 1
        if moving is not None and self.memory_scans > 0:
            self.remember_moving(moving)
        moved_in = self.holds_moving(self.codes)
        self.confirmed &= ~moved_in
        codes, first = np.unique(voxel_codes(points, self.config.voxel), return_index=True)
        held = np.isin(self.codes, codes, assume_unique=True)
        self.evidence[held] = np.minimum(self.evidence[held] + 1, self.config.max_evidence)
        newly = held & ~self.confirmed & (self.evidence >= self.config.confirm) & ~moved_in
        self.confirmed |= newly
        return first[~np.isin(codes, self.codes[held], assume_unique=True)]

    def remember_moving(self, moving: np.ndarray) -> None:
        """Remember the voxels of moving points (odometry frame) as of this scan; forget those not seen for
        `moving_memory` (and the oldest beyond max_voxels)."""
        fresh = self.moving_seen > self.scans - self.memory_scans
        known, seen = self.moving_codes[fresh], self.moving_seen[fresh]
        codes = np.unique(voxel_codes(moving, self.config.voxel)) if len(moving) else np.zeros(0, np.int64)
        where = np.searchsorted(known, codes)
        found = np.zeros(len(codes), bool)
        found[where < len(known)] = known[where[where < len(known)]] == codes[where < len(known)]
        seen[where[found]] = self.scans
        known = np.insert(known, where[~found], codes[~found])
        seen = np.insert(seen, where[~found], self.scans)
        if len(known) > self.config.max_voxels:
            recent = np.sort(np.argpartition(-seen, self.config.max_voxels - 1)[: self.config.max_voxels])
            known, seen = known[recent], seen[recent]
        self.moving_codes, self.moving_seen = known, seen

    def holds_moving(self, codes: np.ndarray) -> np.ndarray:
        """(N,) bool: voxels (codes) where moving points were seen within the memory."""
        if len(self.moving_codes) == 0:
            return np.zeros(len(codes), bool)
        where = np.minimum(np.searchsorted(self.moving_codes, codes), len(self.moving_codes) - 1)
        return (self.moving_codes[where] == codes) & (self.moving_seen[where] > self.scans - self.memory_scans)

    def insert(self, points: np.ndarray, normals: np.ndarray, centre: np.ndarray) -> int:
        """Add points (odometry frame) with their normals in voxels not yet occupied (one observation each), then
        crop to the window around `centre`; returns how many voxels were added."""
        new = self.new_voxels(points)
        if len(new):
            self.stored_points = np.concatenate([self.stored_points, np.asarray(points, np.float32).take(new, axis=0)])
            self.stored_normals = np.concatenate([self.stored_normals, np.asarray(normals, np.float32).take(new, axis=0)])
            self.codes = np.concatenate([self.codes, voxel_codes(np.asarray(points).take(new, axis=0), self.config.voxel)])
            self.evidence = np.concatenate([self.evidence, np.ones(len(new), np.int16)])
            self.first = np.concatenate([self.first, np.full(len(new), self.scans, np.int32)])
            self.confirmed = np.concatenate([self.confirmed, np.full(len(new), self.config.confirm <= 1)])
        self.crop(centre)
        self._changed_since_build += len(new)
        return len(new)

    def clear(self, scan: np.ndarray, pose: np.ndarray) -> int:
        """Free-space clearing by one scan (sensor frame, at `pose`: odometry <- sensor): voxels its beams pass
        through lose evidence, and those left with none (and unconfirmed ones past their window) leave the map;
        returns how many left."""
        keep = np.ones(len(self.codes), bool)
        if self.config.confirm > 1:
            keep &= self.confirmed | (self.scans - self.first < self.config.confirm_window)
        if self.config.clear_cell > 0 and len(scan) and len(self.codes):
            if self.cell is None:
                self.cell = self.config.clear_cell * covered_angular_spacing(scan)
            image = RangeImage.build(scan, self.cell)
            inverse = invert(pose)
            local = self.stored_points @ inverse[:3, :3].T.astype(np.float32) + inverse[:3, 3].astype(np.float32)
            near = np.flatnonzero(np.einsum("ij,ij->i", local, local) < image.farthest ** 2)
            through = near[image.seen_through(local.take(near, axis=0),
                                              self.stored_normals.take(near, axis=0) @ pose[:3, :3].astype(np.float32),
                                              self.config.voxel * np.sqrt(3.0))]
            self.evidence[through] -= self.config.miss_weight
            gone = through[self.evidence[through] <= 0]
            keep[gone] = False
            self.cleared += len(gone)
        if not keep.all():
            self._changed_since_build += int((~keep).sum())
            self._select(keep)
        return int((~keep).sum())

    def crop(self, centre: np.ndarray) -> None:
        """Keep the voxels within the radius of `centre`, and at most max_voxels of them (nearest first)."""
        distance = np.linalg.norm(self.stored_points[:, :2] - np.asarray(centre, np.float32)[:2], axis=1)
        keep = distance <= self.config.radius
        if keep.sum() > self.config.max_voxels:
            keep = np.zeros(len(distance), bool)
            keep[np.argpartition(distance, self.config.max_voxels - 1)[: self.config.max_voxels]] = True
        if not keep.all():
            self._select(keep)

    def _select(self, keep: np.ndarray) -> None:
        """Keep only the voxels `keep` marks."""
        self.stored_points = np.compress(keep, self.stored_points, axis=0)  # 4x faster than boolean indexing of rows
        self.stored_normals = np.compress(keep, self.stored_normals, axis=0)
        self.codes, self.evidence, self.first = self.codes[keep], self.evidence[keep], self.first[keep]
        self.confirmed = self.confirmed[keep]

    def target(self) -> PlaneTarget:
        """Every voxel held (confirmed or not) as a registration target; its KD-tree is rebuilt once `refresh` of the
        map changed (voxels that left the window stay in it until then: they are still true surfaces)."""
        if self._target is None or self._changed_since_build > self.config.refresh * max(len(self._target), 1):
            self._target = PlaneTarget.build(self.stored_points, self.stored_normals)
            self._changed_since_build = 0
        return self._target
