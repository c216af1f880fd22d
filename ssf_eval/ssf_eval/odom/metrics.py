"""Odometry metrics: RPE and ATE computed by evo (RMSE, SSE, STD as the paper reports them), and KITTI drift over
route segments (% of distance, deg per 100 m)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.se3 import invert, rotation_angle

KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP = 10  # first frames of the segments, as the KITTI development kit


class ErrorStats(NamedTuple):
    """Statistics of one error series as evo reports them (std: population)."""

    rmse: float
    sse: float
    std: float
    mean: float
    max: float


class Drift(NamedTuple):
    """KITTI drift: mean translational error in % of segment length and rotational error in deg per 100 m."""

    translation_pct: float
    rotation_deg_per_100m: float
    segments: int
    lengths: tuple[float, ...]


class EndError(NamedTuple):
    """Where the last pose is off (first scan's frame): position along the ground and in height, and the rotation
    error as roll, pitch and yaw in the vehicle's frame. Height is what roll and pitch drift turn into."""

    horizontal_m: float
    height_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class OdomScores(NamedTuple):
    """Every figure of one trajectory against ground truth."""

    rpe_translation: ErrorStats  # m, consecutive frames
    rpe_rotation: ErrorStats  # deg, consecutive frames
    ate: ErrorStats  # m, after SE(3) alignment
    drift: Drift
    endpoint_pct: float  # final position error as a share of the distance travelled
    distance: float  # m
    end: EndError


def evo_trajectory(poses: np.ndarray, stamps_s: np.ndarray):
    """An evo PoseTrajectory3D."""
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(poses_se3=[np.asarray(pose, dtype=np.float64) for pose in poses],
                            timestamps=np.asarray(stamps_s, dtype=np.float64))


def _stats(metric) -> ErrorStats:
    values = metric.get_all_statistics()
    return ErrorStats(float(values["rmse"]), float(values["sse"]), float(values["std"]), float(values["mean"]),
                      float(values["max"]))


def rpe(reference: np.ndarray, estimate: np.ndarray, stamps_s: np.ndarray, rotation: bool = False) -> ErrorStats:
    """Relative pose error between consecutive frames (evo): translation in m or rotation angle in deg."""
    from evo.core import metrics

    relation = metrics.PoseRelation.rotation_angle_deg if rotation else metrics.PoseRelation.translation_part
    metric = metrics.RPE(relation, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
    metric.process_data((evo_trajectory(reference, stamps_s), evo_trajectory(estimate, stamps_s)))
    return _stats(metric)


def ate(reference: np.ndarray, estimate: np.ndarray, stamps_s: np.ndarray) -> ErrorStats:
    """Absolute trajectory error (translation, m) after the least-squares SE(3) alignment (evo, Umeyama)."""
    from evo.core import metrics

    aligned = evo_trajectory(estimate, stamps_s)
    aligned.align(evo_trajectory(reference, stamps_s), correct_scale=False)
    metric = metrics.APE(metrics.PoseRelation.translation_part)
    metric.process_data((evo_trajectory(reference, stamps_s), aligned))
    return _stats(metric)


def path_distances(poses: np.ndarray) -> np.ndarray:
    """Distance travelled (m) up to each pose."""
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def kitti_drift(reference: np.ndarray, estimate: np.ndarray, lengths: tuple[float, ...] = KITTI_LENGTHS,
                step: int = KITTI_STEP) -> Drift:
    """KITTI odometry drift: over every segment of each length the route allows (starting every `step` frames),
    the relative-pose error in % of the length and deg per 100 m, averaged over segments."""
    distance = path_distances(reference)
    t_errors, r_errors, used = [], [], []
    for length in lengths:
        for first in range(0, len(reference), step):
            last = int(np.searchsorted(distance, distance[first] + length))
            if last >= len(reference):
                break
            true = invert(reference[first]) @ reference[last]
            error = invert(true) @ (invert(estimate[first]) @ estimate[last])
            t_errors.append(np.linalg.norm(error[:3, 3]) / length)
            r_errors.append(np.degrees(rotation_angle(error)) / length)
            if length not in used:
                used.append(length)
    if not t_errors:
        return Drift(float("nan"), float("nan"), 0, ())
    return Drift(100.0 * float(np.mean(t_errors)), 100.0 * float(np.mean(r_errors)), len(t_errors), tuple(used))


def end_error(reference: np.ndarray, estimate: np.ndarray) -> EndError:
    """The last pose's error split into horizontal and height offset, and roll / pitch / yaw (deg, estimate against
    reference, in the reference's vehicle frame)."""
    from scipy.spatial.transform import Rotation

    offset = np.asarray(estimate[-1][:3, 3] - reference[-1][:3, 3], np.float64)
    turn = np.asarray(reference[-1][:3, :3]).T @ np.asarray(estimate[-1][:3, :3])
    roll, pitch, yaw = Rotation.from_matrix(turn).as_euler("xyz", degrees=True)
    return EndError(float(np.hypot(offset[0], offset[1])), float(offset[2]), float(roll), float(pitch), float(yaw))


def score(reference: np.ndarray, estimate: np.ndarray, stamps_s: np.ndarray) -> OdomScores:
    """Every figure of one estimated trajectory (poses in the first scan's frame) against the reference."""
    reference, estimate = np.asarray(reference, np.float64), np.asarray(estimate, np.float64)
    distance = float(path_distances(reference)[-1])
    endpoint = float(np.linalg.norm(estimate[-1, :3, 3] - reference[-1, :3, 3]))
    return OdomScores(rpe(reference, estimate, stamps_s), rpe(reference, estimate, stamps_s, rotation=True),
                      ate(reference, estimate, stamps_s), kitti_drift(reference, estimate),
                      100.0 * endpoint / distance if distance > 0 else float("nan"), distance,
                      end_error(reference, estimate))
