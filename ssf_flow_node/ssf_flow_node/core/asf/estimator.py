"""The network as a FlowEstimator: shared pre-processing, ego compensation, network residual flow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ssf_common.errors import DataError
from ssf_flow_node.core.asf.checkpoint import load_asf_checkpoint, shipped_asf_weights
from ssf_flow_node.core.asf.network import AsfNet, MaskStrategy
from ssf_flow_node.core.base import FlowResult, finish, prepare
from ssf_flow_node.core.preprocess import PreprocessConfig
from ssf_common.geometry.se3 import transform_points
from ssf_flow_node.core.registration import RegistrationConfig, ScanMatcher


def mask_channels(mask: np.ndarray | None, count: int) -> np.ndarray:
    """The (dynamic probability, mask present) input channels of scan t."""
    channels = np.zeros((count, 2), dtype=np.float32)
    if mask is not None:
        channels[:, 0] = mask
        channels[:, 1] = 1.0
    return channels


class AsfFlowEstimator:
    """Ego motion by robust registration, then the network's flow on the ego-compensated scan t."""

    def __init__(self, network: AsfNet, preprocess: PreprocessConfig, registration: RegistrationConfig,
                 device: str = "cpu") -> None:
        self.network = network.to(device).eval()
        self.preprocess = preprocess
        self.registration = registration
        self.device = device
        self.name = f"asf-{network.config.strategy.value}"

    @classmethod
    def load(cls, weights: Path | None, preprocess: PreprocessConfig, registration: RegistrationConfig,
             device: str = "cpu", strategy: str | None = None) -> "AsfFlowEstimator":
        """Build from a checkpoint (default: the shipped weights of the strategy, explicit unless named)."""
        try:
            wanted = MaskStrategy(strategy) if strategy else None
        except ValueError:
            raise DataError(f"unknown mask strategy '{strategy}'; choose explicit, implicit or points") from None
        path = weights if weights is not None else shipped_asf_weights(wanted or MaskStrategy.EXPLICIT)
        checkpoint = load_asf_checkpoint(path, device)
        if wanted is not None and checkpoint.config.strategy is not wanted:
            raise DataError(f"{path}: trained for the '{checkpoint.config.strategy.value}' strategy, not '{wanted.value}'")
        return cls(checkpoint.network, preprocess, registration, device)

    def batch(self, array: np.ndarray) -> torch.Tensor:
        """A (1, N, C) float32 tensor on the estimator's device."""
        return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))[None].to(self.device)

    @torch.no_grad()
    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; the mask (dynamic probability per point) is fed as the network input."""
        pair = prepare(pc1, pc2, mask, self.preprocess)
        points1, points2 = pair.sample1.points, pair.sample2.points
        static = slice(None) if pair.mask is None else pair.mask <= 0.5
        ego = ScanMatcher(points2, self.registration).align(points1[static])
        warped = transform_points(ego, points1)
        channels = mask_channels(pair.mask, points1.shape[0])
        residual = self.network(self.batch(warped), self.batch(points2), self.batch(channels)).full[0].cpu().numpy()
        return finish(pair, warped + residual - points1, ego, self.preprocess)
