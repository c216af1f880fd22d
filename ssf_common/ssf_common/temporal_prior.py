"""The temporal prior M^(0) of the fusion loop: a scan's segmentation, carried by its flow onto the next scan.

Split in two so that it can cross processes: the stage that finishes a scan keeps only what the next scan needs
(`prior_source`: the points near its moving objects, moved by their flow), and the flow stage carries that onto the
next scan's points (`carry_prior`). In process the two run back to back."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.neighbours import may_be_near, nearest
from ssf_common.records import PriorSource


def prior_source(stamp_ns: int, frame_id: str, points: np.ndarray, flow: np.ndarray, probability: np.ndarray,
                 radius: float) -> PriorSource:
    """The points of a scan moved by their flow, with their dynamic probability, where they may lie within 2 x radius
    of a moving one (probability > 0; a grid test, which keeps every such point and some farther ones): a point of the
    next scan within radius of a moving point finds its nearest moved point among them."""
    probability = np.asarray(probability, np.float32)
    moving = probability > 0.0
    if not moving.any() or radius <= 0:
        return PriorSource(stamp_ns, frame_id, np.zeros((0, 3), np.float32), np.zeros(0, np.float32), radius)
    moved = np.asarray(points, np.float64)[:, :3] + np.asarray(flow, np.float64)
    around = np.flatnonzero(may_be_near(moved[moving], moved, 2.0 * radius))
    return PriorSource(stamp_ns, frame_id, moved[around].astype(np.float32), probability[around], radius)


def carry_prior(source: PriorSource, next_points: np.ndarray) -> np.ndarray:
    """The dynamic probability of every point of the next scan: that of the nearest source point within the source's
    radius (0 where none lies there, or the nearest does not move)."""
    radius = source.radius
    prior = np.zeros(len(next_points), np.float32)
    moving = source.probability > 0.0
    if not moving.any() or radius <= 0 or len(next_points) == 0:
        return prior
    points = np.asarray(source.points, np.float64)
    following = np.asarray(next_points, np.float64)[:, :3]
    candidates = np.flatnonzero(may_be_near(points[moving], following, radius))  # only near a mover can one be nearest
    around = np.flatnonzero(may_be_near(following[candidates], points, radius))  # and only these source points
    found = nearest(points[around], following[candidates], radius)
    hit = np.isfinite(found.distance)
    prior[candidates[hit]] = source.probability[around[found.index[hit]]]
    return prior
