"""The refinement step timed with three registration back ends on the same scans and maps: the odometry's own
numpy point-to-plane Gauss-Newton, Open3D's point-to-plane ICP and small_gicp's (PyPI small-gicp), side by side."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ssf_common.geometry.se3 import invert
from ssf_odom_node.core.odometry import OdomInput, Odometry
from ssf_common.geometry.registration import PlaneTarget, point_to_plane

BACKENDS = ("numpy", "open3d", "small_gicp")


def numpy_backend(source: np.ndarray, points: np.ndarray, normals: np.ndarray, initial: np.ndarray,
                  odometry: Odometry) -> np.ndarray:
    """The odometry's own refinement (KD-tree of the map built here, as each back end builds its own)."""
    target = PlaneTarget.build(points, normals)
    return point_to_plane(source, None, target, initial, odometry.config.refine_gates, odometry.config.kernel).transform


def open3d_backend(source: np.ndarray, points: np.ndarray, normals: np.ndarray, initial: np.ndarray,
                   odometry: Odometry) -> np.ndarray:
    """Open3D point-to-plane ICP with a Tukey kernel, the map's normals, as many iterations as ours."""
    import open3d as o3d

    registration = o3d.pipelines.registration
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    target.normals = o3d.utility.Vector3dVector(normals)
    result = registration.registration_icp(
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source)), target, odometry.config.refine_gates[0], initial,
        registration.TransformationEstimationPointToPlane(registration.TukeyLoss(k=odometry.config.kernel)),
        registration.ICPConvergenceCriteria(1e-6, 1e-6, len(odometry.config.refine_gates)))
    return np.asarray(result.transformation)


def small_gicp_backend(source: np.ndarray, points: np.ndarray, normals: np.ndarray, initial: np.ndarray,
                       odometry: Odometry) -> np.ndarray:
    """small_gicp point-to-plane ICP (its own KD-tree and normals), as many iterations as ours, one thread."""
    import small_gicp

    target = small_gicp.PointCloud(points)
    tree = small_gicp.KdTree(target, num_threads=1)
    small_gicp.estimate_normals(target, tree, num_neighbors=odometry.config.normal_neighbours, num_threads=1)
    result = small_gicp.align(target, small_gicp.PointCloud(source), tree, initial, registration_type="PLANE_ICP",
                              max_correspondence_distance=odometry.config.refine_gates[0], num_threads=1,
                              max_iterations=len(odometry.config.refine_gates))
    return np.asarray(result.T_target_source)


def compare_backends(odometry: Odometry, frames: list[OdomInput], truths: list[np.ndarray],
                     log: Callable[[str], None]) -> dict[str, dict[str, float]]:
    """Per back end: median ms of one refinement from the odometry's prediction, and median translation error of its
    result against the true pose (relative to the first scan)."""
    available: dict[str, Callable] = {"numpy": numpy_backend, "open3d": open3d_backend,
                                      "small_gicp": small_gicp_backend}
    spent: dict[str, list[float]] = {name: [] for name in available}
    errors: dict[str, list[float]] = {name: [] for name in available}
    first = truths[0]
    for frame, truth in zip(frames, truths):
        if odometry.steps >= 1 and len(odometry.map):
            points, _, dynamic = odometry.reduce(*odometry.check(frame))
            by_flow, by_velocity = odometry.predict(frame.stamp_ns)
            predicted = by_velocity if by_flow is None else by_flow
            source, _ = odometry.registered_points(points, dynamic)
            map_points = np.asarray(odometry.map.points, np.float64)
            map_normals = np.asarray(odometry.map.normals, np.float64)
            for name, backend in available.items():
                started = time.perf_counter()
                estimate = backend(source, map_points, map_normals, predicted, odometry)
                spent[name].append((time.perf_counter() - started) * 1e3)
                errors[name].append(float(np.linalg.norm((invert(estimate) @ invert(first) @ truth)[:3, 3])))
        odometry.step(frame)
    return {name: {"ms_median": float(np.median(spent[name])), "ms_p95": float(np.percentile(spent[name], 95)),
                   "pose_error_median_m": float(np.median(errors[name])), "frames": len(spent[name])}
            for name in available if spent[name]}
