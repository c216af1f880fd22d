"""Ego motion between two scans by robust coarse-to-fine point-to-plane ICP (Open3D)."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section


class RegistrationConfig(Section):
    """Coarse-to-fine ICP schedule: a shrinking correspondence distance, Tukey kernel of half that distance.

    A coarse stage converges on a few random points; the refinement uses many, since with sparse scans the
    sampling noise, not convergence, limits the accuracy."""

    source_points: int = Field(2048, ge=16, description="random source points of the coarse stages (the height, weakly "
                               "held by scans without a ground, needs more than the rest)")
    max_distances: tuple[float, ...] = Field((2.0,), description="correspondence distance (m) of each coarse stage")
    iterations: int = Field(20, ge=1, description="most ICP iterations per coarse stage")
    refine_points: int = Field(8192, ge=16, description="random source points of the refinement")
    refine_distance: float = Field(0.2, gt=0.0, description="correspondence distance (m) of the refinement")
    refine_iterations: int = Field(40, ge=1, description="most ICP iterations of the refinement")
    tolerance: float = Field(1e-6, gt=0.0, description="a stage ends once fitness and RMSE change by less than this "
                             "(relative; the height converges slowly on scans without a ground)")
    normal_neighbours: int = Field(8, ge=3, description="neighbours for target normals (few: sharp planes on sparse scans)")
    seed: int = 0


def to_cloud(points: np.ndarray):
    """An Open3D point cloud of (N, 3) points."""
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


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

    def coarse(self, source: np.ndarray, initial: np.ndarray | None = None, ordered: bool = False) -> np.ndarray:
        """Transform T (4x4) that roughly maps source points onto the target surfaces, from far away."""
        transform = np.eye(4) if initial is None else initial
        for distance in self.config.max_distances:
            transform = self.icp(source, transform, self.config.source_points, distance, self.config.iterations, ordered)
        return transform

    def refine(self, source: np.ndarray, initial: np.ndarray, ordered: bool = False) -> np.ndarray:
        """Transform T (4x4) near `initial` that maps source points accurately onto the target surfaces."""
        return self.icp(source, initial, self.config.refine_points, self.config.refine_distance,
                        self.config.refine_iterations, ordered)

    def align(self, source: np.ndarray, initial: np.ndarray | None = None, ordered: bool = False) -> np.ndarray:
        """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers.

        ordered: the source is already in random order and each stage uses its first points, so that leaving a few
        points out (a motion mask) keeps the others' subsets, and the answer moves only as much as those points weigh."""
        return self.refine(source, self.coarse(source, initial, ordered), ordered)

    def icp(self, source: np.ndarray, initial: np.ndarray, points: int, distance: float, iterations: int,
            ordered: bool = False) -> np.ndarray:
        """Point-to-plane ICP with a Tukey kernel of half the correspondence distance, on up to `points` points."""
        import open3d as o3d

        transform = np.asarray(initial, dtype=np.float64)
        if source.shape[0] < 10 or not self.usable:
            return transform
        if source.shape[0] > points:
            source = source[:points] if ordered else source[
                np.random.default_rng(self.config.seed).choice(source.shape[0], points, replace=False)]
        pipelines = o3d.pipelines.registration
        result = pipelines.registration_icp(
            to_cloud(source), self.target, distance, transform,
            pipelines.TransformationEstimationPointToPlane(pipelines.TukeyLoss(k=distance / 2.0)),
            pipelines.ICPConvergenceCriteria(self.config.tolerance, self.config.tolerance, iterations),
        )
        return np.asarray(result.transformation)


def register(source: np.ndarray, target: np.ndarray, config: RegistrationConfig,
             initial: np.ndarray | None = None) -> np.ndarray:
    """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers."""
    return ScanMatcher(target, config).align(source, initial)
