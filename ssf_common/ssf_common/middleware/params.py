"""ROS 2 command-line arguments (--ros-args -p, -r, --params-file) and parameter storage."""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ssf_common.config import flatten, parse_override, read_yaml
from ssf_common.errors import ConfigError


@dataclass
class RosArgs:
    """What a node's argv says about parameters, remappings and its name."""

    parameters: dict[str, Any] = field(default_factory=dict)
    remappings: dict[str, str] = field(default_factory=dict)
    node_name: str | None = None
    namespace: str | None = None
    params_files: list[Path] = field(default_factory=list)
    unparsed: list[str] = field(default_factory=list)


def parse_ros_args(argv: list[str], node_name: str) -> RosArgs:
    """Parse `--ros-args ... [--]` sections; anything outside them is left in `unparsed`."""
    result = RosArgs()
    file_params: dict[str, Any] = {}
    cli_params: dict[str, Any] = {}
    inside = False
    items = iter(argv)
    for arg in items:
        if arg == "--ros-args":
            inside = True
            continue
        if not inside:
            result.unparsed.append(arg)
            continue
        if arg == "--":
            inside = False
        elif arg in ("-p", "--param"):
            text = next(items, None)
            if text is None:
                raise ConfigError(f"{arg} expects NAME:=VALUE, got nothing")
            name, value = parse_override(text, arg)
            cli_params.update(flatten({name: value}) if isinstance(value, dict) else {name: value})
        elif arg == "--params-file":
            path = next(items, None)
            if path is None:
                raise ConfigError("--params-file needs a file")
            result.params_files.append(Path(path))
        elif arg in ("-r", "--remap"):
            source, target = _split_assignment(next(items, None), arg)
            if source == "__node":
                result.node_name = target
            elif source == "__ns":
                result.namespace = target
            else:
                result.remappings[source] = target
        elif arg in ("--log-level", "--enclave"):
            next(items, None)
        elif arg in ("--disable-rosout-logs", "--disable-stdout-logs", "--enable-rosout-logs"):
            continue
        else:
            raise ConfigError(f"unknown ROS argument '{arg}'")
    name = result.node_name or node_name
    for path in result.params_files:
        file_params.update(read_params_file(path, name))
    result.parameters = {**file_params, **cli_params}
    return result


def _split_assignment(text: str | None, flag: str) -> tuple[str, str]:
    if text is None or ":=" not in text:
        raise ConfigError(f"{flag} expects NAME:=VALUE, got {text!r}")
    name, value = text.split(":=", 1)
    return name, value


def read_params_file(path: Path, node_name: str) -> dict[str, Any]:
    """Parameters for one node from a ROS 2 params YAML (`node: {ros__parameters: {...}}`, wildcards too)."""
    params: dict[str, Any] = {}
    for pattern, values in params_file_sections(path):
        key = pattern.lstrip("/")
        if fnmatch.fnmatch(node_name, key) or key in ("**", "*"):
            params.update(values)
    return params


def params_file_sections(path: Path) -> list[tuple[str, dict[str, Any]]]:
    """Every section of a ROS 2 params YAML with its dotted parameters, each section checked."""
    sections = []
    for pattern, section in read_yaml(path).items():
        if not isinstance(section, dict) or "ros__parameters" not in section:
            raise ConfigError(f"{path}: section '{pattern}' needs a 'ros__parameters' mapping")
        values = section["ros__parameters"]
        if not isinstance(values, dict):
            raise ConfigError(f"{path}: '{pattern}.ros__parameters' must be a mapping")
        sections.append((str(pattern), flatten(values)))
    return sections


@dataclass(frozen=True)
class Parameter:
    """A declared parameter and its current value."""

    name: str
    value: Any


def coerce(name: str, value: Any, default: Any) -> Any:
    """Check an override against the declared default's type (ints widen to floats)."""
    if default is None or value is None:
        return value
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(default, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ConfigError(f"parameter '{name}' must be a finite number, got {value!r}")
        return float(value)
    elif isinstance(default, int) and isinstance(value, int) and not isinstance(value, bool):
        return value
    elif isinstance(default, str) and isinstance(value, str):
        return value
    elif isinstance(default, (list, tuple)) and isinstance(value, (list, tuple)):
        return list(value)
    elif not isinstance(default, (bool, int, float, str, list, tuple)):
        return value
    raise ConfigError(
        f"parameter '{name}' expects {type(default).__name__}, got {type(value).__name__} {value!r}"
    )
