"""The estimator interface: scan t, scan t+1 and an optional motion mask in, per-point flow for scan t out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from ssf_common.geometry.se3 import rigid_flow
from ssf_flow_node.core.preprocess import PreprocessConfig, Sample, check_mask, check_scan, downsample, propagate_motion


@dataclass(frozen=True)
class FlowResult:
    """Flow for every input point of scan t (its sensor frame) and the ego motion found on the way."""

    flow: np.ndarray  # (N, 3) float32: pc1 + flow lies on pc2's surfaces
    ego: np.ndarray  # (4, 4) float64: maps scan-t coordinates of static points into scan t+1's frame


class FlowEstimator(Protocol):
    """Anything that estimates scene flow between two scans."""

    name: str

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; mask is an optional per-point dynamic probability for pc1."""
        ...


class PreparedPair(NamedTuple):
    """Validated scans, the points sampled from each and the mask on the sampled points of scan t."""

    pc1: np.ndarray
    pc2: np.ndarray
    sample1: Sample
    sample2: Sample
    mask: np.ndarray | None


def prepare(pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None, config: PreprocessConfig) -> PreparedPair:
    """Validate inputs and downsample both scans with the shared pre-processing."""
    xyz1, xyz2 = check_scan(pc1, "scan t"), check_scan(pc2, "scan t+1")
    mask = check_mask(mask, xyz1.shape[0])
    rng = np.random.default_rng(config.seed)
    sample1, sample2 = downsample(xyz1, config, rng), downsample(xyz2, config, rng)
    return PreparedPair(xyz1, xyz2, sample1, sample2, None if mask is None else mask[sample1.indices])


def finish(pair: PreparedPair, sample_flow: np.ndarray, ego: np.ndarray, config: PreprocessConfig,
           still: np.ndarray | None = None) -> FlowResult:
    """Flow for every point of scan t: the ego motion, plus the sampled points' motion relative to it carried to
    the points near them (except the `still` ones, e.g. the ground)."""
    ego_flow = rigid_flow(ego, pair.pc1)
    relative = sample_flow.astype(np.float32) - ego_flow[pair.sample1.indices]
    flow = ego_flow + propagate_motion(pair.pc1, pair.sample1, relative, config.propagate_k, config.propagate_radius,
                                       still)
    return FlowResult(flow=flow, ego=np.asarray(ego, dtype=np.float64))
