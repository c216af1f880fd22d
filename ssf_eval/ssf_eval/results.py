"""Result files: strict JSON (no NaN/Infinity), and the effective config that produced them, inside and beside."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import BaseModel

from ssf_common.errors import DataError


def plain(value: Any) -> Any:
    """value with NaN/Inf as None, tuples as lists, enums, numpy scalars and pydantic models as plain data."""
    if isinstance(value, BaseModel):
        return plain(value.model_dump(mode="json"))
    if isinstance(value, dict):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "value") and isinstance(getattr(value, "value"), (str, int)):  # Enum
        return value.value
    return value


def write_result(path: Path, payload: dict[str, Any], config: BaseModel | dict[str, Any] | None = None) -> Path:
    """Write payload (+ "config") as strict JSON, and the config as YAML beside it (FILE.config.yaml)."""
    document = plain({**payload, **({"config": config} if config is not None else {})})
    try:
        path.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n")
        if config is not None:
            config_path = path.with_suffix(".config.yaml")
            config_path.write_text(yaml.safe_dump(document["config"], sort_keys=False))
    except OSError as err:
        raise DataError(f"{path}: cannot write ({err.strerror})") from None
    return path
