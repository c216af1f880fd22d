"""Point operations for networks (torch tensors, batched): FPS, kNN and ball grouping without N x N matrices,
gathering, inverse-distance interpolation. KD-trees on the CPU, chunked distance blocks on other devices."""

from __future__ import annotations

import numpy as np
import torch

from ssf_common.geometry import neighbours
from ssf_common.geometry.sampling import farthest_point_indices

CHUNK = 1024


def batched_knn(query: torch.Tensor, reference: torch.Tensor, k: int) -> torch.Tensor:
    """Indices (B, M, k) of the k nearest reference points (B, N, 3) of each query point (B, M, 3)."""
    k = min(k, reference.shape[1])
    if query.device.type == "cpu":
        return knn_kdtree(query, reference, k)
    return knn_chunked(query, reference, k)


def knn_kdtree(query: torch.Tensor, reference: torch.Tensor, k: int) -> torch.Tensor:
    """kNN by a KD-tree per batch element (CPU)."""
    return torch.from_numpy(np.stack([neighbours.knn(reference[b].detach().numpy(), query[b].detach().numpy(), k).index
                                      for b in range(query.shape[0])]).astype(np.int64))


@torch.no_grad()
def knn_chunked(query: torch.Tensor, reference: torch.Tensor, k: int) -> torch.Tensor:
    """kNN by distance blocks of CHUNK query points at a time (any device)."""
    parts = []
    for start in range(0, query.shape[1], CHUNK):
        block = torch.cdist(query[:, start:start + CHUNK], reference)
        parts.append(block.topk(k, dim=2, largest=False).indices)
    return torch.cat(parts, dim=1)


def ball_group(query: torch.Tensor, reference: torch.Tensor, k: int, radius: float) -> torch.Tensor:
    """Indices (B, M, k) of the k nearest reference points within `radius` of each query point; places without
    a neighbour that close repeat the nearest one (PointNet++'s ball query, nearest first)."""
    index = batched_knn(query, reference, k)
    distance = (gather(reference, index) - query.unsqueeze(2)).norm(dim=-1)
    return torch.where(distance > radius, index[..., :1], index)


def farthest_points(points: torch.Tensor, count: int) -> torch.Tensor:
    """Indices (B, count) of farthest point sampling, started at each cloud's first point."""
    if count >= points.shape[1]:
        return torch.arange(points.shape[1], device=points.device).expand(points.shape[0], -1).clone()
    if points.device.type == "cpu":
        return torch.from_numpy(np.stack([farthest_point_indices(cloud.detach().numpy(), count) for cloud in points]))
    return farthest_torch(points, count)


@torch.no_grad()
def farthest_torch(points: torch.Tensor, count: int) -> torch.Tensor:
    """FPS in torch (for accelerators)."""
    batch, size, _ = points.shape
    chosen = torch.zeros(batch, count, dtype=torch.long, device=points.device)
    distance = torch.full((batch, size), float("inf"), device=points.device)
    current = torch.zeros(batch, dtype=torch.long, device=points.device)
    rows = torch.arange(batch, device=points.device)
    for i in range(count):
        chosen[:, i] = current
        distance = torch.minimum(distance, ((points - points[rows, current, None]) ** 2).sum(-1))
        current = distance.argmax(dim=1)
    return chosen


def gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """values (B, N, C) gathered at index (B, ...) -> (B, ..., C)."""
    batch = values.shape[0]
    flat = index.reshape(batch, -1)
    picked = torch.gather(values, 1, flat.unsqueeze(-1).expand(-1, -1, values.shape[-1]))
    return picked.reshape(*index.shape, values.shape[-1])


def interpolate(source: torch.Tensor, values: torch.Tensor, target: torch.Tensor, k: int = 3) -> torch.Tensor:
    """Inverse-distance kNN interpolation of values (B, N, C) at source points onto target points (B, M, 3)."""
    index = batched_knn(target, source, k)
    distance = (gather(source, index) - target.unsqueeze(2)).norm(dim=-1).clamp_min(1e-6)
    weight = 1.0 / distance
    weight = weight / weight.sum(dim=-1, keepdim=True)
    return (weight.unsqueeze(-1) * gather(values, index)).sum(dim=2)


def mean_nearest_distance(moved: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean distance of each moved point (B, N, 3) to its nearest target point (index search without gradient)."""
    return (gather(target, batched_knn(moved.detach(), target, 1))[:, :, 0] - moved).norm(dim=-1).mean()
