"""ASF-structured scene flow network: shared set-abstraction pyramid, set up-conv decoder, coarse-to-fine flow
from bi-directional point-to-patch cost volumes, with the motion mask as input channels."""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

import torch
from pydantic import Field
from torch import nn

from ssf_common.config import Section
from ssf_common.geometry.torch_ops import farthest_points, gather, interpolate, batched_knn

FLOW_LIMIT = 50.0
IMPLICIT_SENTINEL = -1.0


class MaskStrategy(str, Enum):
    """How the motion mask reaches the network (the paper's ablation)."""

    EXPLICIT = "explicit"  # mask channels concatenated to the point features
    IMPLICIT = "implicit"  # point features of dynamic points overwritten with a distinct value
    POINTS = "points"  # point cloud only


class AsfConfig(Section):
    """Network size; ASF's was points (2048, 512, 256, 128), k (16, 16, 16, 8), widths up to 512."""

    strategy: MaskStrategy = MaskStrategy.EXPLICIT
    points: tuple[int, int, int, int] = (2048, 512, 256, 128)
    neighbours: tuple[int, int, int, int] = (16, 16, 16, 8)
    encoder_width: int = Field(16, ge=4)
    level_widths: tuple[int, int, int, int] = (32, 64, 96, 128)
    cost_width: tuple[int, int, int, int] = (32, 32, 48, 64)
    cost_neighbours: int = Field(16, ge=2, description="points in each point-to-patch neighbourhood")
    patch_neighbours: int = Field(8, ge=2, description="points in each patch-to-patch aggregation")
    upconv_neighbours: int = Field(8, ge=2)
    flow_width: int = Field(64, ge=8)
    coordinate_scale: float = Field(0.05, gt=0.0, description="xyz multiplied by this in the point features")

    @property
    def mask_channels(self) -> int:
        """Extra input channels per point that the strategy adds."""
        return 2 if self.strategy is MaskStrategy.EXPLICIT else 0


class FlowPyramid(NamedTuple):
    """Flow per level, finest first, the level indices into the input points, and flow at every input point."""

    flows: list[torch.Tensor]  # (B, n_l, 3)
    indices: list[torch.Tensor]  # (B, n_l) indices into the input points of scan t
    full: torch.Tensor  # (B, N, 3)
    points1: list[torch.Tensor]  # (B, n_l, 3) level points of scan t (as given, i.e. warped by nothing)
    points2: list[torch.Tensor]  # (B, n_l, 3) level points of scan t+1


def asf_mlp(sizes: list[int]) -> nn.Sequential:
    """Shared 1x1 layers with LeakyReLU(0.1) over the last dimension."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.LeakyReLU(0.1)]
    return nn.Sequential(*layers)


class AsfSetAbstraction(nn.Module):
    """FPS + kNN grouping + shared MLP + max pooling."""

    def __init__(self, count: int, k: int, in_width: int, width: int) -> None:
        super().__init__()
        self.count, self.k = count, k
        self.mlp = asf_mlp([in_width + 3, width // 2, width // 2, width])

    def forward(self, points: torch.Tensor, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sampled points, their features and their indices into `points`."""
        index = farthest_points(points, self.count)
        centres = gather(points, index)
        group = batched_knn(centres, points, self.k)
        local = torch.cat([gather(points, group) - centres.unsqueeze(2), gather(features, group)], dim=-1)
        return centres, self.mlp(local).max(dim=2).values, index


class SetUpConv(nn.Module):
    """Carry features from a coarse level to a finer one: kNN grouping of coarse features, MLP, max."""

    def __init__(self, k: int, in_width: int, width: int) -> None:
        super().__init__()
        self.k = k
        self.mlp = asf_mlp([in_width + 3, width, width])

    def forward(self, fine: torch.Tensor, coarse: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Features (B, n_fine, width) for the fine points."""
        group = batched_knn(fine, coarse, self.k)
        local = torch.cat([gather(coarse, group) - fine.unsqueeze(2), gather(features, group)], dim=-1)
        return self.mlp(local).max(dim=2).values


class PointToPatchCost(nn.Module):
    """Bi-directional point-to-patch cost volume with attention weights, then patch-to-patch aggregation."""

    def __init__(self, width: int, out_width: int, k: int, patch_k: int) -> None:
        super().__init__()
        self.k, self.patch_k = k, patch_k
        self.pair = asf_mlp([2 * width + 3, out_width, out_width])
        self.attention = nn.Linear(out_width, 1)
        self.fuse = asf_mlp([2 * out_width, out_width])
        self.patch_weight = nn.Sequential(nn.Linear(3, 16), nn.LeakyReLU(0.1), nn.Linear(16, 1))

    def directed(self, points: torch.Tensor, features: torch.Tensor, others: torch.Tensor,
                 other_features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Attention-pooled cost of each point against its patch in the other cloud, and the patch indices."""
        group = batched_knn(points, others, self.k)
        offset = gather(others, group) - points.unsqueeze(2)
        pair = self.pair(torch.cat([features.unsqueeze(2).expand(-1, -1, group.shape[2], -1),
                                    gather(other_features, group), offset], dim=-1))
        weight = torch.softmax(self.attention(pair), dim=2)
        return (weight * pair).sum(dim=2), group

    def forward(self, warped1: torch.Tensor, features1: torch.Tensor, points2: torch.Tensor,
                features2: torch.Tensor) -> torch.Tensor:
        """Cost features (B, n, out_width) for each (warped) point of scan t."""
        forward_cost, group = self.directed(warped1, features1, points2, features2)
        backward_cost, _ = self.directed(points2, features2, warped1, features1)
        returned = gather(backward_cost, group[:, :, : self.patch_k]).mean(dim=2)
        cost = self.fuse(torch.cat([forward_cost, returned], dim=-1))
        patch = batched_knn(warped1, warped1, self.patch_k)
        weight = torch.softmax(self.patch_weight(gather(warped1, patch) - warped1.unsqueeze(2)), dim=2)
        return (weight * gather(cost, patch)).sum(dim=2)


class FlowHead(nn.Module):
    """Residual flow of one level from the point features, the cost, the carried-up flow features and flow."""

    def __init__(self, in_width: int, width: int) -> None:
        super().__init__()
        self.mlp = asf_mlp([in_width + 3, width, width])
        self.out = nn.Linear(width, 3)
        nn.init.normal_(self.out.weight, std=1e-3)  # an untrained head (almost) keeps the incoming flow
        nn.init.zeros_(self.out.bias)

    def forward(self, inputs: torch.Tensor, flow: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """New flow (clamped to +-FLOW_LIMIT) and the flow features for the next finer level."""
        features = self.mlp(torch.cat([inputs, flow], dim=-1))
        return (flow + self.out(features)).clamp(-FLOW_LIMIT, FLOW_LIMIT), features


class AsfNet(nn.Module):
    """Scene flow from two point clouds (B, N, 3) and optional per-point input channels of scan t."""

    def __init__(self, config: AsfConfig) -> None:
        super().__init__()
        self.config = config
        width = config.encoder_width
        self.encoder = asf_mlp([3 + config.mask_channels, width, width])
        widths = [width, *config.level_widths]
        self.abstraction = nn.ModuleList(
            AsfSetAbstraction(n, k, widths[i], widths[i + 1])
            for i, (n, k) in enumerate(zip(config.points, config.neighbours)))
        self.cost = nn.ModuleList(
            PointToPatchCost(w, c, config.cost_neighbours, config.patch_neighbours) for w, c in zip(config.level_widths, config.cost_width))
        self.upconv = nn.ModuleList(
            SetUpConv(config.upconv_neighbours, config.flow_width, config.flow_width) for _ in range(3))
        self.heads = nn.ModuleList(
            FlowHead(w + c + (config.flow_width if level < 3 else 0), config.flow_width)
            for level, (w, c) in enumerate(zip(config.level_widths, config.cost_width)))

    def input_features(self, points: torch.Tensor, channels: torch.Tensor | None) -> torch.Tensor:
        """Per-point input of the encoder: scaled xyz, plus the mask channels of the strategy."""
        scaled = points * self.config.coordinate_scale
        if self.config.strategy is MaskStrategy.EXPLICIT:
            if channels is None:
                channels = torch.zeros(*points.shape[:2], 2, device=points.device)
            return torch.cat([scaled, channels], dim=-1)
        if self.config.strategy is MaskStrategy.IMPLICIT and channels is not None:
            dynamic = (channels[..., :1] > 0.5) & (channels[..., 1:2] > 0.5)
            return torch.where(dynamic, torch.full_like(scaled, IMPLICIT_SENTINEL), scaled)
        return scaled

    def forward(self, points1: torch.Tensor, points2: torch.Tensor, channels1: torch.Tensor | None = None) -> FlowPyramid:
        """Coarse-to-fine flow of points1 towards points2; channels1 = (dynamic probability, mask present)."""
        pyramid1, features1, indices = self.encode(points1, self.input_features(points1, channels1))
        pyramid2, features2, _ = self.encode(points2, self.input_features(points2, None))
        flows: list[torch.Tensor] = []
        flow = torch.zeros_like(pyramid1[-1])
        flow_features = None
        for level in reversed(range(4)):
            if level < 3:
                flow = interpolate(pyramid1[level + 1], flow, pyramid1[level])
                flow_features = self.upconv[level](pyramid1[level], pyramid1[level + 1], flow_features)
            cost = self.cost[level](pyramid1[level] + flow, features1[level], pyramid2[level], features2[level])
            inputs = [features1[level], cost] + ([flow_features] if level < 3 else [])
            flow, flow_features = self.heads[level](torch.cat(inputs, dim=-1), flow)
            flows.insert(0, flow)
        full = interpolate(pyramid1[0], flows[0], points1)
        return FlowPyramid(flows, indices, full, pyramid1, pyramid2)

    def encode(self, points: torch.Tensor, inputs: torch.Tensor) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
        """Points, features and indices (into the input) of the four set-abstraction levels."""
        features = self.encoder(inputs)
        pyramid, levels, indices = [], [], []
        current, index = points, None
        for abstraction in self.abstraction:
            current, features, local = abstraction(current, features)
            index = local if index is None else torch.gather(index, 1, local)
            pyramid.append(current)
            levels.append(features)
            indices.append(index)
        return pyramid, levels, indices
