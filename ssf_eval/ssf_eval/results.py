"""Result files: strict JSON (no NaN/Infinity), and the effective config that produced them, inside and beside."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from ssf_common.errors import ConfigError, DataError
from ssf_common.jsonio import to_strict, write_json


def check_bench_args(args: Any, min_frames: int) -> None:
    """Fail now, in one line, on a benchmark's --frames below `min_frames` or a --json it cannot write."""
    from ssf_common.paths import check_writable

    if args.frames < min_frames:
        raise ConfigError(f"--frames must be at least {min_frames}, got {args.frames}")
    if args.json is not None:
        check_writable(args.json, "result file")


def plain(value: Any) -> Any:
    """value as plain JSON data (pydantic models dumped, NaN/Inf as None, numpy as Python)."""
    if isinstance(value, BaseModel):
        return plain(value.model_dump(mode="json"))
    if isinstance(value, dict):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)) and not hasattr(value, "_asdict"):
        return [plain(item) for item in value]
    return to_strict(value)


def write_result(path: Path, payload: dict[str, Any], config: BaseModel | dict[str, Any] | None = None) -> Path:
    """Write payload (+ "config") as strict JSON, and the config as YAML beside it (FILE.config.yaml)."""
    document = plain({**payload, **({"config": config} if config is not None else {})})
    write_json(path, document)
    if config is not None:
        config_path = path.with_suffix(".config.yaml")
        try:
            config_path.write_text(yaml.safe_dump(document["config"], sort_keys=False))
        except OSError as err:
            raise DataError(f"{config_path}: cannot write ({err.strerror})") from None
    return path
