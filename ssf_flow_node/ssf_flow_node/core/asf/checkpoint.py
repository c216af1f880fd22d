"""Network checkpoints that carry their config: save, load (safely), and the shipped weights."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import torch

from ssf_common.errors import DataError
from ssf_flow_node.core.asf.network import AsfConfig, AsfNet, MaskStrategy

FORMAT = "ssf-asf-1"
WEIGHTS_DIR = Path(__file__).resolve().parents[2] / "weights"


class Checkpoint(NamedTuple):
    """A network with its config, and what training needs to resume."""

    network: AsfNet
    config: AsfConfig
    training: dict[str, Any]  # the training config as plain values
    state: dict[str, Any]  # optimizer, scheduler, step (empty for shipped weights)


def shipped_weights(strategy: MaskStrategy) -> Path:
    """Path of the weights shipped for a mask strategy."""
    return WEIGHTS_DIR / f"asf_{strategy.value}.pt"


def save(path: Path, network: AsfNet, training: dict[str, Any], state: dict[str, Any] | None = None) -> None:
    """Write a checkpoint atomically (temporary file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "network": network.config.model_dump(mode="json"),
        "training": training,
        "weights": network.state_dict(),
        "state": state or {},
    }
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, temporary)
    temporary.replace(path)


def load(path: Path, device: str = "cpu") -> Checkpoint:
    """Read a checkpoint; a missing, foreign or incompatible file is one DataError line."""
    if not path.is_file():
        raise DataError(f"{path}: no such weights file (train one with `ssf train flow` or pass asf.weights)")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # torch raises many types for corrupt or non-torch files
        raise DataError(f"{path}: not a readable weights file ({type(err).__name__}: {str(err).splitlines()[0][:120]})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise DataError(f"{path}: not an ssf asf checkpoint (expected format '{FORMAT}')")
    try:
        config = AsfConfig.model_validate(payload["network"])
        network = AsfNet(config)
        network.load_state_dict(payload["weights"])
    except Exception as err:
        raise DataError(f"{path}: weights do not fit the network they describe ({str(err).splitlines()[0][:160]})") from None
    network.to(device).eval()
    return Checkpoint(network, config, dict(payload.get("training") or {}), dict(payload.get("state") or {}))
