"""Rigid registration against surfaces, shared by the flow (scan to scan) and the odometry (scan to map): a target of
points with normals and its KD-tree built once, surface normals, one Alignment type, Open3D's point-to-plane ICP
(`tukey_icp`), robust point-to-plane Gauss-Newton with the covariance from its Hessian (`point_to_plane`), and the
flow-based initial transform (weighted Kabsch)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from ssf_common.geometry.fitting import weighted_kabsch
from ssf_common.geometry.neighbours import PointIndex, knn

MIN_CONSTRAINTS = 30  # fewer matched points than this: the step is not trusted
DEGENERATE = 1e-3  # directions whose Hessian eigenvalue is below this share of the largest are left alone


class PlaneTarget(NamedTuple):
    """Points with unit normals and their KD-tree: what point-to-plane residuals are measured against."""

    points: np.ndarray  # (M, 3) float64
    normals: np.ndarray  # (M, 3) float64
    tree: PointIndex

    @classmethod
    def build(cls, points: np.ndarray, normals: np.ndarray) -> PlaneTarget:
        """A target of points and their normals."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return cls(points, np.asarray(normals, dtype=np.float64).reshape(-1, 3), PointIndex(points))

    def __len__(self) -> int:
        return len(self.points)


class Alignment(NamedTuple):
    """A refined transform, the covariance of its left perturbation (x y z roll pitch yaw) and its support."""

    transform: np.ndarray  # (4, 4)
    covariance: np.ndarray  # (6, 6), translation first (the order of ROS pose covariances)
    inliers: int  # points matched within the gate on the last iteration
    rmse: float  # RMS residual (m) on the last iteration: point-to-plane, weighted (`point_to_plane`), or the matched
    # points' distances (`tukey_icp`, as Open3D reports it)
    iterations: int
    lift: float = 0.0  # where fitted (`shares`): the height (sensor frame, m) a point gains per sweep period before
    # the stamp, i.e. how far the sensor sank over one sweep; 0 where not fitted
    fitness: float = 0.0  # the share of the source points matched within the gate on the last iteration


def estimate_normals(points: np.ndarray, neighbours: int = 8, at: np.ndarray | None = None) -> np.ndarray:
    """Unit normals of a point set (at the points `at` indexes, default all): the least-variance direction of each
    point's k nearest neighbours in the set."""
    points = np.asarray(points, dtype=np.float64)
    query = points if at is None else points[at]
    if len(points) < 3:
        return np.tile([0.0, 0.0, 1.0], (len(query), 1))
    found = knn(points, query, min(neighbours, len(points)))
    return plane_normals(points[found.index])  # (Q, k, 3); knn never misses within the set itself


def plane_normals(near: np.ndarray) -> np.ndarray:
    """(Q, 3) unit normals of Q neighbourhoods (Q, k, 3): each one's least-variance direction."""
    centred = near - near.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    return vectors[:, :, 0]


def normals_among(query: np.ndarray, clouds: list[tuple[np.ndarray, PointIndex]], neighbours: int = 8) -> np.ndarray:
    """Unit normals at the query points from their k nearest neighbours among several point sets (each with its
    KD-tree), e.g. the map and the scan being mapped: a ground voxel first seen far away gets its plane from the rings
    of earlier scans too, not only from its own scan's ring, nearly a line there."""
    query = np.asarray(query, dtype=np.float64).reshape(-1, 3)
    clouds = [(np.asarray(points, dtype=np.float64), tree) for points, tree in clouds if len(points)]
    total = sum(len(points) for points, _ in clouds)
    if len(query) == 0 or total < 3:
        return np.tile([0.0, 0.0, 1.0], (len(query), 1))
    k = min(neighbours, total)
    distances, found = [], []
    for points, tree in clouds:
        distance, index = tree.query(query, k=min(k, len(points)))
        distance, index = distance.reshape(len(query), -1), index.reshape(len(query), -1)
        distances.append(distance)
        found.append(points[index])
    distance, near = np.concatenate(distances, axis=1), np.concatenate(found, axis=1)  # (Q, m, 3), m >= k
    nearest = np.argpartition(distance, k - 1, axis=1)[:, :k]
    return plane_normals(np.take_along_axis(near, nearest[:, :, None], axis=1))


def flow_transform(points: np.ndarray, flow: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """The rigid motion (4x4, scan t -> scan t+1) that best explains the weighted points' flow: weighted Kabsch."""
    points = np.asarray(points, dtype=np.float64)
    return weighted_kabsch(points, points + np.asarray(flow, dtype=np.float64), weights)


def exp_se3(delta: np.ndarray) -> np.ndarray:
    """4x4 transform of a small twist (tx ty tz rx ry rz), rotation from the rotation vector."""
    transform = np.eye(4)
    transform[:3, :3] = Rotation.from_rotvec(delta[3:]).as_matrix()
    transform[:3, 3] = delta[:3]
    return transform


def log_se3(transform: np.ndarray) -> np.ndarray:
    """Twist (tx ty tz rx ry rz) of a transform (translation as is, rotation as a rotation vector)."""
    return np.concatenate([transform[:3, 3], Rotation.from_matrix(transform[:3, :3]).as_rotvec()])


def point_to_plane(source: np.ndarray, weights: np.ndarray | None, target: PlaneTarget, initial: np.ndarray,
                   distances: tuple[float, ...], kernel: float, tolerance: float = 1e-4,
                   shares: np.ndarray | None = None) -> Alignment:
    """Gauss-Newton on weighted point-to-plane residuals with a Geman-McClure kernel (scale: `kernel`, or a third of
    the gate when wider), one iteration per gate in `distances` (m, coarse to fine), stopping early once the step is
    below `tolerance`. With `shares` (each point's time before the stamp, in sweep periods) the sensor's vertical motion
    over a sweep is fitted too: each point moves by its share of `lift` along the sensor's z axis."""
    source = np.asarray(source, dtype=np.float64)
    weights = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=np.float64)
    transform = np.asarray(initial, dtype=np.float64).copy()
    lift = 0.0
    hessian, rmse, inliers, done = np.zeros((6, 6) if shares is None else (7, 7)), np.inf, 0, 0
    if len(target) < MIN_CONSTRAINTS or len(source) < MIN_CONSTRAINTS:
        return Alignment(transform, np.eye(6), 0, rmse, 0)
    for gate in distances:
        lifted = source if shares is None else source + np.outer(shares * lift, [0.0, 0.0, 1.0])
        moved = lifted @ transform[:3, :3].T + transform[:3, 3]
        distance, index = target.tree.query(moved, distance_upper_bound=gate)
        found = np.flatnonzero(np.isfinite(distance))
        inliers = len(found)
        if inliers < MIN_CONSTRAINTS:
            break
        matched = index[found]  # take(): rows gathered 3x faster than by indexing
        x, n = moved.take(found, axis=0), target.normals.take(matched, axis=0)
        residual = np.einsum("ij,ij->i", n, x - target.points.take(matched, axis=0))
        scale = max(kernel, gate / 3.0)  # the kernel widens with the gate: coarse steps must see far correspondences
        robust = weights[found] * (scale ** 2 / (scale ** 2 + residual ** 2)) ** 2
        # rotations about the sensor, not about the odometry frame's origin: a kilometre from the start, a turn about
        # the origin is mostly a translation, and the step's conditioning (and its degenerate directions) with it
        centre = transform[:3, 3].copy()
        arm = x - centre
        jacobian = np.hstack([n, np.cross(arm, n)])  # d residual / d (translation, rotation about the sensor)
        if shares is not None:  # d residual / d lift: the point's share along the sensor's z axis
            jacobian = np.hstack([jacobian, (shares.take(found) * (n @ transform[:3, 2]))[:, None]])
        weighted = (jacobian * robust[:, None]).T
        hessian = weighted @ jacobian
        gradient = weighted @ residual
        step = constrained_step(hessian, gradient, float(np.sqrt(np.mean(np.einsum("ij,ij->i", arm, arm)))))
        about_sensor = exp_se3(step[:6])
        about_sensor[:3, 3] += centre - about_sensor[:3, :3] @ centre  # the step moved to act about `centre`
        transform = about_sensor @ transform
        if shares is not None:
            lift += float(step[6])
        rmse = float(np.sqrt((robust * residual ** 2).sum() / max(robust.sum(), 1e-12)))
        done += 1
        if np.abs(step).max() < tolerance:
            break
    return Alignment(transform, plane_covariance(hessian, rmse, inliers)[:6, :6], inliers, rmse, done, lift)


def tukey_icp(source: np.ndarray, target: PlaneTarget, initial: np.ndarray, distance: float, iterations: int,
              tolerance: float) -> Alignment:
    """Open3D's point-to-plane ICP (`registration_icp` with a Tukey kernel of half the correspondence distance: the
    same steps, answers equal to 1e-15) on the target's KD-tree built once instead of at every call: each iteration
    matches every source point to its nearest target point within `distance`, takes the weighted Gauss-Newton step
    (rotation as roll, pitch, yaw) and stops once the matched share and the matched points' RMS distance change by less
    than `tolerance`."""
    transform = np.asarray(initial, dtype=np.float64).copy()
    source = np.asarray(source, dtype=np.float64)
    moved = source @ transform[:3, :3].T + transform[:3, 3]
    matches = _matches(moved, target, distance)
    hessian, kernel, done = np.zeros((6, 6)), distance / 2.0, 0
    for done in range(1, iterations + 1):
        found, index = matches[0], matches[1]
        if found.size == 0:  # nothing matched: Open3D's step is no motion, and so would every next one be
            break
        x, n = moved.take(found, axis=0), target.normals.take(index, axis=0)
        residual = np.einsum("ij,ij->i", x - target.points.take(index, axis=0), n)
        weight = np.where(np.abs(residual) <= kernel, (1.0 - (residual / kernel) ** 2) ** 2, 0.0)
        jacobian = np.hstack([np.cross(x, n), n])  # d residual / d (roll, pitch, yaw, translation)
        weighted = (jacobian * weight[:, None]).T
        hessian = weighted @ jacobian
        try:
            twist = np.linalg.solve(hessian, -(weighted @ residual))
        except np.linalg.LinAlgError:  # fewer constraints than parameters: the least-norm step
            twist = np.linalg.lstsq(hessian, -(weighted @ residual), rcond=None)[0]
        step = euler_transform(twist)
        transform = step @ transform
        moved = moved @ step[:3, :3].T + step[:3, 3]
        before, matches = matches, _matches(moved, target, distance)
        if abs(before[2] - matches[2]) < tolerance and abs(before[3] - matches[3]) < tolerance:
            break
    rmse = matches[3]
    covariance = plane_covariance(hessian, rmse, matches[0].size)[np.ix_([3, 4, 5, 0, 1, 2], [3, 4, 5, 0, 1, 2])]
    return Alignment(transform, covariance, int(matches[0].size), rmse, done, fitness=matches[2])


def _matches(moved: np.ndarray, target: PlaneTarget, distance: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The source points with a target point within `distance`, those target points, their share and RMS distance."""
    gap, index = target.tree.query(moved, distance_upper_bound=distance)
    found = np.flatnonzero(np.isfinite(gap))
    if found.size == 0:
        return found, index[found], 0.0, 0.0
    return found, index[found], found.size / max(len(moved), 1), float(np.sqrt(np.mean(gap[found] ** 2)))


def euler_transform(twist: np.ndarray) -> np.ndarray:
    """4x4 transform of (roll, pitch, yaw, x, y, z): rotation Rz(yaw) Ry(pitch) Rx(roll), as Open3D's ICP steps."""
    (ca, cb, cg), (sa, sb, sg) = np.cos(twist[:3]), np.sin(twist[:3])
    transform = np.eye(4)
    transform[:3, :3] = [[cg * cb, -sg * ca + cg * sb * sa, sg * sa + cg * sb * ca],
                         [sg * cb, cg * ca + sg * sb * sa, -cg * sa + sg * sb * ca],
                         [-sb, cb * sa, cb * ca]]
    transform[:3, 3] = twist[3:]
    return transform


def steep_support(points: np.ndarray, transform: np.ndarray, target: PlaneTarget, gate: float = 0.5,
                  tight: float = 0.2) -> int:
    """How many points the transform lays within `tight` (m) of a steep target surface (normal within 45 degrees of
    horizontal: walls, poles, cars): what tells headings apart, where the ground fits every heading alike."""
    if len(target) == 0 or len(points) == 0:
        return 0
    moved = np.asarray(points, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]
    distance, index = target.tree.query(moved, distance_upper_bound=gate)
    found = np.isfinite(distance)
    normals = target.normals[index[found]]
    residual = np.abs(np.einsum("ij,ij->i", moved[found] - target.points[index[found]], normals))
    return int(np.count_nonzero((residual < tight) & (np.abs(normals[:, 2]) < np.sqrt(0.5))))


def constrained_step(hessian: np.ndarray, gradient: np.ndarray, length: float) -> np.ndarray:
    """The Gauss-Newton step -H^-1 g in the directions the residuals constrain; none along degenerate directions
    (a corridor's length, a plane's in-plane motion), so the prediction stands there. Rotations are measured as
    the motion they cause at `length` (m), so that both kinds of direction compare; parameters past the six of a
    pose are lengths."""
    scale = np.r_[np.ones(3), np.full(3, 1.0 / max(length, 1e-6)), np.ones(len(gradient) - 6)]  # (translation,
    # rotation * length, any further length) units
    scaled = hessian * np.outer(scale, scale)
    values, vectors = np.linalg.eigh(scaled)
    keep = values > DEGENERATE * max(values[-1], 1e-12)
    return scale * -((vectors[:, keep] / values[keep]) @ (vectors[:, keep].T @ (gradient * scale)))


def plane_covariance(hessian: np.ndarray, rmse: float, inliers: int) -> np.ndarray:
    """Covariance sigma^2 H^-1 of a point-to-plane fit (sigma: its RMS residual); large where unconstrained."""
    if inliers < MIN_CONSTRAINTS or not np.isfinite(rmse):
        return np.eye(len(hessian))
    sigma2 = max(rmse, 1e-3) ** 2
    return sigma2 * np.linalg.inv(hessian + 1e-9 * np.eye(len(hessian)))  # degenerate directions: very uncertain
