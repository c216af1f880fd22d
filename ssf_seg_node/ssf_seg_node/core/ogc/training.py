"""Training of the segmentation networks on exported pairs: `ogc` self-supervised (L_mot + L_SC + L_CD + smoothness,
no labels), `pointnet` supervised (per-point static/dynamic labels). Labels are read for validation only, except by
the supervised baseline. Resumable: checkpoints carry the network config, the training config and the optimizer."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import Field

from ssf_common.config import Section
from ssf_common.dataset.estimates import read_flow_estimate
from ssf_common.dataset.pairs import ScanPair, read_pair
from ssf_common.errors import DataError
from ssf_common.geometry.sampling import sample_indices
from ssf_common.geometry.se3 import rigid_flow, transform_points, yaw_matrix
from ssf_common.geometry.torch_ops import gather
from ssf_common.training import StepTrainer
from ssf_seg_node.core.geometric import GeometricConfig, fit_ego_motion
from ssf_seg_node.core.ogc import checkpoint
from ssf_seg_node.core.ogc.checkpoint import NetworkKind
from ssf_seg_node.core.ogc.config import NetworkRunConfig
from ssf_seg_node.core.ogc.losses import (chamfer_loss, consistency_loss, motion_loss, narrower, neighbourhood,
                                          rigid_mixture, slot_motions, smoothness_loss)
from ssf_seg_node.core.ogc.network import OgcConfig
from ssf_seg_node.core.ogc.segmenter import NetworkRunner, OgcSegmenter, PointNetSegmenter
from ssf_seg_node.core.selection import StaticSelectionConfig

GROUND_TRUTH_FLOW = "gt"


class LossWeights(Section):
    """Weights of the self-supervised terms (OGC: dynamic 10, smoothness 0.1 over kNN x3 + ball x1)."""

    motion: float = Field(10.0, ge=0.0, description="L_mot, rigid motion consistency")
    consistency: float = Field(10.0, ge=0.0, description="L_SC, per-slot variance of the flow the network sees")
    chamfer: float = Field(1.0, ge=0.0, description="L_CD of the slots' rigid mixture against scan t+1")
    smooth: float = Field(0.1, ge=0.0, description="mask smoothness (kNN and ball neighbourhoods)")
    knn_neighbours: int = Field(32, ge=1)
    knn_radius: float = Field(1.0, gt=0.0)
    knn_weight: float = Field(3.0, ge=0.0)
    ball_neighbours: int = Field(64, ge=1)
    ball_radius: float = Field(2.0, gt=0.0)
    ball_weight: float = Field(1.0, ge=0.0)
    smooth_anchors: int = Field(2048, ge=1, description="points whose neighbourhoods the smoothness is averaged over "
                                "(a random subset per step: the same expectation, a fraction of the cost)")


class AugmentConfig(Section):
    """Random changes of each training sample that keep its motions rigid."""

    rotate: bool = Field(True, description="rotate the pair about z by a uniform angle")
    mirror: float = Field(0.5, ge=0.0, le=1.0, description="chance to mirror y")
    scale: tuple[float, float] = Field((0.95, 1.05), description="uniform scale range")


class SegTrainConfig(Section):
    """Everything a training run depends on; stored in every checkpoint."""

    method: NetworkKind = Field(NetworkKind.OGC, description="ogc (self-supervised) | pointnet (supervised)")
    network: OgcConfig = OgcConfig()
    flow: str = Field("rigid", description="the flow trained on: 'gt' or a cached estimator's (`ssf train seg-flow`)")
    compensate_ego: bool = Field(True, description="feed the flow relative to the static scene (ego fitted to the flow)")
    losses: LossWeights = LossWeights()
    augment: AugmentConfig = AugmentConfig()
    dynamic_weight: float = Field(4.0, ge=1.0, description="pointnet: weight of moving points in the cross-entropy")
    steps: int = Field(3000, ge=1)
    batch_size: int = Field(1, ge=1)
    points: int = Field(8192, ge=64, description="points per scan and sample")
    learning_rate: float = Field(1e-3, gt=0.0)
    weight_decay: float = Field(1e-4, ge=0.0, description="decoupled (AdamW)")
    clip_norm: float = Field(1.0, ge=0.0, description="largest gradient norm per step (0 = no clipping): one bad "
                             "batch must not throw the slots into the uniform state they cannot leave")
    decay: float = Field(0.7, gt=0.0, le=1.0, description="learning-rate factor applied every decay_steps")
    decay_steps: int = Field(1000, ge=1)
    seed: int = 0
    threads: int = Field(1, ge=1, description="torch CPU threads")
    log_every: int = Field(20, ge=1)
    checkpoint_every: int = Field(100, ge=1)
    validate_every: int = Field(200, ge=1)
    validation_pairs: int = Field(16, ge=0, description="validation pairs used (labels read for scores only)")
    max_minutes: float = Field(0.0, ge=0.0, description="stop (and save) after this long; 0 = no limit")


class SegSample(NamedTuple):
    """One augmented training sample (float32 arrays)."""

    points: np.ndarray  # (n, 3) scan t
    flow: np.ndarray  # (n, 3) flow towards t+1, sensor frame
    motion: np.ndarray  # (n, 3) the flow the network sees (relative to the static scene, or raw)
    points2: np.ndarray  # (n, 3) scan t+1
    dynamic: np.ndarray  # (n,) 1.0 on moving points (the supervised baseline's target only)


class SegBatch(NamedTuple):
    """Samples stacked into tensors (B, n, ...)."""

    points: torch.Tensor
    flow: torch.Tensor
    motion: torch.Tensor
    points2: torch.Tensor
    dynamic: torch.Tensor


class Scores(NamedTuple):
    """Static/dynamic agreement with the ground truth."""

    accuracy: float
    moving_iou: float


class SegTrainResult(NamedTuple):
    """Where training ended."""

    step: int
    losses: list[float]  # one per step of this run
    validation: list[tuple[int, float, float]]  # (step, accuracy, moving IoU) of the whole run, resumed parts too
    checkpoint: Path


class TrainingPair(NamedTuple):
    """A pair with the flow trained on and the ego motion fitted to that flow."""

    pair: ScanPair
    flow: np.ndarray
    ego: np.ndarray


def motion_scores(predicted: np.ndarray, truth: np.ndarray) -> Scores:
    """Point accuracy and moving-class IoU TP / (TP + FP + FN) of boolean dynamic labels."""
    predicted, truth = np.asarray(predicted, bool), np.asarray(truth, bool)
    union = np.count_nonzero(predicted | truth)
    iou = np.count_nonzero(predicted & truth) / union if union else 1.0
    return Scores(float(np.mean(predicted == truth)) if truth.size else 1.0, float(iou))


def load_training_pair(path: Path, flow: str, ego_fit: GeometricConfig) -> TrainingPair:
    """A pair, its training flow (ground truth or cached) and the ego motion fitted to that flow."""
    pair = read_pair(path)
    estimate = pair.flow if flow == GROUND_TRUTH_FLOW else read_flow_estimate(path, flow, len(pair.pc1))
    return TrainingPair(pair, estimate, fit_ego_motion(pair.pc1.astype(np.float64), estimate.astype(np.float64), None, ego_fit))


def augmentation(config: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    """A random 4x4 similarity (yaw rotation, mirror of y, scale) applied to both scans of a sample."""
    transform = yaw_matrix(rng.uniform(-np.pi, np.pi)) if config.rotate else np.eye(4)
    if rng.random() < config.mirror:
        transform = np.diag([1.0, -1.0, 1.0, 1.0]) @ transform
    transform[:3, :3] *= rng.uniform(*config.scale)
    return transform


def make_seg_sample(item: TrainingPair, config: SegTrainConfig, rng: np.random.Generator) -> SegSample:
    """Resample both scans to `points`, transform them alike, and derive the network's flow input."""
    pair = item.pair
    pick1 = sample_indices(pair.pc1, config.points, rng, pad=True)
    pick2 = sample_indices(pair.pc2, config.points, rng, pad=True)
    change = augmentation(config.augment, rng)
    points = transform_points(change, pair.pc1[pick1])
    flow = transform_points(change, pair.pc1[pick1] + item.flow[pick1]) - points
    ego = change @ item.ego @ np.linalg.inv(change)  # still rigid: the similarity's scale cancels in the rotation
    motion = flow - rigid_flow(ego, points) if config.compensate_ego else flow
    return SegSample(points, flow, motion, transform_points(change, pair.pc2[pick2]), pair.dynamic1[pick1].astype(np.float32))


class SegTrainer(StepTrainer):
    """Owns the network, the optimizer, the data and the loop; resumable from its checkpoints."""

    def __init__(self, config: SegTrainConfig, files: list[Path], out: Path, validation: list[Path] | None = None,
                 device: str = "cpu", log: Callable[[str], None] = print) -> None:
        if not files:
            raise DataError("no training pairs given")
        self.config, self.files, self.out, self.device, self.log = config, files, out, device, log
        validation = list(validation or [])
        spacing = max(1, len(validation) // max(1, config.validation_pairs))
        self.validation_files = validation[::spacing][: config.validation_pairs]  # spread over the folder
        torch.manual_seed(config.seed)
        self.network = config.method.build(config.network).to(device)
        self.optimizer = torch.optim.AdamW(self.network.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=config.decay_steps, gamma=config.decay)
        super().__init__()
        self.history: list[tuple[int, float, float]] = []
        self.ego_fit = GeometricConfig()
        self.cache: dict[Path, TrainingPair] = {}

    @classmethod
    def resume(cls, path: Path, files: list[Path], out: Path, validation: list[Path] | None = None, device: str = "cpu",
               steps: int | None = None, max_minutes: float | None = None,
               log: Callable[[str], None] = print) -> "SegTrainer":
        """Continue a run from its checkpoint, with the config it carries (optionally more steps / time)."""
        saved = checkpoint.load_seg_checkpoint(path, device)
        if not saved.state:
            raise DataError(f"{path}: holds weights only, no optimizer state to resume from")
        overrides = {key: value for key, value in (("steps", steps), ("max_minutes", max_minutes)) if value is not None}
        config = SegTrainConfig.model_validate({**saved.training, **overrides})
        trainer = cls(config, files, out, validation, device, log)
        trainer.restore(saved.state, saved.network.state_dict())
        trainer.history = [tuple(row) for row in saved.state.get("validation", [])]
        return trainer

    def training_pair(self, path: Path) -> TrainingPair:
        """A pair with its flow and fitted ego motion (kept in memory after the first read)."""
        if path not in self.cache:
            self.cache[path] = load_training_pair(path, self.config.flow, self.ego_fit)
        return self.cache[path]

    def batch(self) -> SegBatch:
        """A random batch of augmented samples."""
        samples = [make_seg_sample(self.training_pair(self.files[index]), self.config, self.rng)
                   for index in self.rng.integers(len(self.files), size=self.config.batch_size)]
        return SegBatch(*(torch.from_numpy(np.stack(column).astype(np.float32)).to(self.device) for column in zip(*samples)))

    def loss(self, batch: SegBatch) -> torch.Tensor:
        """The training loss of a batch: the self-supervised sum for ogc, weighted cross-entropy for pointnet."""
        if self.config.method is NetworkKind.POINTNET:
            logits = self.network(batch.points, batch.motion)
            weight = 1.0 + (self.config.dynamic_weight - 1.0) * batch.dynamic
            return F.binary_cross_entropy_with_logits(logits, batch.dynamic, weight=weight)
        return seg_self_supervised_loss(self.network(batch.points, batch.motion), batch, self.config.losses)

    def segmenter(self) -> OgcSegmenter | PointNetSegmenter:
        """The current network as the segmenter inference uses."""
        run = NetworkRunConfig(compensate_ego=self.config.compensate_ego, points=self.config.points)
        runner = NetworkRunner(self.network, run, self.ego_fit, self.device)
        if self.config.method is NetworkKind.POINTNET:
            return PointNetSegmenter(runner)
        return OgcSegmenter(runner, StaticSelectionConfig())  # the selection inference uses by default

    def validate(self) -> Scores | None:
        """Mean accuracy and moving IoU of the current network on the validation pairs (labels only scored)."""
        if not self.validation_files:
            return None
        segmenter = self.segmenter()
        scores = []
        for path in self.validation_files:
            item = self.training_pair(path)
            result = segmenter.segment(item.pair.pc1, item.flow)
            scores.append(motion_scores(result.segmentation.dynamic, item.pair.dynamic1))
        self.network.train()
        return Scores(*(float(value) for value in np.mean(np.array(scores), axis=0)))

    def batch_loss(self) -> torch.Tensor:
        """The training loss of the next batch."""
        return self.loss(self.batch())

    def clip_gradients(self) -> None:
        """Bound the gradients' norm to clip_norm (when set)."""
        if self.config.clip_norm:
            torch.nn.utils.clip_grad_norm_(self.network.parameters(), self.config.clip_norm)

    def after_step(self) -> None:
        """Validate every validate_every steps and at the last."""
        if self.step % self.config.validate_every == 0 or self.step == self.config.steps:
            self.log_validation()

    def at_time_limit(self) -> None:
        """Validate the last weights unless this step just did."""
        if self.step % self.config.validate_every:
            self.log_validation()

    def save(self) -> None:
        """Write the resumable checkpoint (network config, training config, optimizer state, validation history)."""
        state = {**self.optimizer_state(), "validation": [list(row) for row in self.history]}
        checkpoint.save_seg_checkpoint(self.out, self.config.method, self.network, self.config.model_dump(mode="json"),
                                       state)

    def run(self) -> SegTrainResult:
        """Train until `steps` or `max_minutes`, logging progress, validating and saving checkpoints."""
        losses = self.run_steps()
        return SegTrainResult(self.step, losses, list(self.history), self.out)

    def log_validation(self) -> None:
        """Validate, keep the scores in the history and log them."""
        scores = self.validate()
        if scores is not None:
            self.history.append((self.step, float(scores.accuracy), float(scores.moving_iou)))
            self.log(f"step {self.step} validation: accuracy {100 * scores.accuracy:.2f} %, moving IoU "
                     f"{scores.moving_iou:.3f} ({len(self.validation_files)} pairs)")


def seg_self_supervised_loss(masks: torch.Tensor, batch: SegBatch, weights: LossWeights) -> torch.Tensor:
    """L_mot + L_SC + L_CD + smoothness, weighted; no labels involved."""
    motions = slot_motions(batch.points, batch.flow, masks)
    loss = weights.motion * motion_loss(batch.points, batch.flow, masks, motions)
    loss = loss + weights.consistency * consistency_loss(batch.motion, masks)
    if weights.chamfer:
        loss = loss + weights.chamfer * chamfer_loss(rigid_mixture(batch.points, masks, motions), batch.points2)
    if weights.smooth:
        loss = loss + weights.smooth * smoothness_terms(batch.points, masks, weights)
    return loss


def smoothness_terms(points: torch.Tensor, masks: torch.Tensor, weights: LossWeights) -> torch.Tensor:
    """kNN and ball-query smoothness, weighted, over random anchor points (one neighbour search for both)."""
    count = min(weights.smooth_anchors, points.shape[1])
    anchors = torch.stack([torch.randperm(points.shape[1], device=points.device)[:count] for _ in range(points.shape[0])])
    centres = gather(points, anchors)
    ball = neighbourhood(points, weights.ball_neighbours, weights.ball_radius, centres)
    if weights.knn_neighbours <= weights.ball_neighbours and weights.knn_radius <= weights.ball_radius:
        knn = narrower(points, ball, weights.knn_neighbours, weights.knn_radius, centres)
    else:
        knn = neighbourhood(points, weights.knn_neighbours, weights.knn_radius, centres)
    return (weights.knn_weight * smoothness_loss(masks, knn, anchors)
            + weights.ball_weight * smoothness_loss(masks, ball, anchors))
