"""The trained networks as Segmenters: `ogc` (K soft slots, then the paper's static selection) and `pointnet` (the
supervised per-point classifier, moving points joined into instances)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ssf_common.errors import DataError
from ssf_common.geometry.clustering import voxel_components
from ssf_common.geometry.neighbours import propagate
from ssf_seg_node.core.base import SegInput, SegmentationResult, result_from_slots
from ssf_seg_node.core.features import MotionInput, motion_input, selection_for
from ssf_seg_node.core.geometric import GeometricConfig
from ssf_seg_node.core.ogc.checkpoint import NetworkKind, load_seg_checkpoint, shipped_seg_weights
from ssf_seg_node.core.ogc.config import NetworkRunConfig
from ssf_seg_node.core.ogc.network import OgcNet, PointNetClassifier
from ssf_seg_node.core.selection import StaticSelectionConfig, static_slots_of


class NetworkRunner:
    """What both network segmenters share: the motion input, sampling at most `points`, carrying results back."""

    def __init__(self, network: OgcNet | PointNetClassifier, run: NetworkRunConfig, ego_fit: GeometricConfig,
                 device: str = "cpu") -> None:
        self.network = network.to(device).eval()
        self.run = run
        self.ego_fit = ego_fit
        self.device = device

    def tensor(self, array: np.ndarray) -> torch.Tensor:
        """A (1, N, C) float32 tensor on the runner's device."""
        return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))[None].to(self.device)

    def infer(self, points: np.ndarray, flow: np.ndarray, ego: np.ndarray | None,
              previous: np.ndarray | None) -> tuple[MotionInput, np.ndarray]:
        """The motion input, and the network's per-point output (N, C) for every point."""
        motion = motion_input(points, flow, ego, previous, self.run.compensate_ego, self.ego_fit)
        seen = np.arange(len(points))
        if len(points) > self.run.points:
            seen = np.sort(np.random.default_rng(0).choice(len(points), self.run.points, replace=False))
        output = self.network.predict(self.tensor(points[seen]), self.tensor(motion.flow[seen]))[0].cpu().numpy()
        output = output.reshape(len(seen), -1)
        if seen.size < len(points):
            output = propagate(points[seen], output, points, k=3)
        return motion, output


def selection_ego(ego: np.ndarray | None, compensated: bool) -> np.ndarray | None:
    """The ego motion the static selection compares speeds with: none left once the flow is compensated."""
    return np.eye(4) if compensated else ego


class OgcSegmenter:
    """The OGC-style network: K soft slot masks from points and flow, then the paper's static selection."""

    def __init__(self, runner: NetworkRunner, selection: StaticSelectionConfig) -> None:
        self.runner = runner
        self.selection = selection_for(selection, runner.run.static_rule, runner.network.config.input)
        self.name = f"ogc-{runner.network.config.input.value}"

    def segment(self, points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None = None,
                ego: np.ndarray | None = None) -> SegmentationResult:
        """Static scene and moving objects of scan t (the previous mask only helps to fit the ego motion)."""
        points = np.asarray(points, np.float32)[:, :3]
        # 1. K soft masks from the network, for every point
        motion, slots = self.runner.infer(points, flow, ego, previous)
        slots = slots / np.maximum(slots.sum(axis=1, keepdims=True), 1e-9)
        # 2. the static slots, as the paper chooses them, from the flow the network saw
        static = static_slots_of(slots, motion.flow, points, selection_ego(ego, self.runner.run.compensate_ego),
                                 self.selection)
        # 3. labels, probabilities and instances
        return result_from_slots(slots, static, self.runner.run.min_instance_points)


class PointNetSegmenter:
    """The supervised PointNet++ baseline: a probability of moving per point; moving points joined into instances."""

    def __init__(self, runner: NetworkRunner) -> None:
        self.runner = runner
        self.name = f"pointnet-{runner.network.config.input.value}"

    def segment(self, points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None = None,
                ego: np.ndarray | None = None) -> SegmentationResult:
        """Static scene and moving objects of scan t."""
        points = np.asarray(points, np.float32)[:, :3]
        # 1. the probability that each point moves
        _, probability = self.runner.infer(points, flow, ego, previous)
        probability = np.clip(probability[:, 0], 0.0, 1.0)
        # 2. moving points in touching voxels form one instance
        moving = np.flatnonzero(probability > 0.5)
        labels, count = voxel_components(points[moving], self.runner.run.instance_voxel)
        # 3. slots: the static scene (1 - p), the moving mass of points in no instance, then one slot per instance
        slots = np.zeros((len(points), 2 + count), np.float32)
        slots[:, 0] = 1.0 - probability
        slots[:, 1] = probability
        slots[moving, 1] = 0.0
        slots[moving, 2 + labels] = probability[moving]
        static = np.zeros(2 + count, bool)
        static[0] = True
        return result_from_slots(slots, static, self.runner.run.min_instance_points)


def load_runner(kind: NetworkKind, run: NetworkRunConfig, wanted: SegInput, ego_fit: GeometricConfig,
                device: str) -> NetworkRunner:
    """The network of a checkpoint (default: the shipped weights for the input), checked against what is asked."""
    path = Path(run.weights) if run.weights else shipped_seg_weights(kind, wanted)
    checkpoint = load_seg_checkpoint(path, device)
    if checkpoint.kind is not kind:
        raise DataError(f"{path}: holds a '{checkpoint.kind.value}' network, not '{kind.value}'")
    if checkpoint.config.input is not wanted:
        raise DataError(f"{path}: trained on input '{checkpoint.config.input.value}', not '{wanted.value}' "
                        f"(pick the input with -p input:=..., or other weights)")
    return NetworkRunner(checkpoint.network, run, ego_fit, device)


def build_ogc(config, device: str = "cpu") -> OgcSegmenter:
    """Factory entry: the OGC-style network segmenter (config: SegConfig)."""
    return OgcSegmenter(load_runner(NetworkKind.OGC, config.ogc, config.input, config.geometric, device), config.selection)


def build_pointnet(config, device: str = "cpu") -> PointNetSegmenter:
    """Factory entry: the supervised PointNet++ classifier (config: SegConfig)."""
    return PointNetSegmenter(load_runner(NetworkKind.POINTNET, config.pointnet, config.input, config.geometric, device))
