"""The clustering baselines of the paper's segmentation table: a Gaussian mixture (soft) and DBSCAN (hard) over
standardised points, flow or both (scikit-learn), each cluster a slot, then the paper's static selection."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.clustering import dbscan
from ssf_common.geometry.neighbours import nearest
from ssf_seg_node.core.base import SegInput, SegmentationResult, one_hot, result_from_slots
from ssf_seg_node.core.features import feature_columns, motion_input, selection_for, standardised
from ssf_seg_node.core.geometric import GeometricConfig
from ssf_seg_node.core.selection import StaticRule, StaticSelectionConfig, static_slots_of


class ClusteringInputConfig(Section):
    """What the clustering baselines share: the flow they see, and at most how many points are clustered."""

    compensate_ego: bool = Field(True, description="cluster the flow relative to the static scene, not the raw flow")
    fit_points: int = Field(8192, ge=16, description="at most this many points are clustered; the others join the "
                            "cluster of their nearest clustered point in feature space (gmm: the mixture's posterior)")
    static_rule: StaticRule | None = Field(StaticRule.VELOCITY, description="the static selection rule for this "
                                           "method (null: selection.rule); the clusters split the static scene, so the "
                                           "largest one is only part of it")
    min_instance_points: int = Field(5, ge=1, description="smaller moving clusters get no instance id")
    seed: int = 0


class GmmConfig(ClusteringInputConfig):
    """Gaussian mixture over the features (soft slots = posterior probabilities)."""

    components: int = Field(10, ge=1, description="K, as many slots as the network has")
    covariance: str = Field("full", pattern="^(full|tied|diag|spherical)$")
    max_iterations: int = Field(50, ge=1)
    fit_points: int = Field(4096, ge=16, description="at most this many points fit the mixture; every point gets "
                            "its posterior")


class DbscanConfig(ClusteringInputConfig):
    """DBSCAN over the standardised features (one slot per cluster, noise in a slot of its own)."""

    eps: float = Field(0.35, gt=0.0, description="neighbourhood radius in standardised feature units")
    min_samples: int = Field(10, ge=1)


class ClusteringSegmenter:
    """Features -> clusters (slots) -> the paper's static selection."""

    def __init__(self, method: str, kind: SegInput, config: GmmConfig | DbscanConfig, selection: StaticSelectionConfig,
                 ego_fit: GeometricConfig) -> None:
        self.method, self.kind, self.config, self.ego_fit = method, SegInput(kind), config, ego_fit
        self.selection = selection_for(selection, config.static_rule, self.kind)
        self.name = f"{method}-{self.kind.value}"

    def segment(self, points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None = None,
                ego: np.ndarray | None = None) -> SegmentationResult:
        """Static scene and moving objects of scan t from clusters of its points and/or flow."""
        points = np.asarray(points, np.float64)[:, :3]
        # 1. standardised features: the points, the flow relative to the static scene, or both
        motion = motion_input(points, flow, ego, previous, self.config.compensate_ego, self.ego_fit)
        features = standardised(feature_columns(points, motion.flow, self.kind))
        # 2. clusters as slots
        slots = self.cluster(features)
        # 3. the static slots, chosen as the paper does, from the flow the clustering saw
        static = static_slots_of(slots, motion.flow, points, np.eye(4) if self.config.compensate_ego else ego,
                                 self.selection)
        return result_from_slots(slots, static, self.config.min_instance_points)

    def cluster(self, features: np.ndarray) -> np.ndarray:
        """(N, K) slots: mixture posteriors (gmm) or one-hot clusters (dbscan), fitted on at most fit_points."""
        rng = np.random.default_rng(self.config.seed)
        fitted = np.arange(len(features))
        if len(features) > self.config.fit_points:
            fitted = np.sort(rng.choice(len(features), self.config.fit_points, replace=False))
        if isinstance(self.config, GmmConfig):
            return gmm_slots(features, fitted, self.config)
        labels, count = dbscan(features[fitted], self.config.eps, self.config.min_samples)
        if fitted.size < len(features):
            labels = labels[nearest(features[fitted], features).index]
        return one_hot(labels, max(count, 1))


def gmm_slots(features: np.ndarray, fitted: np.ndarray, config: GmmConfig) -> np.ndarray:
    """Posterior probabilities (N, K) of a Gaussian mixture fitted to features[fitted]."""
    from sklearn.mixture import GaussianMixture

    components = min(config.components, fitted.size)
    mixture = GaussianMixture(components, covariance_type=config.covariance, max_iter=config.max_iterations,
                              reg_covar=1e-4, random_state=config.seed).fit(features[fitted])
    return mixture.predict_proba(features).astype(np.float32)


def build_gmm(config, device: str = "cpu") -> ClusteringSegmenter:
    """Factory entry: the Gaussian-mixture baseline (config: SegConfig; no device needed)."""
    return ClusteringSegmenter("gmm", config.input, config.gmm, config.selection, config.geometric)


def build_dbscan(config, device: str = "cpu") -> ClusteringSegmenter:
    """Factory entry: the DBSCAN baseline (config: SegConfig; no device needed)."""
    return ClusteringSegmenter("dbscan", config.input, config.dbscan, config.selection, config.geometric)
