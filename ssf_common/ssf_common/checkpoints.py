"""Network checkpoints as plain torch payloads tagged with a format name: written atomically, read safely (tensors
and plain values only), every way of failing one DataError line. The networks' own modules build on these two."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ssf_common.errors import DataError


def write_payload(path: Path, payload: dict[str, Any]) -> None:
    """torch.save to a temporary file beside `path`, then rename: a reader never sees half a checkpoint."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, temporary)
    temporary.replace(path)


def read_payload(path: Path, expected_format: str, what: str, how_to_make: str, device: str = "cpu") -> dict[str, Any]:
    """The payload of a checkpoint of `expected_format`; a missing, unreadable or foreign file is one DataError line
    naming `what` it should have been and `how_to_make` one."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such weights file ({how_to_make})")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # torch raises many types for corrupt or non-torch files
        first_line = str(err).splitlines()[0][:120] if str(err) else ""
        raise DataError(f"{path}: not a readable weights file ({type(err).__name__}: {first_line})") from None
    if not isinstance(payload, dict) or payload.get("format") != expected_format:
        raise DataError(f"{path}: not {what} (expected format '{expected_format}')")
    return payload


def unfit(path: Path, err: Exception) -> DataError:
    """The error for weights that do not fit the network their checkpoint describes."""
    return DataError(f"{path}: weights do not fit the network they describe ({str(err).splitlines()[0][:160]})")
