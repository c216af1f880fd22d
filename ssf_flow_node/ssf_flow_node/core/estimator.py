"""Estimator configuration, the factory, and the baselines that bound the problem (zero flow, ego motion only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError
from ssf_flow_node.core.base import FlowEstimator, FlowResult, prepare
from ssf_flow_node.core.deskew import DeskewingEstimator
from ssf_flow_node.core.preprocess import PreprocessConfig
from ssf_common.geometry.se3 import rigid_flow
from ssf_flow_node.core.registration import RegistrationConfig, register
from ssf_flow_node.core.rigid import RigidConfig, RigidFlowEstimator

ESTIMATORS = ("zero", "ego", "rigid", "asf")

# Defaults for whole LiDAR scans (the node, `ssf flow estimate`): the N points go to non-ground structure at any range,
# thinned where the scan is dense so that far objects keep theirs, a few ground points join the ego registration (they
# pin its height, so a short schedule on half the usual refinement points converges: static EPE within 0.5 mm), and
# every other point gets its flow from them. Pairs already cut
# (`ssf eval flow`) use the plain defaults.
WHOLE_SCAN = {"preprocess": {"remove_ground": True, "max_range": 1000.0, "range_balance": True, "points_share": 0.3,
                             "object_height": 4.5},
              "registration": {"source_points": 1024, "refine_points": 4096, "refine_iterations": 20, "tolerance": 1e-4}}


class AsfRunConfig(Section):
    """How the network is run: weights file (empty: the shipped weights) and how the mask is fed."""

    weights: str = Field("", description="checkpoint path; empty = shipped weights")
    strategy: str = Field("", description="override the checkpoint's mask strategy (explicit|implicit|points); empty = as trained")


class FlowConfig(Section):
    """Everything an estimator needs; the same dotted names in YAML, ROS parameters and CLI flags."""

    estimator: str = Field("rigid", description="zero | ego | rigid | asf")
    deskew: bool = Field(True, description="where the scans' points carry time (a sweep that takes its period to "
                         "turn), move them to their stamps by the ego motion along the ground interpolated across the "
                         "sweep before the estimate, and each point's flow back to its time after it (core/deskew.py); scans without "
                         "time, or all of it zero, are estimated as given either way")
    preprocess: PreprocessConfig = PreprocessConfig()
    registration: RegistrationConfig = RegistrationConfig()
    rigid: RigidConfig = RigidConfig()
    asf: AsfRunConfig = AsfRunConfig()


class ZeroFlowEstimator:
    """Baseline: nothing moves (flow zero everywhere)."""

    name = "zero"

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Zero flow for every point of pc1."""
        pair = prepare(pc1, pc2, mask, PreprocessConfig())
        return FlowResult(flow=np.zeros_like(pair.pc1), ego=np.eye(4))


class EgoFlowEstimator:
    """Baseline: every point moves with the ego motion found by robust registration."""

    name = "ego"

    def __init__(self, preprocess: PreprocessConfig, registration: RegistrationConfig) -> None:
        self.preprocess = preprocess
        self.registration = registration
        self.previous: np.ndarray | None = None  # the last pair's ego motion (a stream's constant velocity)

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Ego-motion flow for every point of pc1 (dynamic points of the mask kept out of the registration; the last
        pair's ego motion one of its starts)."""
        pair = prepare(pc1, pc2, mask, self.preprocess)
        source = pair.sample1.points if pair.mask is None else pair.sample1.points[pair.mask <= 0.5]
        ego = self.previous = register(source, pair.sample2.points, self.registration, prior=self.previous)
        return FlowResult(flow=rigid_flow(ego, pair.pc1), ego=ego)


def make_estimator(name: str | None = None, config: FlowConfig | None = None, device: str = "cpu") -> DeskewingEstimator:
    """The estimator called `name` (default: config.estimator) built from its config, deskewing sweeps that carry time
    (config.deskew)."""
    config = config or FlowConfig()
    return DeskewingEstimator(_make(name or config.estimator, config, device), config.deskew)


def _make(name: str, config: FlowConfig, device: str) -> FlowEstimator:
    """The estimator called `name` on scans as given."""
    if name == "zero":
        return ZeroFlowEstimator()
    if name == "ego":
        return EgoFlowEstimator(config.preprocess, config.registration)
    if name == "rigid":
        return RigidFlowEstimator(config.preprocess, config.registration, config.rigid)
    if name == "asf" or name.startswith("asf-"):
        from ssf_flow_node.core.asf.estimator import AsfFlowEstimator

        strategy = name.partition("-")[2] or config.asf.strategy or None
        weights = Path(config.asf.weights) if config.asf.weights else None
        return AsfFlowEstimator.load(weights, config.preprocess, config.registration, device=device, strategy=strategy)
    raise ConfigError(f"unknown flow estimator '{name}'; choose one of {', '.join(ESTIMATORS)} (or asf-explicit|asf-implicit|asf-points)")
