"""Ego motion between two scans by robust coarse-to-fine point-to-plane ICP: Open3D's algorithm on the shared
registration layer (the target's normals and KD-tree built once), or Open3D's or small_gicp's own."""

from __future__ import annotations

from enum import Enum

import numpy as np
import small_gicp
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.registration import Alignment, PlaneTarget, tukey_icp


class IcpBackend(str, Enum):
    """Which library runs the point-to-plane ICP."""

    PLANE = "plane"  # Open3D's ICP (Tukey kernel of half the distance) on the target's KD-tree built once: its answers
    OPEN3D = "open3d"  # Open3D's registration_icp itself, which builds the target's KD-tree again on every call
    SMALL_GICP = "small_gicp"  # correspondences cut at half the distance; the target's KD-tree and normals built once


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
    coarse_samples: int = Field(5, ge=1, description="random samples the coarse stages may run on: where the "
                                "refinement walks away from the first one's answer, the others' answers are "
                                "refined too and the one that brings most points within refine_distance wins")
    backend: IcpBackend = Field(IcpBackend.PLANE, description="ICP: plane (Open3D's algorithm on the shared registration "
                                "layer, the target's KD-tree built once: Open3D's answers to 1e-15, a third faster), "
                                "open3d (registration_icp itself), or small_gicp (faster still, but its hard "
                                "correspondence cut instead of the Tukey kernel doubles the static EPE on whole scans: "
                                "docs/realtime.md; it stops on its own small-update test, so `tolerance` does not apply)")
    seed: int = 0


def to_cloud(points: np.ndarray):
    """An Open3D point cloud of (N, 3) points."""
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


class ScanMatcher:
    """Point-to-plane ICP against one target scan (its normals computed once)."""

    def __init__(self, target: np.ndarray, config: RegistrationConfig) -> None:
        self.config = config
        self.usable = target.shape[0] >= 10
        self.icp = TARGETS[config.backend](np.asarray(target, dtype=np.float64), config.normal_neighbours, self.usable)

    def normals(self) -> np.ndarray:
        """Unit normals (N, 3) of the target points (zeros when the target was too small)."""
        return self.icp.normals()

    def coarse(self, source: np.ndarray, initial: np.ndarray | None = None, ordered: bool = False,
               sample: int = 0) -> np.ndarray:
        """Transform T (4x4) that roughly maps source points onto the target surfaces, from far away (`sample`: which
        random sample of the source to use)."""
        transform = np.eye(4) if initial is None else initial
        for distance in self.config.max_distances:
            transform = self.fit(source, transform, self.config.source_points, distance, self.config.iterations,
                                 ordered, sample).transform
        return transform

    def refine(self, source: np.ndarray, initial: np.ndarray, ordered: bool = False) -> np.ndarray:
        """Transform T (4x4) near `initial` that maps source points accurately onto the target surfaces."""
        return self.refined(source, initial, ordered).transform

    def refined(self, source: np.ndarray, initial: np.ndarray, ordered: bool = False) -> Alignment:
        """The refinement from `initial`, with the share of its points it brings within refine_distance."""
        return self.fit(source, initial, self.config.refine_points, self.config.refine_distance,
                        self.config.refine_iterations, ordered)

    def align(self, source: np.ndarray, initial: np.ndarray | None = None, ordered: bool = False,
              prior: np.ndarray | None = None, restarts: bool = True) -> np.ndarray:
        """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers.

        A refinement that walks away from its coarse start by more than refine_distance, or ends that far from `prior`
        (e.g. the previous pair's motion), is not trusted: the refinements from the coarse stages on the other samples
        and from `prior` compete with it, and the one that brings most points within refine_distance wins (on a sparse
        scan, ground rings that look the same wherever the sensor is, and objects moving with it, can pull the
        refinement to no motion).
        ordered: the source is already in random order and each stage uses its first points, so that leaving a few
        points out (a motion mask) keeps the others' subsets, and the answer moves only as much as those points weigh.
        restarts=False: the first refinement is the answer, trusted or not (an alignment made only to judge another)."""
        start = self.coarse(source, initial, ordered)
        first = self.refined(source, start, ordered)
        distance = self.config.refine_distance
        trusted = same_motion(first.transform, start, distance)
        if not restarts or trusted and (prior is None or same_motion(first.transform, prior, distance)):
            return first.transform
        starts = [self.coarse(source, initial, ordered, sample) for sample in range(1, self.config.coarse_samples)]
        starts += [] if prior is None else [np.asarray(prior, dtype=np.float64)]
        candidates = [first] + [self.refined(source, other, ordered) for other in starts]
        return max(candidates, key=lambda fit: fit.fitness).transform

    def fit(self, source: np.ndarray, initial: np.ndarray, points: int, distance: float, iterations: int,
            ordered: bool = False, sample: int = 0) -> Alignment:
        """Point-to-plane ICP with a Tukey kernel of half the correspondence distance, on up to `points` points (the
        `sample`-th random sample: ordered sources use their `sample`-th run of `points`)."""
        transform = np.asarray(initial, dtype=np.float64)
        if source.shape[0] < 10 or not self.usable:
            return Alignment(transform, np.eye(6), 0, 0.0, 0)
        if source.shape[0] > points:
            source = source[(sample * points + np.arange(points)) % source.shape[0]] if ordered else source[
                source_sample(source.shape[0], points, self.config.seed, sample)]
        return self.icp.fit(source, transform, distance, iterations, self.config.tolerance)


class Open3dTarget:
    """Open3D's point-to-plane ICP with a Tukey kernel of half the correspondence distance, against a target whose
    normals Open3D estimates once."""

    def __init__(self, target: np.ndarray, neighbours: int, usable: bool) -> None:
        import open3d as o3d

        self.cloud = to_cloud(target)
        if usable:
            self.cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(neighbours))

    def normals(self) -> np.ndarray:
        """Unit normals (N, 3) (zeros when none were estimated)."""
        normals = np.asarray(self.cloud.normals)
        return normals if len(normals) else np.zeros((len(self.cloud.points), 3))

    def fit(self, source: np.ndarray, initial: np.ndarray, distance: float, iterations: int,
            tolerance: float) -> Alignment:
        """ICP from `initial`; fitness: the share of source points within `distance`."""
        import open3d as o3d

        pipelines = o3d.pipelines.registration
        result = pipelines.registration_icp(
            to_cloud(source), self.cloud, distance, initial,
            pipelines.TransformationEstimationPointToPlane(pipelines.TukeyLoss(k=distance / 2.0)),
            pipelines.ICPConvergenceCriteria(tolerance, tolerance, iterations),
        )
        return Alignment(np.asarray(result.transformation), np.eye(6), len(result.correspondence_set),
                         float(result.inlier_rmse), 0, fitness=float(result.fitness))


class PlaneIcpTarget(Open3dTarget):
    """Open3D's ICP run on the shared registration layer (`tukey_icp`) against the target's normals (Open3D's, as
    before) and a KD-tree built once, where Open3D builds its tree again on every call."""

    def __init__(self, target: np.ndarray, neighbours: int, usable: bool) -> None:
        super().__init__(target, neighbours, usable)
        self.target = PlaneTarget.build(target, self.normals()) if usable else None

    def fit(self, source: np.ndarray, initial: np.ndarray, distance: float, iterations: int,
            tolerance: float) -> Alignment:
        """ICP from `initial`; fitness: the share of source points within `distance`."""
        return tukey_icp(source, self.target, initial, distance, iterations, tolerance)


class SmallGicpTarget:
    """small_gicp's point-to-plane ICP against a target whose KD-tree and normals are built once; correspondences
    farther than half the distance are dropped (where Open3D's Tukey kernel reaches zero weight)."""

    def __init__(self, target: np.ndarray, neighbours: int, usable: bool) -> None:
        self.count = target.shape[0]
        self.cloud = small_gicp.PointCloud(target)
        self.tree = small_gicp.KdTree(self.cloud) if usable else None
        if usable:
            small_gicp.estimate_normals(self.cloud, self.tree, num_neighbors=neighbours)

    def normals(self) -> np.ndarray:
        """Unit normals (N, 3) (zeros when none were estimated)."""
        return np.asarray(self.cloud.normals())[:, :3] if self.tree is not None else np.zeros((self.count, 3))

    def fit(self, source: np.ndarray, initial: np.ndarray, distance: float, iterations: int,
            tolerance: float) -> Alignment:
        """ICP from `initial` (small_gicp stops on its own small-update test: `tolerance` does not apply); fitness:
        the share of source points within half the distance."""
        result = small_gicp.align(self.cloud, small_gicp.PointCloud(np.asarray(source, dtype=np.float64)),
                                       self.tree, np.asarray(initial, dtype=np.float64), registration_type="PLANE_ICP",
                                       max_correspondence_distance=distance / 2.0, num_threads=1,
                                       max_iterations=iterations)
        return Alignment(np.asarray(result.T_target_source), np.eye(6), int(result.num_inliers), float(result.error),
                         int(result.iterations), fitness=result.num_inliers / max(source.shape[0], 1))


TARGETS = {IcpBackend.PLANE: PlaneIcpTarget, IcpBackend.OPEN3D: Open3dTarget, IcpBackend.SMALL_GICP: SmallGicpTarget}


def source_sample(count: int, points: int, seed: int, sample: int) -> np.ndarray:
    """Indices of `points` of `count` source points: the seeded random sample (0), or the `sample`-th run of a second
    seeded order (wrapping around when it runs out)."""
    if sample == 0:
        return np.random.default_rng(seed).choice(count, points, replace=False)
    order = np.random.default_rng([seed, 1]).permutation(count)
    return order[(sample * points + np.arange(points)) % count]


def motion_gap(first: np.ndarray, second: np.ndarray) -> float:
    """How far apart (m) two transforms move the points of a 1 m radius around the origin, at most."""
    rotation = np.linalg.norm(first[:3, :3] - second[:3, :3], ord=2)
    return float(np.linalg.norm(first[:3, 3] - second[:3, 3]) + rotation)


def same_motion(first: np.ndarray, second: np.ndarray, distance: float) -> bool:
    """Whether two transforms move every point within `distance` (m) of a 1 m radius around the origin alike."""
    return motion_gap(first, second) < distance


def register(source: np.ndarray, target: np.ndarray, config: RegistrationConfig,
             initial: np.ndarray | None = None, prior: np.ndarray | None = None) -> np.ndarray:
    """Transform T (4x4) that maps source points onto the target surfaces, robust to outliers (`prior`: a further
    start, e.g. the previous pair's motion)."""
    return ScanMatcher(target, config).align(source, initial, prior=prior)
