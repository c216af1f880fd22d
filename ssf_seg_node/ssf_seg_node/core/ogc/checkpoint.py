"""Segmentation network checkpoints that carry their config: save (atomically), load (safely), shipped weights."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Any, NamedTuple

import torch

from ssf_common.checkpoints import read_payload, unfit, write_payload
from ssf_seg_node.core.base import SegInput
from ssf_seg_node.core.ogc.network import OgcConfig, OgcNet, PointNetClassifier

FORMAT = "ssf-seg-net-1"
WEIGHTS_DIR = Path(__file__).resolve().parents[2] / "weights"


class NetworkKind(str, Enum):
    """Which network a checkpoint holds."""

    OGC = "ogc"  # K-slot masks, self-supervised
    POINTNET = "pointnet"  # per-point static/dynamic classifier, supervised

    def build(self, config: OgcConfig) -> OgcNet | PointNetClassifier:
        """A fresh network of this kind."""
        return OgcNet(config) if self is NetworkKind.OGC else PointNetClassifier(config)


class SegCheckpoint(NamedTuple):
    """A network with its config, and what training needs to resume."""

    kind: NetworkKind
    network: OgcNet | PointNetClassifier
    config: OgcConfig
    training: dict[str, Any]  # the training config as plain values
    state: dict[str, Any]  # optimizer, scheduler, step, validation history (empty for shipped weights)


def shipped_seg_weights(kind: NetworkKind, kind_input: SegInput) -> Path:
    """Path of the weights shipped for a network kind and input, e.g. weights/ogc_both.pt."""
    return WEIGHTS_DIR / f"{kind.value}_{SegInput(kind_input).value}.pt"


def save_seg_checkpoint(path: Path, kind: NetworkKind, network: torch.nn.Module, training: dict[str, Any],
                        state: dict[str, Any] | None = None) -> None:
    """Write a checkpoint atomically (temporary file, then rename)."""
    write_payload(path, {"format": FORMAT, "kind": kind.value, "network": network.config.model_dump(mode="json"),
                         "training": training, "weights": network.state_dict(), "state": state or {}})


def load_seg_checkpoint(path: Path, device: str = "cpu") -> SegCheckpoint:
    """Read a checkpoint; a missing, foreign or incompatible file is one DataError line."""
    payload = read_payload(path, FORMAT, "an ssf segmentation network checkpoint",
                           "train one with `ssf train seg` or pass the weights option", device)
    try:
        kind = NetworkKind(payload["kind"])
        config = OgcConfig.model_validate(payload["network"])
        network = kind.build(config)
        network.load_state_dict(payload["weights"])
    except Exception as err:
        raise unfit(path, err) from None
    network.to(device).eval()
    return SegCheckpoint(kind, network, config, dict(payload.get("training") or {}), dict(payload.get("state") or {}))
