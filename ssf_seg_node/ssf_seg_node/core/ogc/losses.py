"""The self-supervised segmentation losses (the paper's L* = L_mot + L_SC + L_CD, plus OGC's smoothness): small pure
functions of soft masks (B, N, K), points and flow, beside the network."""

from __future__ import annotations

from typing import NamedTuple

import torch

from ssf_common.geometry.torch_ops import ball_group, gather, mean_nearest_distance

MIN_WEIGHT = 1e-6


class SlotMotions(NamedTuple):
    """One rigid motion per slot: rotations (B, K, 3, 3) and translations (B, K, 3)."""

    rotation: torch.Tensor
    translation: torch.Tensor

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """Points (B, N, 3) moved by every slot's motion: (B, K, N, 3)."""
        return torch.einsum("bkij,bnj->bkni", self.rotation, points) + self.translation.unsqueeze(2)


def slot_kabsch(source: torch.Tensor, target: torch.Tensor, weights: torch.Tensor) -> SlotMotions:
    """Per slot k the rigid T_k minimising sum_i w_ik |T_k s_i - t_i|^2 (weights (B, N, K)), differentiable.

    Weighted centroids, S = (P - mu_s)^T diag(w) (Q - mu_t), SVD, reflection fix R = V diag(1, 1, det(V U^T)) U^T,
    t = mu_t - R mu_s; in float64. Slots with no weight or a non-finite fit get the identity."""
    dtype = source.dtype
    source, target, weights = source.double(), target.double(), weights.double()
    total = weights.sum(dim=1)  # (B, K)
    safe = total.clamp_min(MIN_WEIGHT).unsqueeze(-1)
    mean_s = torch.einsum("bnk,bni->bki", weights, source) / safe
    mean_t = torch.einsum("bnk,bni->bki", weights, target) / safe
    cross = torch.einsum("bnk,bni,bnj->bkij", weights, source, target) - total[..., None, None] * (
        mean_s.unsqueeze(-1) * mean_t.unsqueeze(-2))
    u, _, vh = torch.linalg.svd(cross)
    v, ut = vh.transpose(-1, -2), u.transpose(-1, -2)
    fix = torch.ones_like(mean_s)
    fix[..., 2] = torch.sign(torch.det(v @ ut)).masked_fill(torch.det(v @ ut) == 0, 1.0)
    rotation = (v * fix.unsqueeze(-2)) @ ut
    translation = mean_t - torch.einsum("bkij,bkj->bki", rotation, mean_s)
    good = (total > MIN_WEIGHT) & torch.isfinite(rotation).all(dim=(-1, -2)) & torch.isfinite(translation).all(dim=-1)
    identity = torch.eye(3, dtype=rotation.dtype, device=rotation.device).expand_as(rotation)
    rotation = torch.where(good[..., None, None], rotation, identity)
    translation = torch.where(good[..., None], translation, torch.zeros_like(translation))
    return SlotMotions(rotation.to(dtype), translation.to(dtype))


def slot_motions(points: torch.Tensor, flow: torch.Tensor, masks: torch.Tensor) -> SlotMotions:
    """The rigid motion of each slot from P_t to P_t + S_t, as OGC uses it: fitted without gradient."""
    with torch.no_grad():
        return slot_kabsch(points, points + flow, masks)


def rigid_mixture(points: torch.Tensor, masks: torch.Tensor, motions: SlotMotions) -> torch.Tensor:
    """sum_k m_ik (R_k p_i + t_k): where the slots' rigid motions carry each point (B, N, 3); the gradient reaches
    the masks only."""
    return torch.einsum("bnk,bkni->bni", masks, motions.apply(points).detach())


def motion_loss(points: torch.Tensor, flow: torch.Tensor, masks: torch.Tensor,
                motions: SlotMotions | None = None) -> torch.Tensor:
    """L_mot, rigid motion consistency (OGC's dynamic loss): mean_i |sum_k m_ik T_k p_i - (p_i + f_i)|."""
    motions = slot_motions(points, flow, masks) if motions is None else motions
    return (rigid_mixture(points, masks, motions) - (points + flow)).norm(dim=-1).mean()


def consistency_loss(flow: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """L_SC, semantic scene flow consistency: per slot the mask-weighted variance of the flow around the slot's mean
    flow, averaged over the slots weighted by their share of the points (sum_k sum_i m_ik |f_i - mu_k|^2 / N).

    Weighting by size keeps the largest slot from absorbing outliers for free (in a plain slot average a point's
    squared deviation is divided by the size of the slot it sits in, so the static scene would swallow movers)."""
    total = masks.sum(dim=1)  # (B, K)
    mean = torch.einsum("bnk,bni->bki", masks, flow) / total.clamp_min(MIN_WEIGHT).unsqueeze(-1)
    second = torch.einsum("bnk,bn->bk", masks, (flow * flow).sum(dim=-1))
    within = (second - total * (mean * mean).sum(dim=-1)).clamp_min(0.0)  # sum_i m_ik |f_i - mu_k|^2
    return within.sum(dim=1).mean() / masks.shape[1]


def chamfer_loss(moved: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L_CD: bidirectional nearest-neighbour distance between the predicted P_t + S_t and P_t+1.

    With a fixed input flow this is a constant; it steers the masks when P_t + S_t is the slots' rigid mixture
    (the flow refined by the segmentation, as in OGC's object-aware refinement)."""
    return mean_nearest_distance(moved, target) + mean_nearest_distance(target, moved)


def neighbourhood(points: torch.Tensor, k: int, radius: float, centres: torch.Tensor | None = None) -> torch.Tensor:
    """(B, M, k) indices of the k nearest points within radius of each centre (default: every point), nearest first;
    the nearest repeats where there are fewer."""
    return ball_group(points if centres is None else centres, points, k, radius)


def narrower(points: torch.Tensor, neighbours: torch.Tensor, k: int, radius: float,
             centres: torch.Tensor | None = None) -> torch.Tensor:
    """The k-nearest-within-radius neighbourhood taken from a wider one (nearest first), without another search."""
    index = neighbours[..., :k]
    distance = (gather(points, index) - (points if centres is None else centres).unsqueeze(2)).norm(dim=-1)
    return torch.where(distance > radius, index[..., :1], index)


def smoothness_loss(masks: torch.Tensor, neighbours: torch.Tensor, anchors: torch.Tensor | None = None) -> torch.Tensor:
    """OGC's smoothness: mean L1 difference between a point's mask and its neighbours' masks (over the anchor points
    (B, M) whose neighbourhoods these are, default every point)."""
    centre = masks if anchors is None else gather(masks, anchors)
    return (gather(masks, neighbours) - centre.unsqueeze(2)).abs().sum(dim=-1).mean()
