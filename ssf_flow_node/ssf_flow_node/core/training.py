"""Training of the ASF-style network: supervised multi-scale EPE or self-supervised Chamfer + smoothness."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
import torch
from pydantic import Field

from ssf_common.config import Section
from ssf_common.dataset.masks import noisy_mask
from ssf_common.dataset.pairs import ScanPair, read_pair
from ssf_common.errors import DataError
from ssf_common.geometry.se3 import transform_points, yaw_matrix
from ssf_common.geometry.torch_ops import gather, batched_knn, mean_nearest_distance
from ssf_common.training import StepTrainer
from ssf_flow_node.core.asf import checkpoint
from ssf_flow_node.core.asf.estimator import mask_channels
from ssf_flow_node.core.asf.network import AsfConfig, AsfNet, FlowPyramid
from ssf_flow_node.core.registration import RegistrationConfig, register


class TrainMode(str, Enum):
    """What the loss is made of."""

    SUPERVISED = "supervised"  # multi-scale EPE against ground-truth flow (ASF)
    SELF_SUPERVISED = "self_supervised"  # Chamfer distance to scan t+1 plus flow smoothness, no labels


class TrainConfig(Section):
    """Everything a training run depends on; stored in every checkpoint."""

    mode: TrainMode = TrainMode.SUPERVISED
    network: AsfConfig = AsfConfig()
    steps: int = Field(3000, ge=1)
    batch_size: int = Field(2, ge=1)
    points: int = Field(8192, ge=256, description="points per scan and sample")
    learning_rate: float = Field(1e-3, gt=0.0)
    weight_decay: float = Field(1e-4, ge=0.0, description="decoupled (AdamW): with Adam's L2 term, weights that get little gradient decay to zero")
    decay: float = Field(0.7, gt=0.0, le=1.0, description="learning-rate factor applied every decay_samples")
    decay_samples: int = Field(8000, ge=1)
    level_weights: tuple[float, float, float, float] = (0.02, 0.04, 0.08, 0.16)
    dynamic_weight: float = Field(10.0, ge=1.0, description="weight of points on moving objects in the supervised EPE (about 1 % of points)")
    mask_flip: float = Field(0.03, ge=0.0, le=1.0, description="share of points whose ground-truth mask is flipped")
    mask_drop: float = Field(0.1, ge=0.0, le=1.0, description="chance that a moving object is missing from the mask")
    mask_absent: float = Field(0.2, ge=0.0, le=1.0, description="chance that no mask is given")
    mask_segmentation: float = Field(0.5, ge=0.0, le=1.0, description="chance to use an exported segmentation mask")
    ego_noise_m: float = Field(0.01, ge=0.0, description="std of the translation noise on the ego compensation")
    ego_noise_deg: float = Field(0.05, ge=0.0, description="std of the yaw noise on the ego compensation")
    chamfer_weight: float = Field(1.0, ge=0.0)
    smooth_weight: float = Field(1.0, ge=0.0)
    smooth_neighbours: int = Field(8, ge=2)
    seed: int = 0
    threads: int = Field(1, ge=1, description="torch CPU threads")
    log_every: int = Field(20, ge=1)
    checkpoint_every: int = Field(200, ge=1)
    max_minutes: float = Field(0.0, ge=0.0, description="stop (and save) after this long; 0 = no limit")


class FlowBatch(NamedTuple):
    """Network inputs and targets for one step."""

    warped1: torch.Tensor  # (B, N, 3) ego-compensated scan t
    points2: torch.Tensor  # (B, N, 3)
    channels1: torch.Tensor  # (B, N, 2) mask channels
    residual: torch.Tensor  # (B, N, 3) ground-truth flow minus the ego compensation
    dynamic: torch.Tensor  # (B, N) 1.0 on points of moving objects


class FlowTrainResult(NamedTuple):
    """Where training ended."""

    step: int
    losses: list[float]  # one per step of this run
    checkpoint: Path


def training_mask(pair: ScanPair, config: TrainConfig, rng: np.random.Generator) -> np.ndarray | None:
    """The mask a sample is trained with: none, an exported segmentation, or noisy ground truth."""
    if rng.random() < config.mask_absent:
        return None
    if pair.mask1 is not None and rng.random() < config.mask_segmentation:
        return pair.mask1
    return noisy_mask(pair, rng, config.mask_flip, config.mask_drop)


def make_flow_sample(pair: ScanPair, ego: np.ndarray, config: TrainConfig, rng: np.random.Generator):
    """Resample, rotate (augmentation), ego-compensate with noise, and build the mask channels of one pair."""
    pick1 = rng.choice(pair.pc1.shape[0], config.points, replace=pair.pc1.shape[0] < config.points)
    pick2 = rng.choice(pair.pc2.shape[0], config.points, replace=pair.pc2.shape[0] < config.points)
    rotation = yaw_matrix(rng.uniform(-np.pi, np.pi))
    points1 = transform_points(rotation, pair.pc1[pick1])
    points2 = transform_points(rotation, pair.pc2[pick2])
    target = transform_points(rotation, pair.pc1[pick1] + pair.flow[pick1])
    noise = yaw_matrix(np.deg2rad(rng.normal(0.0, config.ego_noise_deg)))
    noise[:3, 3] = rng.normal(0.0, config.ego_noise_m, 3) * [1.0, 1.0, 0.3]
    compensation = noise @ rotation @ ego @ np.linalg.inv(rotation)
    warped = transform_points(compensation, points1)
    mask = training_mask(pair, config, rng)
    channels = mask_channels(None if mask is None else mask[pick1], config.points)
    return warped, points2, channels, target - warped, pair.dynamic1[pick1].astype(np.float32)


def multiscale_epe(pyramid: FlowPyramid, residual: torch.Tensor, dynamic: torch.Tensor, weights: tuple[float, ...],
                   dynamic_weight: float) -> torch.Tensor:
    """ASF's loss, weighted mean end-point error of each level's flow (finest first), with moving points up-weighted."""
    loss = torch.zeros((), device=residual.device)
    point_weight = 1.0 + (dynamic_weight - 1.0) * dynamic.unsqueeze(-1)
    for flow, index, weight in zip(pyramid.flows, pyramid.indices, weights):
        level_weight = gather(point_weight, index)[..., 0]
        error = (flow - gather(residual, index)).norm(dim=-1)
        loss = loss + weight * (level_weight * error).sum() / level_weight.sum()
    return loss


def smoothness(points: torch.Tensor, flow: torch.Tensor, k: int) -> torch.Tensor:
    """Mean flow difference to the k nearest neighbours."""
    neighbours = batched_knn(points, points, k)
    return (gather(flow, neighbours) - flow.unsqueeze(2)).norm(dim=-1).mean()


def flow_self_supervised_loss(pyramid: FlowPyramid, warped1: torch.Tensor, points2: torch.Tensor,
                              config: TrainConfig) -> torch.Tensor:
    """Chamfer between the moved scan t and scan t+1 (every level moves onto the full scan t+1) plus smoothness."""
    moved = warped1 + pyramid.full
    loss = config.level_weights[0] * config.chamfer_weight * (mean_nearest_distance(moved, points2) + mean_nearest_distance(points2, moved))
    for points1, flow, weight in zip(pyramid.points1, pyramid.flows, config.level_weights):
        loss = loss + weight * (config.chamfer_weight * mean_nearest_distance(points1 + flow, points2)
                                + config.smooth_weight * smoothness(points1, flow, config.smooth_neighbours))
    return loss


class Trainer(StepTrainer):
    """Owns the network, the optimizer, the data and the loop; resumable from its checkpoints."""

    def __init__(self, config: TrainConfig, files: list[Path], out: Path, device: str = "cpu",
                 log: Callable[[str], None] = print) -> None:
        if not files:
            raise DataError("no training pairs given")
        self.config, self.files, self.out, self.device, self.log = config, files, out, device, log
        torch.manual_seed(config.seed)
        self.network = AsfNet(config.network).to(device)
        self.optimizer = torch.optim.AdamW(self.network.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
        decay_steps = max(1, config.decay_samples // config.batch_size)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=decay_steps, gamma=config.decay)
        super().__init__()
        self.ego_cache: dict[Path, np.ndarray] = {}
        self.epes: list[float] = []  # each step's full-resolution EPE, for the progress line

    @classmethod
    def resume(cls, path: Path, files: list[Path], out: Path, device: str = "cpu", steps: int | None = None,
               max_minutes: float | None = None, log: Callable[[str], None] = print) -> "Trainer":
        """Continue a run from its checkpoint, with the config it carries (optionally more steps / time)."""
        saved = checkpoint.load_asf_checkpoint(path, device)
        if not saved.state:
            raise DataError(f"{path}: holds weights only, no optimizer state to resume from")
        overrides = {key: value for key, value in (("steps", steps), ("max_minutes", max_minutes)) if value is not None}
        config = TrainConfig.model_validate({**saved.training, **overrides})
        trainer = cls(config, files, out, device, log)
        trainer.restore(saved.state, saved.network.state_dict())
        return trainer

    def ego_of(self, path: Path, pair: ScanPair) -> np.ndarray:
        """The pair's ego motion: from its poses when it has them, else by registration (cached)."""
        if not np.allclose(pair.ego, np.eye(4)):
            return pair.ego
        if path not in self.ego_cache:
            self.ego_cache[path] = register(pair.pc1, pair.pc2, RegistrationConfig())
        return self.ego_cache[path]

    def batch(self) -> FlowBatch:
        """A random batch of augmented samples."""
        parts = []
        for index in self.rng.integers(len(self.files), size=self.config.batch_size):
            path = self.files[index]
            pair = read_pair(path)
            parts.append(make_flow_sample(pair, self.ego_of(path, pair), self.config, self.rng))
        stacked = [torch.from_numpy(np.stack(column).astype(np.float32)).to(self.device) for column in zip(*parts)]
        return FlowBatch(*stacked)

    def loss(self, batch: FlowBatch) -> tuple[torch.Tensor, float]:
        """The training loss of a batch and the EPE of its full-resolution flow."""
        pyramid = self.network(batch.warped1, batch.points2, batch.channels1)
        epe = float((pyramid.full.detach() - batch.residual).norm(dim=-1).mean())
        if self.config.mode is TrainMode.SUPERVISED:
            return multiscale_epe(pyramid, batch.residual, batch.dynamic, self.config.level_weights,
                                  self.config.dynamic_weight), epe
        return flow_self_supervised_loss(pyramid, batch.warped1, batch.points2, self.config), epe

    def batch_loss(self) -> torch.Tensor:
        """The training loss of the next batch (its EPE kept for the progress line)."""
        loss, epe = self.loss(self.batch())
        self.epes.append(epe)
        return loss

    def progress(self, last: int) -> str:
        """The mean EPE of the last steps."""
        return f" epe {np.mean(self.epes[-last:]):.4f}"

    def save(self) -> None:
        """Write the resumable checkpoint (network config, training config, optimizer state)."""
        checkpoint.save_asf_checkpoint(self.out, self.network, self.config.model_dump(mode="json"),
                                       self.optimizer_state())

    def run(self) -> FlowTrainResult:
        """Train until `steps` or `max_minutes`, logging progress and saving checkpoints."""
        losses = self.run_steps()
        return FlowTrainResult(self.step, losses, self.out)
