"""Oriented boxes of point sets: the minimum-area rectangle of the points' footprint (rotating calipers)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import ConvexHull, QhullError


class Box(NamedTuple):
    """An upright box: centre (x, y, z), size (length >= width, height), heading of the length axis (rad)."""

    centre: np.ndarray  # (3,)
    size: np.ndarray  # (3,)
    yaw: float


def min_area_rectangle(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre (2,), sides (length >= width) and heading in [-pi/2, pi/2) of the smallest rectangle around xy."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        return np.zeros(2), np.zeros(2), 0.0
    hull = xy
    if len(xy) >= 3:
        try:
            hull = xy[ConvexHull(xy).vertices]
        except QhullError:  # collinear or repeated points
            hull = xy
    edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    angles = angles if angles.size else np.zeros(1)
    c, s = np.cos(angles), np.sin(angles)
    u = hull @ np.stack([c, s])  # (hull, angles): coordinates along each candidate axis
    v = hull @ np.stack([-s, c])
    area = (u.max(0) - u.min(0)) * (v.max(0) - v.min(0))
    best = int(np.argmin(area))
    lo_u, hi_u, lo_v, hi_v = u[:, best].min(), u[:, best].max(), v[:, best].min(), v[:, best].max()
    centre_uv = np.array([(lo_u + hi_u) / 2, (lo_v + hi_v) / 2])
    axis_u, axis_v = np.array([c[best], s[best]]), np.array([-s[best], c[best]])
    centre = centre_uv[0] * axis_u + centre_uv[1] * axis_v
    sides, yaw = np.array([hi_u - lo_u, hi_v - lo_v]), float(angles[best])
    if sides[1] > sides[0]:
        sides, yaw = sides[::-1], yaw + np.pi / 2
    yaw = float((yaw + np.pi / 2) % np.pi - np.pi / 2)
    return centre, sides, yaw


def bounding_box(points: np.ndarray) -> Box:
    """The upright box of a point set: minimum-area footprint, z from the lowest to the highest point."""
    points = np.asarray(points, dtype=np.float64)
    centre_xy, sides, yaw = min_area_rectangle(points[:, :2])
    low, high = (points[:, 2].min(), points[:, 2].max()) if len(points) else (0.0, 0.0)
    return Box(np.array([centre_xy[0], centre_xy[1], (low + high) / 2]), np.array([sides[0], sides[1], high - low]), yaw)


def box_corners(centre: np.ndarray, length: float, width: float, yaw: float) -> np.ndarray:
    """The 4 footprint corners (4, 2) of a box, counter-clockwise."""
    c, s = np.cos(yaw), np.sin(yaw)
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [length / 2, width / 2]
    return np.asarray(centre)[:2] + half @ np.array([[c, s], [-s, c]])


def boxes_corners(centres: np.ndarray, lengths: np.ndarray, widths: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """The footprint corners (M, 4, 2) of M boxes at once, counter-clockwise (box_corners for many)."""
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, np.shape(centres)[-1])[:, :2]
    c, s = np.cos(yaws), np.sin(yaws)
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
    along = half[None, :, 0] * (np.asarray(lengths) / 2)[:, None]  # (M, 4) along the length axis
    across = half[None, :, 1] * (np.asarray(widths) / 2)[:, None]
    return centres[:, None, :] + np.stack([along * c[:, None] - across * s[:, None],
                                           along * s[:, None] + across * c[:, None]], axis=-1)
