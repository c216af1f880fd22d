"""Rigid fits of point correspondences: weighted Kabsch (single and batched per label, float64, reflection fixed,
degenerate sets give the identity), the planar (yaw-only) Kabsch, and a per-label point-to-plane Gauss-Newton step."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.labels import label_counts, label_means, label_sums, label_sums_of_rows
from ssf_common.geometry.se3 import from_rotation_translation

MIN_WEIGHT = 1e-9


def weighted_kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The 4x4 rigid T minimising sum_i w_i |T s_i - t_i|^2; the identity when fewer than 3 points carry weight."""
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    w = np.ones(len(source)) if weights is None else np.clip(np.asarray(weights, dtype=np.float64), 0.0, None)
    total = w.sum()
    if np.count_nonzero(w > MIN_WEIGHT) < 3 or not total > MIN_WEIGHT:
        return np.eye(4)
    mean_s, mean_t = w @ source / total, w @ target / total
    cross = (source - mean_s).T @ ((target - mean_t) * w[:, None])
    if not np.isfinite(cross).all():
        return np.eye(4)
    u, _, vt = np.linalg.svd(cross)
    fix = np.diag([1.0, 1.0, 1.0 if np.linalg.det(vt.T @ u.T) >= 0 else -1.0])
    rotation = vt.T @ fix @ u.T
    transform = from_rotation_translation(rotation, mean_t - rotation @ mean_s)
    return transform if np.isfinite(transform).all() else np.eye(4)


def batched_kabsch(source: np.ndarray, target: np.ndarray, labels: np.ndarray, count: int,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """Per label k, the 4x4 rigid T_k minimising sum_{i in k} w_i |T_k s_i - t_i|^2, as (count, 4, 4).

    Weighted centroids, S = (P - mu_s)^T diag(w) (Q - mu_t), SVD, reflection fix R = V diag(1, 1, det(V U^T)) U^T,
    t = mu_t - R mu_s. Labels with fewer than 3 weighted points, no weight or a non-finite result get the identity."""
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    w = np.ones(len(source)) if weights is None else np.clip(np.asarray(weights, dtype=np.float64), 0.0, None)
    total = np.bincount(labels, w, count)
    support = np.bincount(labels, w > MIN_WEIGHT, count)
    mean_s = label_means(source, labels, count, w)
    mean_t = label_means(target, labels, count, w)
    s, t = source - mean_s[labels], target - mean_t[labels]
    cross = np.stack([label_sums(s[:, i] * t[:, j], labels, count, w) for i in range(3) for j in range(3)], axis=1)
    cross = cross.reshape(count, 3, 3)
    transforms = np.tile(np.eye(4), (count, 1, 1))
    good = (support >= 3) & (total > MIN_WEIGHT) & np.isfinite(cross).all(axis=(1, 2))
    if not good.any():
        return transforms
    u, _, vt = np.linalg.svd(cross[good])
    v, ut = np.swapaxes(vt, 1, 2), np.swapaxes(u, 1, 2)
    fix = np.ones((good.sum(), 3))
    fix[:, 2] = np.sign(np.linalg.det(v @ ut))
    fix[fix[:, 2] == 0, 2] = 1.0
    rotation = (v * fix[:, None, :]) @ ut
    translation = mean_t[good] - np.einsum("kij,kj->ki", rotation, mean_s[good])
    fitted = from_rotation_translation(rotation, translation)
    finite = np.isfinite(fitted).all(axis=(1, 2))
    transforms[np.flatnonzero(good)[finite]] = fitted[finite]
    return transforms


def planar_kabsch(source: np.ndarray, target: np.ndarray, labels: np.ndarray, count: int,
                  max_yaw: float = np.pi) -> tuple[np.ndarray, np.ndarray]:
    """Per label, the yaw (at most max_yaw) and translation that best map source onto target (rotation about z)."""
    mean_s = label_means(source, labels, count)
    mean_t = label_means(target, labels, count)
    s = source - mean_s[labels]
    t = target - mean_t[labels]
    cos_term = np.bincount(labels, s[:, 0] * t[:, 0] + s[:, 1] * t[:, 1], count)
    sin_term = np.bincount(labels, s[:, 0] * t[:, 1] - s[:, 1] * t[:, 0], count)
    yaw = np.clip(np.arctan2(sin_term, cos_term), -max_yaw, max_yaw)
    c, si = np.cos(yaw), np.sin(yaw)
    rotated = np.stack([c * mean_s[:, 0] - si * mean_s[:, 1], si * mean_s[:, 0] + c * mean_s[:, 1], mean_s[:, 2]], axis=1)
    return yaw, mean_t - rotated


def planar_plane_step(moved: np.ndarray, target: np.ndarray, normals: np.ndarray, labels: np.ndarray,
                      yaw: np.ndarray, translation: np.ndarray, count: int, point_weight: float = 0.3,
                      max_yaw: float = np.pi) -> tuple[np.ndarray, np.ndarray]:
    """One Gauss-Newton step per label on point-to-plane (plus `point_weight` point-to-point) residuals, for a yaw
    about the label's centre and a translation; returns the updated (yaw, translation) of each label."""
    sizes = np.maximum(label_counts(labels, count), 1).astype(np.float64)
    centre = label_sums(moved, labels, count) / sizes[:, None]
    # one contiguous row per coordinate (N-long row operations are several times faster than along axis 1 of (N, 3))
    x, y, z = np.ascontiguousarray(np.asarray(moved, dtype=np.float64).T)
    lever_x, lever_y = -(y - centre[labels, 1]), x - centre[labels, 0]  # d position / d yaw about the centre
    error = np.ascontiguousarray((moved - target).T)
    nx, ny, nz = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).T)
    plane_rows = np.stack([nx, ny, nz, nx * lever_x + ny * lever_y])  # (4, N): d plane residual / d (t, yaw)
    plane_error = nx * error[0] + ny * error[1] + nz * error[2]
    # per point, the upper triangle of the 4x4 normal matrix and the gradient; the point-to-point residuals add
    # [[I, lever], [lever^T, |lever|^2]] and [error, lever . error]
    first, second = np.triu_indices(4)
    hessian = plane_rows[first] * plane_rows[second]  # (10, N)
    diagonal = {i: int(np.flatnonzero((first == i) & (second == i))[0]) for i in range(4)}
    for i in range(3):
        hessian[diagonal[i]] += point_weight
    hessian[int(np.flatnonzero((first == 0) & (second == 3))[0])] += point_weight * lever_x
    hessian[int(np.flatnonzero((first == 1) & (second == 3))[0])] += point_weight * lever_y
    hessian[diagonal[3]] += point_weight * (lever_x * lever_x + lever_y * lever_y)
    gradient = plane_rows * plane_error
    gradient[:3] += point_weight * error
    gradient[3] += point_weight * (lever_x * error[0] + lever_y * error[1])
    sums = label_sums_of_rows(np.vstack([hessian, gradient]), labels, count)  # one pass over the points for all 14
    system = np.zeros((count, 4, 4))
    system[:, first, second] = sums[:, :10]
    system[:, second, first] = sums[:, :10]
    system += 1e-3 * np.eye(4)
    rhs = sums[:, 10:]
    step = -np.linalg.solve(system, rhs[:, :, None])[:, :, 0]
    turn = np.clip(yaw + step[:, 3], -max_yaw, max_yaw) - yaw
    c, s = np.cos(turn), np.sin(turn)
    relative = translation - centre
    rotated = np.column_stack([c * relative[:, 0] - s * relative[:, 1], s * relative[:, 0] + c * relative[:, 1], relative[:, 2]])
    return yaw + turn, rotated + centre + step[:, :3]
