"""Strict JSON out: NaN and infinities become null (strict parsers reject them), a write failure is one line."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ssf_common.errors import DataError


def to_strict(value: Any, where: str = "$") -> Any:
    """The payload as plain JSON types: non-finite floats -> None, numpy -> Python, paths -> str."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, enum.Enum):
        return to_strict(value.value, where)
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_strict(dataclasses.asdict(value), where)
    if isinstance(value, Mapping):
        return {_key(key, where): to_strict(item, f"{where}.{key}") for key, item in value.items()}
    if isinstance(value, tuple) and hasattr(value, "_asdict"):
        return to_strict(value._asdict(), where)
    if isinstance(value, (list, tuple, np.ndarray)):
        return [to_strict(item, f"{where}[{index}]") for index, item in enumerate(value)]
    raise TypeError(f"{where}: {type(value).__name__} has no JSON form")


def _key(key: Any, where: str) -> str:
    if isinstance(key, str):
        return key
    if isinstance(key, (bool, int, float, np.integer, np.floating, enum.Enum)) or key is None:
        return json.dumps(to_strict(key, where))
    raise TypeError(f"{where}: a {type(key).__name__} key has no JSON form")


def dumps_strict(payload: Any, *, indent: int | None = 2) -> str:
    """JSON text that every strict parser accepts (no NaN, no Infinity)."""
    return json.dumps(to_strict(payload), indent=indent, allow_nan=False)


def write_json(path: str | Path, payload: Any, *, indent: int | None = 2) -> Path:
    """Write strict JSON (and a final newline); DataError in one line when the file cannot be written."""
    path = Path(path)
    text = dumps_strict(payload, indent=indent) + "\n"
    try:
        path.write_text(text)
    except OSError as err:
        raise DataError(f"{path}: cannot write ({err.strerror or type(err).__name__})") from None
    return path
