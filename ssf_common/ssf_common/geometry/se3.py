"""Rigid transforms as 4x4 float64 matrices, and their action on (N, 3) points."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def make_pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """A 4x4 transform: rotation `yaw` about z, then translation (x, y, z)."""
    matrix = yaw_matrix(yaw)
    matrix[:3, 3] = [x, y, z]
    return matrix


def yaw_matrix(angle: float) -> np.ndarray:
    """A 4x4 rotation about z by `angle` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    matrix = np.eye(4)
    matrix[:2, :2] = [[c, -s], [s, c]]
    return matrix


def from_rotation_translation(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """A 4x4 transform from a 3x3 rotation (or a stack (..., 3, 3)) and a translation (..., 3)."""
    rotation, translation = np.asarray(rotation, dtype=np.float64), np.asarray(translation, dtype=np.float64)
    matrix = np.zeros(rotation.shape[:-2] + (4, 4))
    matrix[..., :3, :3] = rotation
    matrix[..., :3, 3] = translation
    matrix[..., 3, 3] = 1.0
    return matrix


def compose(*transforms: np.ndarray) -> np.ndarray:
    """The product T1 @ T2 @ ... (the rightmost applies first)."""
    result = np.eye(4)
    for transform in transforms:
        result = result @ np.asarray(transform, dtype=np.float64)
    return result


def invert(transform: np.ndarray) -> np.ndarray:
    """The inverse of a rigid transform (or a stack of them), in closed form: [R^T, -R^T t]."""
    transform = np.asarray(transform, dtype=np.float64)
    rotation_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    return from_rotation_translation(rotation_t, -np.einsum("...ij,...j->...i", rotation_t, transform[..., :3, 3]))


def relative_pose(pose1: np.ndarray, pose2: np.ndarray) -> np.ndarray:
    """pose2^-1 pose1 for world <- sensor poses: maps scan-t coordinates of static points into scan t+1's frame."""
    return np.linalg.inv(np.asarray(pose2, dtype=np.float64)) @ np.asarray(pose1, dtype=np.float64)


def interpolate_poses(start: np.ndarray, end: np.ndarray, shares: np.ndarray) -> np.ndarray:
    """Poses (K, 4, 4) at `shares` of a constant-twist (screw) motion from start (0) to end (1); exact at 1.

    A unicycle's arc at constant speed and yaw rate is such a motion; so is KISS-ICP's constant-velocity deskew."""
    end = np.asarray(end, dtype=np.float64)
    remaining = 1.0 - np.asarray(shares, dtype=np.float64).reshape(-1, 1)  # of the way back from the end
    if not remaining.any():
        return np.repeat(end[None], len(remaining), axis=0)
    back = invert(end) @ np.asarray(start, dtype=np.float64)  # end -> start, in the end's frame
    rotation_vector = _rotation_vector(back[:3, :3])
    left_jacobian = _so3_left_jacobian(rotation_vector[None])[0]
    translation_twist = np.linalg.solve(left_jacobian, back[:3, 3])
    return end @ exp_twists(remaining * rotation_vector, remaining * translation_twist)


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle) of a 3x3 rotation."""
    angle = float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
    if angle > np.pi - 1e-3:  # near half a turn the antisymmetric part vanishes: scipy's general method
        return Rotation.from_matrix(rotation).as_rotvec()
    twice_sine_axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                                rotation[1, 0] - rotation[0, 1]])
    return twice_sine_axis / 2.0 * (1.0 if angle < 1e-6 else angle / np.sin(angle))


def exp_twists(rotation_vectors: np.ndarray, translation_twists: np.ndarray) -> np.ndarray:
    """SE(3) exponentials (K, 4, 4) of twists given as rotation vectors (K, 3) and translation parts (K, 3)."""
    rotation_vectors = np.asarray(rotation_vectors, dtype=np.float64)
    skew = _skew(rotation_vectors)
    angle = np.linalg.norm(rotation_vectors, axis=1)[:, None, None]
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    sine = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    cosine = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    rotation = np.eye(3) + sine * skew + cosine * (skew @ skew)
    translation = np.einsum("kij,kj->ki", _so3_left_jacobian(rotation_vectors), translation_twists)
    return from_rotation_translation(rotation, translation)


def _so3_left_jacobian(rotation_vectors: np.ndarray) -> np.ndarray:
    """V(w) = I + (1 - cos a) / a^2 [w] + (a - sin a) / a^3 [w]^2 for rotation vectors (K, 3): SE(3)'s t = V rho."""
    skew = _skew(rotation_vectors)
    angle = np.linalg.norm(rotation_vectors, axis=1)[:, None, None]
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    first = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    second = np.where(small, 1.0 / 6.0 - angle**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    return np.eye(3) + first * skew + second * (skew @ skew)


def _skew(vectors: np.ndarray) -> np.ndarray:
    """Cross-product matrices (K, 3, 3) of vectors (K, 3)."""
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], 1)


def yaw_of(transform: np.ndarray) -> float:
    """Heading (rotation about z) of a 4x4 transform."""
    return float(np.arctan2(transform[1, 0], transform[0, 0]))


def rotation_angle(transform: np.ndarray) -> float:
    """Angle (rad) of a transform's rotation, whatever its axis."""
    cosine = (np.trace(np.asarray(transform)[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(cosine, -1.0, 1.0)))


def displacement_at(first: np.ndarray, second: np.ndarray, distance: float) -> float:
    """How far apart (m) two motions put a point `distance` away, at most: the translation between them plus the angle
    of the rotation between them times the distance."""
    deviation = invert(np.asarray(first, dtype=np.float64)) @ np.asarray(second, dtype=np.float64)
    return float(np.linalg.norm(deviation[:3, 3]) + rotation_angle(deviation) * distance)


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points; float32 out."""
    return (points @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)


def own_motion(transform: np.ndarray, points: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Per point, its flow less the flow the rigid transform gives it (T p - p): how it moves on its own (float32; the
    rotation enters as R - I, whose small entries keep float32 exact to micrometres at 100 m)."""
    transform = np.asarray(transform, np.float64)
    rotation = (transform[:3, :3] - np.eye(3)).astype(np.float32)
    points, flow = np.asarray(points, np.float32)[:, :3], np.asarray(flow, np.float32)
    return flow - points @ rotation.T - transform[:3, 3].astype(np.float32)


def rigid_flow(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Flow of points that move with a rigid transform: T p - p."""
    return transform_points(transform, points) - points


def yaw_translate(points: np.ndarray, yaw: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Per point: rotate by yaw[i] about z, then add translation[i] (N, 3)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * points[:, 0] - s * points[:, 1] + translation[:, 0],
                     s * points[:, 0] + c * points[:, 1] + translation[:, 1],
                     points[:, 2] + translation[:, 2]], axis=1)
