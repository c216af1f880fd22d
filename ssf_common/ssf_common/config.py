"""One config vocabulary: pydantic models read from YAML, ROS parameters and CLI flags with the same dotted names."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from ssf_common.errors import ConfigError

ModelT = TypeVar("ModelT", bound=BaseModel)


class Section(BaseModel):
    """Base of every config section: unknown keys are errors, values are validated and immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def flatten(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Turn nested dicts into dotted names: {'lidar': {'rows': 64}} -> {'lidar.rows': 64}."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def unflatten(flat: dict[str, Any]) -> dict[str, Any]:
    """Turn dotted names back into nested dicts."""
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        node = nested
        *parents, leaf = name.split(".")
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"'{name}': '{part}' is a value, not a section")
            node = child
        node[leaf] = value
    return nested


def merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge override into a copy of base."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def describe_validation_error(err: ValidationError, source: str) -> str:
    """Condense a pydantic error to one line naming the first bad field."""
    first = err.errors()[0]
    field = ".".join(str(part) for part in first["loc"]) or "(root)"
    got = first.get("input")
    got_text = "" if isinstance(got, dict) else f" (got {got!r})"
    more = len(err.errors()) - 1
    tail = f"; and {more} more problem{'s' if more > 1 else ''}" if more else ""
    return f"{source}: field '{field}': {first['msg']}{got_text}{tail}"


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping, turning every failure into one ConfigError line."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}: not valid YAML{where}: {getattr(err, 'problem', err)}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings, got {type(data).__name__}")
    return data


def build(model: type[ModelT], *layers: dict[str, Any], source: str = "config") -> ModelT:
    """Validate the deep merge of layers (nested or dotted dicts, later wins) into a config model."""
    merged: dict[str, Any] = {}
    for layer in layers:
        merged = merge(merged, unflatten(flatten(layer)))
    try:
        return model.model_validate(merged)
    except ValidationError as err:
        raise ConfigError(describe_validation_error(err, source)) from None


def load(model: type[ModelT], path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> ModelT:
    """Load a config model from an optional YAML file plus dotted overrides."""
    layers = [read_yaml(path)] if path is not None else []
    return build(model, *layers, overrides or {}, source=str(path) if path else "config")


def dump(config: BaseModel) -> str:
    """Render a config as YAML, to be written beside every recording and result."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
