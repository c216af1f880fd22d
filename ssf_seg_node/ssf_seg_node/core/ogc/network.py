"""OGC-structured segmentation network: a PointNet++ encoder (FPS + ball grouping, GroupNorm, three set-abstraction
levels, feature propagation back to every point) and a K-slot mask head (learned queries, cross- then
self-attention decoder layers, cosine softmax); the same encoder with a per-point static/dynamic head is the
supervised PointNet++ baseline."""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from pydantic import Field
from torch import nn

from ssf_common.config import Section
from ssf_common.geometry.torch_ops import ball_group, farthest_points, gather, interpolate
from ssf_seg_node.core.base import SegInput


class OgcConfig(Section):
    """Network shape. OGC's: SA at N/4 (r 1 and 2 m), N/8 (r 4 m), N/16 (r 8 m), 64-d per point, 2 decoder layers of
    width 128 with 8 heads, K = 10, tau = 0.05; sized down here for CPU inference."""

    input: SegInput = Field(SegInput.BOTH, description="per-point input: points | flow | both")
    slots: int = Field(10, ge=2, description="K: soft masks per scan (the slot head)")
    ratios: tuple[int, int, int] = Field((4, 8, 16), description="each SA level keeps N / ratio points (FPS)")
    neighbours: tuple[int, int, int] = Field((16, 16, 16), description="ball-grouping neighbours per SA level")
    radii: tuple[float, float, float] = Field((2.0, 4.0, 8.0), description="ball radius (m) per SA level")
    input_width: int = Field(32, ge=4)
    widths: tuple[int, int, int] = Field((48, 96, 128), description="feature width of each SA level")
    embedding: int = Field(64, ge=8, description="per-point feature width after feature propagation")
    decoder_width: int = Field(128, ge=8)
    decoder_layers: int = Field(2, ge=1)
    heads: int = Field(4, ge=1)
    temperature: float = Field(0.05, gt=0.0, description="tau of the cosine softmax over slots")
    query_identity: bool = Field(True, description="add each slot's learned query to its attention inputs in every "
                                 "decoder layer (MaskFormer's query position): without it the decoder can merge the "
                                 "slots into one, and the masks become uniform for good")
    groups: int = Field(4, ge=1, description="GroupNorm groups")
    coordinate_scale: float = Field(0.05, gt=0.0, description="xyz multiplied by this in the input features")
    flow_scale: float = Field(5.0, gt=0.0, description="flow (m per frame) multiplied by this in the input features")

    @property
    def input_channels(self) -> int:
        """Per-point input channels of the chosen input."""
        return 6 if self.input is SegInput.BOTH else 3


class Encoding(NamedTuple):
    """What the encoder gives: features of every point, and of the N / ratio_2 points of the second level."""

    points: torch.Tensor  # (B, N, embedding)
    summary: torch.Tensor  # (B, N / ratios[1], widths[1])


class GroupNorm(nn.Module):
    """GroupNorm over the last (channel) dimension of (B, ..., C): statistics per sample and group."""

    def __init__(self, groups: int, channels: int) -> None:
        super().__init__()
        self.groups = groups if channels % groups == 0 else 1
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised x, same shape (channel moments first, then one fused scale and shift per channel)."""
        flat = x.reshape(x.shape[0], -1, x.shape[-1])
        mean = flat.mean(dim=1).reshape(x.shape[0], self.groups, -1).mean(dim=2)
        square = (flat * flat).mean(dim=1).reshape(x.shape[0], self.groups, -1).mean(dim=2)
        inverse = torch.rsqrt((square - mean * mean).clamp_min(0.0) + 1e-5)
        per_channel = x.shape[-1] // self.groups
        scale = self.weight * inverse.repeat_interleave(per_channel, dim=1)  # (B, C)
        shift = self.bias - mean.repeat_interleave(per_channel, dim=1) * scale
        shape = (x.shape[0],) + (1,) * (x.dim() - 2) + (x.shape[-1],)
        return torch.addcmul(shift.reshape(shape), x, scale.reshape(shape))


def ogc_mlp(sizes: list[int], groups: int) -> nn.Sequential:
    """Shared per-point layers: Linear, GroupNorm, ReLU."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), GroupNorm(groups, sizes[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers)


class OgcSetAbstraction(nn.Module):
    """FPS to N / ratio centres, ball grouping, shared MLP over (offset / radius, features), max pooling.

    The first layer is split into its feature part, applied once per point before grouping, and its offset part."""

    def __init__(self, ratio: int, k: int, radius: float, in_width: int, width: int, groups: int) -> None:
        super().__init__()
        self.ratio, self.k, self.radius = ratio, k, radius
        self.first_features = nn.Linear(in_width, width // 2)
        self.first_offsets = nn.Linear(3, width // 2, bias=False)
        self.first_norm = GroupNorm(groups, width // 2)
        self.mlp = ogc_mlp([width // 2, width // 2, width], groups)

    def forward(self, points: torch.Tensor, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Centres (B, M, 3) and their features (B, M, width)."""
        centres = gather(points, farthest_points(points, max(1, points.shape[1] // self.ratio)))
        group = ball_group(centres, points, self.k, self.radius)
        offsets = (gather(points, group) - centres.unsqueeze(2)) / self.radius
        first = gather(self.first_features(features), group) + self.first_offsets(offsets)
        return centres, self.mlp(torch.relu(self.first_norm(first))).max(dim=2).values


class FeaturePropagation(nn.Module):
    """Carry coarse features to finer points (inverse-distance, 3 neighbours), joined with the finer features."""

    def __init__(self, coarse_width: int, fine_width: int, width: int, groups: int) -> None:
        super().__init__()
        self.mlp = ogc_mlp([coarse_width + fine_width, width, width], groups)

    def forward(self, fine: torch.Tensor, coarse: torch.Tensor, fine_features: torch.Tensor,
                coarse_features: torch.Tensor) -> torch.Tensor:
        """Features (B, n_fine, width)."""
        carried = interpolate(coarse, coarse_features, fine, k=3)
        return self.mlp(torch.cat([carried, fine_features], dim=-1))


class PointEncoder(nn.Module):
    """PointNet++ encoder: per-point input features -> three SA levels -> feature propagation to every point."""

    def __init__(self, config: OgcConfig) -> None:
        super().__init__()
        self.config = config
        g = config.groups
        self.input_mlp = ogc_mlp([config.input_channels, config.input_width], g)
        widths = [config.input_width, *config.widths]
        self.abstraction = nn.ModuleList(
            OgcSetAbstraction(ratio, k, radius, widths[i], widths[i + 1], g)
            for i, (ratio, k, radius) in enumerate(zip(config.ratios, config.neighbours, config.radii)))
        self.propagation = nn.ModuleList([
            FeaturePropagation(widths[1], config.input_width, config.embedding, g),
            FeaturePropagation(widths[2], widths[1], widths[1], g),
            FeaturePropagation(widths[3], widths[2], widths[2], g),
        ])

    def input_features(self, points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        """Scaled xyz, scaled flow, or both, as the config's input says."""
        parts = {SegInput.POINTS: [points * self.config.coordinate_scale],
                 SegInput.FLOW: [flow * self.config.flow_scale],
                 SegInput.BOTH: [points * self.config.coordinate_scale, flow * self.config.flow_scale]}
        return torch.cat(parts[self.config.input], dim=-1)

    def forward(self, points: torch.Tensor, flow: torch.Tensor) -> Encoding:
        """Features of points (B, N, 3) with flow (B, N, 3): per point, and of the second level's points."""
        levels = [points]
        features = [self.input_mlp(self.input_features(points, flow))]
        for abstraction in self.abstraction:
            centres, level_features = abstraction(levels[-1], features[-1])
            levels.append(centres)
            features.append(level_features)
        carried = features[-1]
        for level in reversed(range(3)):
            carried = self.propagation[level](levels[level], levels[level + 1], features[level], carried)
            if level == 2:
                summary = carried  # the second level's points, for the slot queries
        return Encoding(carried, summary)


class DecoderLayer(nn.Module):
    """Slot queries attend to the point features (cross-attention), then to each other (self-attention)."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.cross = nn.MultiheadAttention(width, heads, batch_first=True)
        self.itself = nn.MultiheadAttention(width, heads, batch_first=True)
        self.feed = nn.Sequential(nn.Linear(width, 2 * width), nn.ReLU(), nn.Linear(2 * width, width))
        self.norms = nn.ModuleList(nn.LayerNorm(width) for _ in range(3))

    def forward(self, queries: torch.Tensor, memory: torch.Tensor, identity: torch.Tensor | float = 0.0) -> torch.Tensor:
        """Updated queries (B, K, width); `identity` (B, K, width) is added where the queries ask."""
        queries = self.norms[0](queries + self.cross(queries + identity, memory, memory, need_weights=False)[0])
        asking = queries + identity
        queries = self.norms[1](queries + self.itself(asking, asking, queries, need_weights=False)[0])
        return self.norms[2](queries + self.feed(queries))


class OgcNet(nn.Module):
    """K soft masks per point from points and flow: m_ik = softmax_k(cos(f_i, s_k) / tau); the slot queries attend to
    the features of the second SA level (N / 8 points), so no layer is wider than N x K."""

    def __init__(self, config: OgcConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = PointEncoder(config)
        width = config.decoder_width
        self.memory = nn.Linear(config.widths[1], width)
        self.queries = nn.Parameter(torch.randn(config.slots, width))
        self.decoder = nn.ModuleList(DecoderLayer(width, config.heads) for _ in range(config.decoder_layers))
        self.slot_head = nn.Sequential(nn.Linear(width, width), nn.ReLU(), nn.Linear(width, config.embedding),
                                       nn.LayerNorm(config.embedding))
        # the last GroupNorm has one group per channel: each channel centred over the scan's points, so that the
        # embeddings spread over directions instead of sharing the common one ReLU features have
        self.point_head = nn.Sequential(nn.Linear(config.embedding, config.embedding), nn.ReLU(),
                                        nn.Linear(config.embedding, config.embedding),
                                        GroupNorm(config.embedding, config.embedding))

    def forward(self, points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        """Soft masks (B, N, K), rows summing to 1."""
        encoding = self.encoder(points, flow)
        memory = self.memory(encoding.summary)
        slots = self.queries.unsqueeze(0).expand(points.shape[0], -1, -1)
        identity = slots if self.config.query_identity else 0.0
        for layer in self.decoder:
            slots = layer(slots, memory, identity)
        point_embedding = F.normalize(self.point_head(encoding.points), dim=-1)
        slot_embedding = F.normalize(self.slot_head(slots), dim=-1)
        return torch.softmax(point_embedding @ slot_embedding.transpose(1, 2) / self.config.temperature, dim=-1)

    @torch.no_grad()
    def predict(self, points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        """Soft masks (B, N, K) in inference mode."""
        self.eval()
        return self(points, flow)


class PointNetClassifier(nn.Module):
    """The supervised baseline: the same encoder with a per-point static/dynamic head (a logit of moving)."""

    def __init__(self, config: OgcConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = PointEncoder(config)
        self.head = nn.Sequential(nn.Linear(config.embedding, config.embedding), nn.ReLU(), nn.Linear(config.embedding, 1))

    def forward(self, points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        """Logits (B, N) that each point moves."""
        return self.head(self.encoder(points, flow).points)[..., 0]

    @torch.no_grad()
    def predict(self, points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        """Probabilities (B, N) that each point moves, in inference mode."""
        self.eval()
        return torch.sigmoid(self(points, flow))
