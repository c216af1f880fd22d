"""Collision avoidance the RDA way: each obstacle a convex polygon (its box) moving with constant velocity, and per
obstacle and horizon step the dual variables of the distance between it and the ego footprint.

For two convex polygons the RDA dual problem (max over lambda, mu >= 0 with ||A^T lambda|| <= 1 and
G^T mu + R^T A^T lambda = 0 of lambda^T (A p - b) - g^T mu) has a closed-form optimum: n = A^T lambda is the unit
direction that separates the two shapes the most, i.e. the direction between their closest points (or, when they
overlap, the axis of least penetration), and its value is their signed distance. With n fixed, the distance bound
is linear in the ego position: n . p >= h_O(n) + h_R(yaw, n) + d, where h_O and h_R are the support functions of
obstacle and footprint. That is what the primal problem constrains; the dual step recomputes n from the new plan.
The footprint's support depends on the heading too (a car turning away swings its rear the other way), so the bound
is kept per footprint corner, n . (p + R(yaw) c) >= h_O(n) + d, linearised in yaw at the planned heading, for the
BINDING_CORNERS corners nearest the obstacle along n (two: a side-on car's nearest side has two equal corners). The
primal problem keeps the bound at the planned heading as well, so that a turn may cost distance but never buys it (a
linearised turn that seems to buy it would let the car spin in place away from a box)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.boxes import boxes_corners
from ssf_common.geometry.reductions import vector_lengths
from ssf_common.records import Obstacles

INACTIVE_OFFSET = -1.0e4  # n = 0, offset far below: the constraint of an empty slot always holds
BINDING_CORNERS = 2  # footprint corners per obstacle and step whose distance bound the primal problem keeps


class Hyperplanes(NamedTuple):
    """Per horizon step and obstacle slot: unit normal n (T, K, 2), per binding corner a yaw gain g (T, K, C) and
    offset c (T, K, C), current distance (T, K) and the ego's speed towards the obstacle (T, K); the ego position p
    and heading yaw must satisfy n . p + g yaw >= c + d for every corner to keep distance d."""

    normals: np.ndarray
    yaw_gains: np.ndarray
    offsets: np.ndarray
    distances: np.ndarray
    closing: np.ndarray


def footprint_corners(xy: np.ndarray, yaw: np.ndarray, length: float, width: float) -> np.ndarray:
    """(T, 4, 2) corners of the ego footprint at positions (T, 2) and headings (T,), counter-clockwise."""
    count = len(xy)
    return boxes_corners(xy, np.full(count, length), np.full(count, width), np.asarray(yaw, dtype=np.float64))


def predicted_corners(obstacles: Obstacles, times: np.ndarray, static_speed: float) -> np.ndarray:
    """(T, M, 4, 2) footprints at times (s after the obstacles' stamp), moved with constant velocity; obstacles
    slower than static_speed stay where they are."""
    moving = np.linalg.norm(obstacles.velocities[:, :2], axis=1) > static_speed
    velocities = np.where(moving[:, None], obstacles.velocities[:, :2], 0.0)
    now = boxes_corners(obstacles.centres, obstacles.sizes[:, 0], obstacles.sizes[:, 1], obstacles.yaws)
    return now[None] + np.asarray(times, dtype=np.float64)[:, None, None, None] * velocities[None, :, None, :]


def within_range(obstacles: Obstacles, xy: np.ndarray, time: float, max_range: float, static_speed: float) -> np.ndarray:
    """Indices of the obstacles whose centre, moved on to `time`, lies within max_range of xy."""
    moving = np.linalg.norm(obstacles.velocities[:, :2], axis=1) > static_speed
    centres = obstacles.centres[:, :2] + np.where(moving[:, None], obstacles.velocities[:, :2], 0.0) * time
    return np.flatnonzero(np.linalg.norm(centres - xy, axis=1) <= max_range)


def nearest_first(obstacles: Obstacles, xy: np.ndarray, count: int) -> tuple[Obstacles, int]:
    """At most `count` obstacles, those whose boxes come nearest to `xy` (centre distance less half the box's
    diagonal), chosen in linear time (np.argpartition, unordered), and how many were dropped."""
    dropped = len(obstacles) - count
    if dropped <= 0:
        return obstacles, 0
    reach = np.linalg.norm(obstacles.centres[:, :2] - np.asarray(xy, dtype=np.float64)[:2], axis=1)
    reach -= 0.5 * np.hypot(obstacles.sizes[:, 0], obstacles.sizes[:, 1])
    return obstacles.take(np.sort(np.argpartition(reach, count - 1)[:count])), dropped


def nearest_obstacles(corners: np.ndarray, ego_xy: np.ndarray, ego_radius: float, count: int, max_range: float) -> np.ndarray:
    """Indices of up to `count` obstacles nearest to the planned motion: smallest gap, over the horizon, between
    each obstacle's predicted footprint and the ego's planned position at the same time (nearest first)."""
    if corners.shape[1] == 0 or count == 0:
        return np.zeros(0, np.int64)
    centres = corners.mean(axis=2)  # (T, M, 2)
    radii = np.linalg.norm(corners - centres[:, :, None, :], axis=3).max(axis=2)
    gaps = np.linalg.norm(centres - ego_xy[:, None, :], axis=2) - radii - ego_radius  # (T, M)
    in_range = np.linalg.norm(centres[0] - ego_xy[0], axis=1) <= max_range
    nearest = gaps.min(axis=0)
    order = np.argsort(np.where(in_range, nearest, np.inf), kind="stable")
    return order[: min(count, int(in_range.sum()))]


def _support(corners: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """max over each polygon's corners of n . corner: corners (..., 4, 2), normals (..., C, 2) -> (..., C)."""
    return np.einsum("...vi,...ci->...cv", corners, normals).max(axis=-1)


def _point_edge_vectors(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(..., P, E, 2) vectors from the nearest point of each polygon edge to each point."""
    edge = np.roll(polygon, -1, axis=-2) - polygon  # (..., E, 2)
    offset = points[..., :, None, :] - polygon[..., None, :, :]  # (..., P, E, 2)
    length = np.maximum(np.sum(edge * edge, axis=-1), 1e-12)[..., None, :]
    t = np.clip(np.sum(offset * edge[..., None, :, :], axis=-1) / length, 0.0, 1.0)
    return offset - t[..., None] * edge[..., None, :, :]


def _closest_direction(ego: np.ndarray, obstacle: np.ndarray) -> np.ndarray:
    """(..., 2) unit vector from the obstacle's closest point to the ego's (vertex-to-edge distances both ways)."""
    vectors = np.concatenate([_point_edge_vectors(ego, obstacle).reshape(ego.shape[:-2] + (-1, 2)),
                              -_point_edge_vectors(obstacle, ego).reshape(ego.shape[:-2] + (-1, 2))], axis=-2)
    gaps = np.sum(vectors * vectors, axis=-1)
    best = np.take_along_axis(vectors, gaps.argmin(axis=-1)[..., None, None], axis=-2)[..., 0, :]
    length = np.linalg.norm(best, axis=-1, keepdims=True)
    return np.where(length > 1e-9, best / np.maximum(length, 1e-12), 0.0)


def separation(ego: np.ndarray, obstacle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dual optimum for footprints ego (..., 4, 2) and obstacle (..., 4, 2): the unit direction n (..., 2) from
    the obstacle towards the ego that separates them most, and their signed distance along it (negative: overlap)."""
    axes = []
    for polygon in (ego, obstacle):
        edge = np.roll(polygon, -1, axis=-2) - polygon
        for e in (0, 1):  # a rectangle has two edge directions; both normals and their opposites are candidates
            normal = np.stack([edge[..., e, 1], -edge[..., e, 0]], axis=-1)
            normal = normal / np.maximum(vector_lengths(normal)[..., None], 1e-12)
            axes += [normal, -normal]
    axes.append(_closest_direction(ego, obstacle))
    candidates = np.stack(axes, axis=-2)  # (..., C, 2)
    value = -_support(ego, -candidates) - _support(obstacle, candidates)  # min over ego - max over obstacle
    valid = vector_lengths(candidates) > 0.5
    value = np.where(valid, value, -np.inf)
    best = value.argmax(axis=-1)
    normal = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    return normal, np.take_along_axis(value, best[..., None], axis=-1)[..., 0]


def in_path(ego_xy: np.ndarray, heading: np.ndarray, width: float, corners: np.ndarray, band: float) -> np.ndarray:
    """Per step (T) and obstacle (M): whether its footprint reaches within `band` of the strip the car sweeps along its
    heading (a car in the next lane does not; one cutting in does, at the steps it is predicted there)."""
    left = np.stack([-heading[:, 1], heading[:, 0]], axis=1)
    lateral = np.einsum("tmvi,ti->tmv", corners - ego_xy[:, None, None, :], left)
    reach = width / 2 + band
    return (lateral.min(axis=-1) < reach) & (lateral.max(axis=-1) > -reach)


def hyperplanes(ego_xy: np.ndarray, ego_yaw: np.ndarray, ego_speed: np.ndarray, length: float, width: float,
                corners: np.ndarray, slots: int, band: float | None = None,
                lanes_kept: np.ndarray | None = None) -> Hyperplanes:
    """The dual step: for each horizon step (T) and obstacle (M <= slots), the separating direction between the
    planned footprint and the predicted obstacle, as a constraint on the ego position (padded to `slots`); the closing
    speed counts only for obstacles within `band` (m) of the car's path (its sides carried along its heading; None:
    for every obstacle), for those that keep their lanes (`lanes_kept` (M,): vehicles; default all); a person beside
    the path may step into it at once, so the closing speed always counts for them."""
    steps, count = len(ego_xy), corners.shape[1]
    normals = np.zeros((steps, slots, 2))
    yaw_gains = np.zeros((steps, slots, BINDING_CORNERS))
    offsets = np.full((steps, slots, BINDING_CORNERS), INACTIVE_OFFSET)
    distances = np.full((steps, slots), np.inf)
    closing = np.zeros((steps, slots))
    if count:
        ego = footprint_corners(ego_xy, ego_yaw, length, width)
        normal, distance = separation(np.broadcast_to(ego[:, None], corners.shape), corners)
        # per corner o = R(yaw) c: n . p + n . o(yaw) >= h_O(n) + d, with n . o linearised in yaw at the planned one
        arms = ego - ego_xy[:, None, :]  # (T, 4, 2)
        reach = np.einsum("tvi,tmi->tmv", arms, normal)  # n . o per corner (T, M, 4)
        turn = np.einsum("tvi,tmi->tmv", np.stack([-arms[..., 1], arms[..., 0]], axis=-1), normal)  # d(n . o)/dyaw
        binding = np.argsort(reach, axis=-1, kind="stable")[..., :BINDING_CORNERS]  # nearest the obstacle first
        reach, turn = np.take_along_axis(reach, binding, axis=-1), np.take_along_axis(turn, binding, axis=-1)
        obstacle_support = np.einsum("tmvi,tmi->tmv", corners, normal).max(axis=-1)
        normals[:, :count] = normal
        yaw_gains[:, :count] = turn
        offsets[:, :count] = obstacle_support[..., None] - reach + turn * np.asarray(ego_yaw)[:, None, None]
        distances[:, :count] = distance
        heading = np.stack([np.cos(ego_yaw), np.sin(ego_yaw)], axis=1)
        closing[:, :count] = np.maximum(-np.einsum("tmi,ti->tm", normal, heading), 0.0) * np.maximum(ego_speed, 0.0)[:, None]
        if band is not None:
            kept = np.ones(count, dtype=bool) if lanes_kept is None else np.asarray(lanes_kept, dtype=bool)
            closing[:, :count] *= in_path(ego_xy, heading, width, corners, band) | ~kept[None, :]
    return Hyperplanes(normals, yaw_gains, offsets, distances, closing)
