"""Network checkpoints that carry their config: save, load (safely), and the shipped weights."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple


from ssf_common.checkpoints import read_payload, unfit, write_payload
from ssf_flow_node.core.asf.network import AsfConfig, AsfNet, MaskStrategy

FORMAT = "ssf-asf-1"
WEIGHTS_DIR = Path(__file__).resolve().parents[2] / "weights"


class AsfCheckpoint(NamedTuple):
    """A network with its config, and what training needs to resume."""

    network: AsfNet
    config: AsfConfig
    training: dict[str, Any]  # the training config as plain values
    state: dict[str, Any]  # optimizer, scheduler, step (empty for shipped weights)


def shipped_asf_weights(strategy: MaskStrategy) -> Path:
    """Path of the weights shipped for a mask strategy."""
    return WEIGHTS_DIR / f"asf_{strategy.value}.pt"


def save_asf_checkpoint(path: Path, network: AsfNet, training: dict[str, Any],
                        state: dict[str, Any] | None = None) -> None:
    """Write a checkpoint atomically (temporary file, then rename)."""
    write_payload(path, {"format": FORMAT, "network": network.config.model_dump(mode="json"), "training": training,
                         "weights": network.state_dict(), "state": state or {}})


def load_asf_checkpoint(path: Path, device: str = "cpu") -> AsfCheckpoint:
    """Read a checkpoint; a missing, foreign or incompatible file is one DataError line."""
    payload = read_payload(path, FORMAT, "an ssf asf checkpoint",
                           "train one with `ssf train flow` or pass asf.weights", device)
    try:
        config = AsfConfig.model_validate(payload["network"])
        network = AsfNet(config)
        network.load_state_dict(payload["weights"])
    except Exception as err:
        raise unfit(path, err) from None
    network.to(device).eval()
    return AsfCheckpoint(network, config, dict(payload.get("training") or {}), dict(payload.get("state") or {}))
