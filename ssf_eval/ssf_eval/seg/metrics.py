"""Segmentation metrics as small pure functions: static/dynamic accuracy, moving-class IoU, instance precision /
recall / F1 / PQ at IoU >= 0.5 (OGC's protocol), and obstacle errors against the true objects."""

from __future__ import annotations

from typing import Iterable, NamedTuple

import numpy as np

from ssf_common.dataset.pairs import ScanPair
from ssf_common.geometry.se3 import invert
from ssf_common.records import ObstacleKind, Obstacles, Segmentation

MIN_OBJECT_POINTS = 50  # true objects with fewer points are ignored (OGC)
MATCH_IOU = 0.5


class SegCounts(NamedTuple):
    """Counts that pool over frames: motion confusion, instance matches, and the IoU mass of the matches."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    instance_tp: int = 0
    instance_fp: int = 0
    instance_fn: int = 0
    matched_iou: float = 0.0

    def __add__(self, other: SegCounts) -> SegCounts:  # type: ignore[override]
        return SegCounts(*(a + b for a, b in zip(self, other)))


class SegScores(NamedTuple):
    """The segmentation table's columns (NaN where undefined)."""

    accuracy: float
    balanced_accuracy: float
    moving_iou: float
    precision: float
    recall: float
    f1: float
    pq: float
    points: int
    objects: int


def _ratio(num: float, den: float) -> float:
    return float(num / den) if den else float("nan")


def motion_counts(predicted: np.ndarray, truth: np.ndarray) -> tuple[int, int, int, int]:
    """TP, FP, FN, TN of the moving class."""
    predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
    return (int(np.sum(predicted & truth)), int(np.sum(predicted & ~truth)), int(np.sum(~predicted & truth)),
            int(np.sum(~predicted & ~truth)))


def instance_counts(predicted: np.ndarray, truth: np.ndarray, true_dynamic: np.ndarray,
                    min_points: int = MIN_OBJECT_POINTS) -> tuple[int, int, int, float]:
    """TP, FP, FN and summed IoU of the matches between predicted instances (>0) and true moving objects.

    True objects under min_points are ignored, and so are predictions lying mostly on them; a match needs IoU >= 0.5
    (which makes it one-to-one)."""
    predicted, truth = np.asarray(predicted), np.where(np.asarray(true_dynamic, bool), np.asarray(truth), 0)
    objects, sizes = np.unique(truth[truth > 0], return_counts=True)
    counted = set(objects[sizes >= min_points].tolist())
    ignored = set(objects[sizes < min_points].tolist())
    tp = fp = 0
    iou_sum = 0.0
    matched: set[int] = set()
    for k in np.unique(predicted[predicted > 0]):
        mine = predicted == k
        owners, overlap = np.unique(truth[mine], return_counts=True)
        best = int(owners[np.argmax(overlap)])
        if best in ignored:
            continue
        iou = overlap.max() / np.count_nonzero(mine | (truth == best)) if best in counted else 0.0
        if iou >= MATCH_IOU:
            tp, iou_sum = tp + 1, iou_sum + iou
            matched.add(best)
        else:
            fp += 1
    return tp, fp, len(counted - matched), float(iou_sum)


def seg_counts(segmentation: Segmentation, pair: ScanPair) -> SegCounts:
    """The counts of one segmentation of scan t against the pair's truth."""
    return SegCounts(*motion_counts(segmentation.dynamic, pair.dynamic1),
                     *instance_counts(segmentation.instance, pair.instance1, pair.dynamic1))


def seg_scores(counts: SegCounts) -> SegScores:
    """Scores of pooled counts."""
    c = counts
    recall_moving, recall_static = _ratio(c.tp, c.tp + c.fn), _ratio(c.tn, c.tn + c.fp)
    precision, recall = _ratio(c.instance_tp, c.instance_tp + c.instance_fp), _ratio(c.instance_tp, c.instance_tp + c.instance_fn)
    f1 = _ratio(2 * c.instance_tp, 2 * c.instance_tp + c.instance_fp + c.instance_fn)
    pq = _ratio(c.matched_iou, c.instance_tp + 0.5 * c.instance_fp + 0.5 * c.instance_fn)
    balanced = float(np.nanmean([recall_moving, recall_static])) if not np.isnan([recall_moving, recall_static]).all() else float("nan")
    return SegScores(_ratio(c.tp + c.tn, c.tp + c.fp + c.fn + c.tn), balanced, _ratio(c.tp, c.tp + c.fp + c.fn),
                     precision, recall, f1, pq, c.tp + c.fp + c.fn + c.tn, c.instance_tp + c.instance_fn)


class ObstacleErrors(NamedTuple):
    """Obstacle errors pooled over frames (lists of per-match errors and counts)."""

    position: tuple[float, ...] = ()
    velocity: tuple[float, ...] = ()
    true_objects: int = 0
    missed: int = 0
    phantoms: int = 0
    frames: int = 0
    yaw: tuple[float, ...] = ()  # degrees, modulo the true footprint's symmetry
    yaw_vehicle: tuple[float, ...] = ()  # the same, vehicles only

    def __add__(self, other: ObstacleErrors) -> ObstacleErrors:  # type: ignore[override]
        return ObstacleErrors(*(mine + theirs for mine, theirs in zip(self, other)))

    def summary(self) -> dict[str, float]:
        """Median errors, miss share, phantoms per 10 frames, and yaw errors (median, share over 30 degrees)."""
        return {"position_m_median": _median(self.position), "velocity_mps_median": _median(self.velocity),
                "missed_ratio": _ratio(self.missed, self.true_objects),
                "phantoms_per_10_frames": _ratio(10 * self.phantoms, self.frames),
                "true_objects": self.true_objects, "matches": len(self.velocity),
                "yaw_deg_median": _median(self.yaw), "yaw_over_30deg_ratio": _ratio(sum(e > 30 for e in self.yaw), len(self.yaw)),
                "yaw_deg_median_vehicles": _median(self.yaw_vehicle),
                "yaw_over_30deg_ratio_vehicles": _ratio(sum(e > 30 for e in self.yaw_vehicle), len(self.yaw_vehicle))}


def _median(values: tuple[float, ...]) -> float:
    """Median, NaN of nothing."""
    return float(np.median(values)) if values else float("nan")


def yaw_error(estimate: float, truth: float, length: float, width: float) -> float:
    """Degrees between two box headings, modulo the true footprint's symmetry (180 degrees; 90 for a square)."""
    period = np.pi / 2 if np.isclose(length, width, rtol=1e-3) else np.pi
    return float(np.degrees(abs((estimate - truth + period / 2) % period - period / 2)))


def true_velocities(pair: ScanPair, dt: float) -> np.ndarray:
    """(N, 3) each point's own velocity (m/s) in scan t's axes, from the exact flow with the ego motion removed."""
    back = invert(pair.ego)
    return ((pair.pc1 + pair.flow) @ back[:3, :3].T + back[:3, 3] - pair.pc1) / dt


def obstacle_errors(obstacles: Obstacles, segmentation: Segmentation, pair: ScanPair, dt: float,
                    min_points: int = MIN_OBJECT_POINTS) -> ObstacleErrors:
    """Match each obstacle to the true object most of its points lie on; errors of the matches (centre, velocity,
    yaw), misses of true moving objects (>= min_points) and phantoms (obstacles mostly on static points)."""
    truth = np.where(pair.dynamic1, pair.instance1, 0)
    objects, sizes = np.unique(truth[truth > 0], return_counts=True)
    counted = set(objects[sizes >= min_points].tolist())
    velocities = true_velocities(pair, dt)
    objects1 = pair.objects1
    rows = {} if objects1 is None else {k: row for row, k in enumerate(objects1.ids.tolist())}
    position, velocity, yaw, yaw_vehicle, found, phantoms = [], [], [], [], set(), 0
    for index, k in enumerate(obstacles.ids):
        owners = truth[segmentation.instance == k]
        if owners.size == 0:
            continue
        best = int(np.bincount(owners).argmax())
        if best == 0:
            phantoms += 1
            continue
        if best not in counted or best in found:
            continue
        found.add(best)
        velocity.append(float(np.linalg.norm(obstacles.velocities[index, :2] - velocities[truth == best, :2].mean(axis=0))))
        if best in rows:
            row = rows[best]
            position.append(float(np.linalg.norm(obstacles.centres[index, :2] - objects1.centres[row, :2])))
            yaw.append(yaw_error(obstacles.yaws[index], objects1.yaws[row], *objects1.sizes[row, :2]))
            if objects1.kinds[row] == ObstacleKind.VEHICLE:
                yaw_vehicle.append(yaw[-1])
    return ObstacleErrors(tuple(position), tuple(velocity), len(counted), len(counted - found), phantoms, 1,
                          tuple(yaw), tuple(yaw_vehicle))


def pool(items: Iterable):
    """Sum of counts or errors."""
    items = list(items)
    total = items[0]
    for item in items[1:]:
        total = total + item
    return total
