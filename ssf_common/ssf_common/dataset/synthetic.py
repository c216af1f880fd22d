"""Synthetic scan pairs with exact flow: rough ground, walls, poles and moving boxes with known rigid motions."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.dataset.pairs import PointClass, ScanPair, make_pair
from ssf_common.geometry.se3 import make_pose as pose


class SyntheticBox(NamedTuple):
    """An upright box: centre (x, y, z of its base), size (length, width, height), yaw."""

    centre: np.ndarray
    size: np.ndarray
    yaw: float


def ground_height(xy: np.ndarray) -> np.ndarray:
    """A gently sloped ground with small undulations."""
    return 0.01 * xy[:, 0] + 0.08 * np.sin(0.3 * xy[:, 0]) * np.cos(0.23 * xy[:, 1])


def sample_ground(rng: np.random.Generator, count: int, centre: np.ndarray) -> np.ndarray:
    """Ground points around a sensor, denser near it (like LiDAR rings)."""
    radius = rng.uniform(3.0, 45.0, count)
    angle = rng.uniform(-np.pi, np.pi, count)
    xy = centre[:2] + np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    z = ground_height(xy) + rng.normal(0.0, 0.02, count)
    return np.column_stack([xy, z])


def sample_box(rng: np.random.Generator, box: SyntheticBox, count: int,
               viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Points on the sides and the top of a box, in world coordinates (only the sides facing `viewpoint`, as a
    LiDAR there would see them)."""
    length, width, height = box.size
    areas = np.array([length * height, length * height, width * height, width * height, length * width])
    if viewpoint is not None:
        c, s = np.cos(box.yaw), np.sin(box.yaw)
        local_view = np.array([[c, s], [-s, c]]) @ (viewpoint[:2] - box.centre[:2])
        outward = np.array([local_view[1] > 0, local_view[1] < 0, local_view[0] > 0, local_view[0] < 0, True])
        areas = areas * outward
    face = rng.choice(5, count, p=areas / areas.sum())
    u, v = rng.uniform(-0.5, 0.5, count), rng.uniform(0.0, 1.0, count)
    local = np.zeros((count, 3))
    sides = {0: (0, 1, 0.5), 1: (0, 1, -0.5), 2: (1, 0, 0.5), 3: (1, 0, -0.5)}
    for index, (free, fixed, sign) in sides.items():
        chosen = face == index
        local[chosen, free] = u[chosen] * box.size[free]
        local[chosen, fixed] = sign * box.size[fixed]
        local[chosen, 2] = v[chosen] * height
    top = face == 4
    local[top, 0] = u[top] * length
    local[top, 1] = (v[top] - 0.5) * width
    local[top, 2] = height
    return (pose(*box.centre, box.yaw) @ np.column_stack([local, np.ones(count)]).T).T[:, :3]


def scene_boxes(rng: np.random.Generator,
                agents: int) -> tuple[list[SyntheticBox], list[SyntheticBox], list[np.ndarray]]:
    """Static structure, moving agents and each agent's rigid motion (4x4, world frame) over one frame."""
    static = [SyntheticBox(np.array([x, side * rng.uniform(11.0, 14.0), 0.0]), np.array([rng.uniform(6, 12), 2.0, rng.uniform(4, 9)]), 0.0)
              for x in np.arange(-30.0, 45.0, 14.0) for side in (-1, 1)]
    static += [SyntheticBox(np.array([x, side * 8.5, 0.0]), np.array([0.3, 0.3, 5.0]), 0.0) for x in np.arange(-30.0, 45.0, 9.0) for side in (-1, 1)]
    moving, motions = [], []
    slots = [(x, lane) for lane in (-5.0, -1.75, 1.75, 5.0) for x in np.arange(-30.0, 40.0, 7.0)]
    for slot in rng.choice(len(slots), min(agents, len(slots)), replace=False):
        x, lane = slots[slot]
        yaw = (0.0 if lane > 0 else np.pi) + rng.normal(0.0, 0.05)
        centre = np.array([x + rng.uniform(-1.0, 1.0), lane + rng.normal(0.0, 0.2), 0.0])
        centre[2] = ground_height(centre[None, :2])[0]
        pedestrian = rng.random() < 0.25
        size = np.array([0.6, 0.6, 1.75]) if pedestrian else np.array([rng.uniform(3.8, 5.0), rng.uniform(1.7, 2.0), rng.uniform(1.4, 1.9)])
        speed = rng.uniform(0.05, 0.2) if pedestrian else rng.uniform(0.3, 1.6)
        turn = rng.normal(0.0, 0.03)
        box = SyntheticBox(centre, size, float(yaw))
        step = pose(*centre, yaw) @ pose(speed, 0.0, 0.0, turn) @ np.linalg.inv(pose(*centre, yaw))
        moving.append(box)
        motions.append(step)
    return static, moving, motions


def synthetic_pair(seed: int = 0, agents: int = 2, ego_step: float = 1.0, points: int = 8192) -> ScanPair:
    """A scan pair of a street with `agents` moving boxes; the ego moves `ego_step` metres along x."""
    rng = np.random.default_rng(seed)
    static, moving, motions = scene_boxes(rng, agents)
    pose1 = pose(0.0, 0.0, 1.8, 0.0)
    pose2 = pose(ego_step, 0.0, 1.8 + 0.01 * ego_step, rng.normal(0.0, 0.01))
    count_box = points // 2 // max(1, len(static) + len(moving))

    def scan(sensor: np.ndarray, moved: bool, generator: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        parts = [sample_ground(generator, points - count_box * (len(static) + len(moving)), sensor[:3, 3])]
        labels = [np.zeros(parts[0].shape[0], dtype=np.int32)]
        classes = [np.full(parts[0].shape[0], PointClass.GROUND, dtype=np.uint8)]
        for box in static:
            parts.append(sample_box(generator, box, count_box, sensor[:3, 3]))
            labels.append(np.zeros(count_box, dtype=np.int32))
            classes.append(np.full(count_box, PointClass.POLE if box.size[0] < 1.0 else PointClass.BUILDING, np.uint8))
        for index, (box, motion) in enumerate(zip(moving, motions), start=1):
            viewpoint = (np.linalg.inv(motion) @ sensor[:, 3])[:3] if moved else sensor[:3, 3]
            world = sample_box(generator, box, count_box, viewpoint)
            if moved:
                world = (motion @ np.column_stack([world, np.ones(len(world))]).T).T[:, :3]
            parts.append(world)
            labels.append(np.full(count_box, index, dtype=np.int32))
            classes.append(np.full(count_box, PointClass.PEDESTRIAN if box.size[0] < 1.0 else PointClass.VEHICLE, np.uint8))
        world = np.concatenate(parts) + generator.normal(0.0, 0.01, (sum(len(p) for p in parts), 3))
        local = (np.linalg.inv(sensor) @ np.column_stack([world, np.ones(len(world))]).T).T[:, :3]
        return local.astype(np.float32), np.concatenate(labels), np.concatenate(classes)

    pc1, instance1, class1 = scan(pose1, False, np.random.default_rng(seed + 1))
    pc2, _, _ = scan(pose2, True, np.random.default_rng(seed + 2))
    world1 = (pose1 @ np.column_stack([pc1, np.ones(len(pc1))]).T).T
    moved = world1.copy()
    for index, motion in enumerate(motions, start=1):
        on = instance1 == index
        moved[on] = (motion @ world1[on].T).T
    target = (np.linalg.inv(pose2) @ moved.T).T[:, :3]
    flow = (target - pc1).astype(np.float32)
    return make_pair(pc1, pc2, flow, instance1 > 0, instance1, class1, pose1, pose2)
