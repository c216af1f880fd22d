"""Map trails: the share of a map's voxels that lie where moving agents have been (their footprints, above the
ground, up to their height). A static map built from static points only should have almost none.

Two figures: `on_paths` counts every map voxel in a swept footprint, including those where an agent stands at the
moment the map is sampled (a queue of cars standing still is in the map as it is in the world); `left_behind`
counts only those where no agent stands at that moment: voxels an agent has left, the true trails of motion.

A map is put into the world voxel by voxel, each by the odometry's error when the voxel first appeared in it
(`MapPlacement`): a map's voxels never move once inserted, so this puts each where the sensor saw it. Placing the
whole map by the latest pose instead adds the odometry's drift since then to every voxel (0.6 deg of pitch lifts
the road 50 m away by 0.5 m into the agents' paths), which the pose errors already score."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.sampling import voxel_keys
from ssf_common.geometry.se3 import invert
from ssf_common.records import Obstacles

CELL = 0.25  # m, grid of the swept footprints
GROUND_CLEARANCE = 0.2  # m: map points this close to an agent's base are the ground under it, not the agent
KEY_BITS = 31  # per axis of the footprint grid's codes


class SweptPaths:
    """Every cell any agent's footprint covered so far, with the lowest base and highest top seen there."""

    def __init__(self) -> None:
        self.codes = np.zeros(0, np.int64)
        self.base = np.zeros(0)
        self.top = np.zeros(0)

    def add(self, agents: Obstacles) -> None:
        """Sweep the agents' footprints (world frame, box centres at half height) into the cells."""
        if len(agents) == 0:
            return
        longest = float(max(agents.sizes[:, 0].max(), agents.sizes[:, 1].max()))
        steps = np.linspace(-0.5, 0.5, int(np.ceil(longest / (CELL / 2))) + 1)
        u, v = np.meshgrid(steps, steps, indexing="ij")
        local = np.stack([u.ravel(), v.ravel()], axis=1)  # (S, 2) in units of the box sides
        c, s = np.cos(agents.yaws), np.sin(agents.yaws)
        along = local[None, :, 0] * agents.sizes[:, None, 0]
        across = local[None, :, 1] * agents.sizes[:, None, 1]
        xy = np.stack([agents.centres[:, None, 0] + c[:, None] * along - s[:, None] * across,
                       agents.centres[:, None, 1] + s[:, None] * along + c[:, None] * across], axis=2).reshape(-1, 2)
        base = np.repeat(agents.centres[:, 2] - agents.sizes[:, 2] / 2, local.shape[0])
        top = np.repeat(agents.centres[:, 2] + agents.sizes[:, 2] / 2, local.shape[0])
        codes = np.concatenate([self.codes, voxel_keys(xy, CELL, KEY_BITS)])
        base, top = np.concatenate([self.base, base]), np.concatenate([self.top, top])
        self.codes, inverse = np.unique(codes, return_inverse=True)
        self.base = np.full(len(self.codes), np.inf)
        self.top = np.full(len(self.codes), -np.inf)
        np.minimum.at(self.base, inverse, base)
        np.maximum.at(self.top, inverse, top)

    def on_paths(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: world points inside a swept footprint, above the ground under it and below the agent's top."""
        if len(self.codes) == 0 or len(points) == 0:
            return np.zeros(len(points), bool)
        codes = voxel_keys(np.asarray(points)[:, :2], CELL, KEY_BITS)
        where = np.minimum(np.searchsorted(self.codes, codes), len(self.codes) - 1)
        inside = self.codes[where] == codes
        z = np.asarray(points)[:, 2]
        return inside & (z > self.base[where] + GROUND_CLEARANCE) & (z <= self.top[where] + 0.1)


def standing_now(points: np.ndarray, agents: Obstacles) -> np.ndarray:
    """(N,) bool: world points inside the footprint of an agent where it stands now (`agents`: one moment), above
    the ground under it and below its top, on the same grid as `SweptPaths`."""
    now = SweptPaths()
    now.add(agents)
    return now.on_paths(points)


def left_behind(points: np.ndarray, paths: SweptPaths, agents: Obstacles) -> tuple[np.ndarray, np.ndarray]:
    """Map voxels (world points) on agents' paths, and those of them where no agent stands now: (N,) bool each."""
    on = paths.on_paths(points)
    left = on.copy()
    if on.any():
        left[on] = ~standing_now(np.asarray(points)[on], agents)
    return on, left


def point_keys(points: np.ndarray) -> np.ndarray:
    """(N,) uint64: a hash of each point's float32 coordinates (a stored map point keeps its exact bits)."""
    bits = np.ascontiguousarray(np.asarray(points, np.float32)[:, :3]).view(np.uint32).astype(np.uint64)
    return (bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) ^ bits[:, 2]


class MapPlacement:
    """Puts one map's points (odometry frame) into the world, each by the `world <- odometry` transform (truth times
    the inverse of the estimate) of the first sample that held it: where the sensor saw it, give or take the drift
    between two samples."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.uint64)  # sorted keys of the points held at the last sample
        self.placed_by = np.zeros(0, np.int64)  # per key, the index of its transform
        self.transforms: list[np.ndarray] = []

    def place(self, points: np.ndarray, world_from_odom: np.ndarray) -> np.ndarray:
        """(N, 3) world points; points not held at the last sample are placed by `world_from_odom`."""
        if len(points) == 0:
            return np.zeros((0, 3))
        points = np.asarray(points, np.float64)[:, :3]
        keys = point_keys(points)
        where = np.minimum(np.searchsorted(self.keys, keys), max(len(self.keys) - 1, 0))
        found = self.keys[where] == keys if len(self.keys) else np.zeros(len(keys), bool)
        placed_by = np.where(found, self.placed_by[where] if len(self.keys) else 0, len(self.transforms))
        if not found.all():
            self.transforms.append(np.asarray(world_from_odom, np.float64))
        order = np.argsort(keys)
        self.keys, self.placed_by = keys[order], placed_by[order]
        transforms = np.stack(self.transforms)[placed_by]
        return np.einsum("nij,nj->ni", transforms[:, :3, :3], points) + transforms[:, :3, 3]


def world_from_odometry(true_pose: np.ndarray, estimated_pose: np.ndarray) -> np.ndarray:
    """The transform that puts an odometry frame into the world at one scan: its true pose times its estimate's
    inverse."""
    return np.asarray(true_pose) @ invert(np.asarray(estimated_pose))
