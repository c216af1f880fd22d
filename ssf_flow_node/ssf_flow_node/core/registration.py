"""Ego motion between two scans by robust coarse-to-fine point-to-plane ICP (Open3D)."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section


class RegistrationConfig(Section):
    """Coarse-to-fine ICP schedule: a shrinking correspondence distance, Tukey kernel of half that distance."""

    source_points: int = Field(2048, ge=16, description="random source points used for registration")
    max_distances: tuple[float, ...] = (2.0, 0.5)
    iterations: int = Field(10, ge=1, description="ICP iterations per stage")
    refine_distance: float = Field(0.3, gt=0.0, description="correspondence distance of the refinement on static points")
    normal_neighbours: int = Field(10, ge=3, description="neighbours for target normals")
    seed: int = 0


def to_cloud(points: np.ndarray):
    """An Open3D point cloud of (N, 3) points."""
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points."""
    return (points @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)


def rigid_flow(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Flow of points that move with a rigid transform: T p - p."""
    return transform_points(transform, points) - points


class ScanMatcher:
    """Point-to-plane ICP against one target scan (its normals computed once)."""

    def __init__(self, target: np.ndarray, config: RegistrationConfig) -> None:
        import open3d as o3d

        self.config = config
        self.usable = target.shape[0] >= 10
        self.target = to_cloud(target)
        if self.usable:
            self.target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(config.normal_neighbours))

    def normals(self) -> np.ndarray:
        """Unit normals (N, 3) of the target points (zeros when the target was too small)."""
        normals = np.asarray(self.target.normals)
        return normals if len(normals) else np.zeros((len(self.target.points), 3))

    def align(self, source: np.ndarray, initial: np.ndarray | None = None,
              distances: tuple[float, ...] | None = None) -> np.ndarray:
        """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers."""
        import open3d as o3d

        pipelines = o3d.pipelines.registration
        transform = np.eye(4) if initial is None else np.asarray(initial, dtype=np.float64)
        if source.shape[0] < 10 or not self.usable:
            return transform
        if source.shape[0] > self.config.source_points:
            rng = np.random.default_rng(self.config.seed)
            source = source[rng.choice(source.shape[0], self.config.source_points, replace=False)]
        moving = to_cloud(source)
        for distance in distances or self.config.max_distances:
            result = pipelines.registration_icp(
                moving, self.target, distance, transform,
                pipelines.TransformationEstimationPointToPlane(pipelines.TukeyLoss(k=distance / 2.0)),
                pipelines.ICPConvergenceCriteria(max_iteration=self.config.iterations),
            )
            transform = result.transformation
        return np.asarray(transform)


def register(source: np.ndarray, target: np.ndarray, config: RegistrationConfig,
             initial: np.ndarray | None = None) -> np.ndarray:
    """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers."""
    return ScanMatcher(target, config).align(source, initial)
