"""Oriented boxes of point sets: the minimum-area rectangle of the points' footprint (rotating calipers)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ssf_common.geometry.labels import ragged_arange


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
    hull = footprint_hull(xy)
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


def footprint_hull(xy: np.ndarray) -> np.ndarray:
    """The convex hull's vertices of 2-D points, in order; the points as they come where they are too few or collinear."""
    if len(xy) >= 3:
        try:
            return xy[ConvexHull(xy).vertices]
        except QhullError:  # collinear or repeated points
            return xy
    return xy


def bounding_boxes(points: np.ndarray, labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """bounding_box of every label's points at once (labels 0..count-1, none empty): centres (count, 3), sizes
    (count, 3) and yaws (count,). The hulls come one by one; the calipers' candidate headings of all hulls are scored
    together, which is what a box per call spends most of its time on."""
    points = np.asarray(points, dtype=np.float64)
    if count == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    order = np.argsort(labels, kind="stable")
    grouped = points[order]
    starts = np.searchsorted(np.asarray(labels)[order], np.arange(count + 1))
    hulls = [footprint_hull(grouped[lo:hi, :2]) for lo, hi in zip(starts[:-1], starts[1:])]
    corners = np.array([len(hull) for hull in hulls])
    hull = np.concatenate(hulls)
    owner = np.repeat(np.arange(count), corners)
    first = np.repeat(np.cumsum(corners) - corners, corners)
    vertex = np.arange(len(hull))
    following = np.where(vertex + 1 < first + corners[owner], vertex + 1, first)  # each hull closes on itself
    edges = hull[following] - hull
    angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)  # one candidate heading per hull edge
    c, s = np.cos(angles), np.sin(angles)
    tried = np.repeat(vertex, corners[owner])  # every candidate against every vertex of its own hull
    against = first[tried] + ragged_arange(corners[owner])
    u = hull[against, 0] * c[tried] + hull[against, 1] * s[tried]
    v = hull[against, 1] * c[tried] - hull[against, 0] * s[tried]
    runs = np.cumsum(corners[owner]) - corners[owner]
    low_u, high_u = np.minimum.reduceat(u, runs), np.maximum.reduceat(u, runs)
    low_v, high_v = np.minimum.reduceat(v, runs), np.maximum.reduceat(v, runs)
    ranked = np.lexsort((angles, (high_u - low_u) * (high_v - low_v), owner))  # least area, then least heading
    best = ranked[np.searchsorted(owner[ranked], np.arange(count))]
    centre_u, centre_v = (low_u[best] + high_u[best]) / 2, (low_v[best] + high_v[best]) / 2
    cb, sb = c[best], s[best]
    sides = np.stack([high_u[best] - low_u[best], high_v[best] - low_v[best]], axis=1)
    yaws = angles[best].copy()
    across = sides[:, 1] > sides[:, 0]
    sides[across] = sides[across, ::-1]
    yaws[across] += np.pi / 2
    yaws = (yaws + np.pi / 2) % np.pi - np.pi / 2
    low_z, high_z = np.minimum.reduceat(grouped[:, 2], starts[:-1]), np.maximum.reduceat(grouped[:, 2], starts[:-1])
    centres = np.stack([centre_u * cb - centre_v * sb, centre_u * sb + centre_v * cb, (low_z + high_z) / 2], axis=1)
    return centres, np.column_stack([sides, high_z - low_z]), yaws


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
