"""2-D footprints (oriented rectangles, circles): exact distances and overlap tests, vectorised over pairs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rectangles:
    """Oriented rectangles: centre (N,2), yaw (N,), length along heading (N,), width (N,)."""

    centre: np.ndarray
    yaw: np.ndarray
    length: np.ndarray
    width: np.ndarray

    def corners(self) -> np.ndarray:
        """Corners (N, 4, 2) in counter-clockwise order."""
        half = np.stack([self.length / 2, self.width / 2], -1)
        signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], np.float64)
        local = signs[None] * half[:, None, :]
        cos, sin = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        return (
            np.stack([cos * local[..., 0] - sin * local[..., 1], sin * local[..., 0] + cos * local[..., 1]], -1)
            + self.centre[:, None, :]
        )

    def take(self, index: np.ndarray) -> Rectangles:
        """A subset (or repetition) of the rectangles."""
        return Rectangles(self.centre[index], self.yaw[index], self.length[index], self.width[index])


def point_rectangle_distance(points: np.ndarray, rects: Rectangles) -> np.ndarray:
    """Distance from each point (N,2) or (N,K,2) to its rectangle (0 inside)."""
    offset = points - (rects.centre if points.ndim == 2 else rects.centre[:, None, :])
    cos, sin = np.cos(rects.yaw), np.sin(rects.yaw)
    if points.ndim == 3:
        cos, sin = cos[:, None], sin[:, None]
        half_l, half_w = rects.length[:, None] / 2, rects.width[:, None] / 2
    else:
        half_l, half_w = rects.length / 2, rects.width / 2
    local_x = cos * offset[..., 0] + sin * offset[..., 1]
    local_y = -sin * offset[..., 0] + cos * offset[..., 1]
    dx = np.maximum(np.abs(local_x) - half_l, 0.0)
    dy = np.maximum(np.abs(local_y) - half_w, 0.0)
    return np.hypot(dx, dy)


def rectangles_overlap(a: Rectangles, b: Rectangles) -> np.ndarray:
    """Separating-axis test for pairs of rectangles (a[i], b[i])."""
    ca, cb = a.corners(), b.corners()
    overlap = np.ones(len(a.centre), bool)
    for yaws in (a.yaw, b.yaw):
        for angle in (yaws, yaws + np.pi / 2):
            axis = np.stack([np.cos(angle), np.sin(angle)], -1)[:, None, :]
            pa, pb = (ca * axis).sum(-1), (cb * axis).sum(-1)
            overlap &= (pa.max(1) > pb.min(1)) & (pb.max(1) > pa.min(1))
    return overlap


def rectangle_distance(a: Rectangles, b: Rectangles) -> np.ndarray:
    """Distance between pairs of rectangles (a[i], b[i]), 0 where they overlap."""
    vertex_to_b = point_rectangle_distance(a.corners(), b).min(1)
    vertex_to_a = point_rectangle_distance(b.corners(), a).min(1)
    distance = np.minimum(vertex_to_a, vertex_to_b)
    return np.where(rectangles_overlap(a, b), 0.0, distance)


def rectangle_circle_distance(rects: Rectangles, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Distance between pairs (rectangle i, circle i), 0 where they overlap."""
    return np.maximum(point_rectangle_distance(centres, rects) - radii, 0.0)


def circle_distance(ca: np.ndarray, ra: np.ndarray, cb: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Distance between pairs of circles, 0 where they overlap."""
    return np.maximum(np.linalg.norm(ca - cb, axis=-1) - ra - rb, 0.0)


@dataclass(frozen=True)
class DiscCover:
    """Discs covering each footprint: owner agent, offset along the heading, radius."""

    owner: np.ndarray
    offset: np.ndarray
    radius: np.ndarray

    def centres(self, position: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """Disc centres (D, 2) for agent positions (N, 2) and yaws (N,)."""
        heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)[self.owner]
        return position[self.owner] + self.offset[:, None] * heading


def rectangle_cover(length: np.ndarray, width: np.ndarray, owner: np.ndarray) -> DiscCover:
    """Three discs along each rectangle that together contain it."""
    offsets = np.stack([-length / 3, np.zeros_like(length), length / 3], 1).reshape(-1)
    radius = np.repeat(np.hypot(length / 6, width / 2), 3)
    return DiscCover(np.repeat(owner, 3), offsets, radius)
