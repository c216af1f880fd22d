"""One config vocabulary: pydantic models read from YAML, ROS parameters and CLI flags with the same dotted names.

Every YAML the project takes (scenarios, graphs, params files, flow configs, bag metadata, `-p` values) is read
here: UTF-8 only, bounded in size, depth and alias expansion, no recursive aliases, no repeated keys, and every
failure is one ConfigError line that names the file (or flag) and the place.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from ssf_common.errors import ConfigError

_PLAIN_TEXT = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-./~+= "

ModelT = TypeVar("ModelT", bound=BaseModel)

MAX_YAML_BYTES = 4 * 1024 * 1024  # far above any config; a larger file is not one
MAX_YAML_DEPTH = 64  # nesting levels, aliases expanded
MAX_YAML_VALUES = 200_000  # scalars and collections, aliases expanded (no billion laughs)
MAX_VALUE_CHARS = 64 * 1024  # one `-p NAME:=VALUE` value
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_MERGE_TAG = "tag:yaml.org,2002:merge"


class Section(BaseModel):
    """Base of every config section: unknown keys are errors, numbers finite, values validated and immutable; fields
    renamed since a config was written are read under their old names too (`renamed`: old name -> name now)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    renamed: ClassVar[dict[str, str]] = {}

    @model_validator(mode="before")
    @classmethod
    def _current_names(cls, data: Any) -> Any:
        try:
            return current_names(cls, data) if isinstance(data, dict) else data
        except ConfigError as err:
            raise ValueError(str(err)) from None


def _section_of(model: Any, name: str) -> type[BaseModel] | None:
    """The config model of a model's field, when that field is a section."""
    field = model.model_fields.get(name) if isinstance(model, type) and issubclass(model, BaseModel) else None
    annotation = field.annotation if field is not None else None
    return annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None


def current_names(model: Any, values: dict[str, Any]) -> dict[str, Any]:
    """Nested config values with every renamed field (the model's and its sections') under its name now; a field given
    under both names is an error."""
    renamed = getattr(model, "renamed", {})
    current: dict[str, Any] = {}
    for key, value in values.items():
        name = renamed.get(key, key)
        if name != key and name in values:
            raise ConfigError(f"'{key}' is the old name of '{name}': give only '{name}'")
        section = _section_of(model, name)
        current[name] = current_names(section, value) if section is not None and isinstance(value, dict) else value
    return current


def current_name(model: Any, dotted: str) -> str:
    """A dotted field name with each renamed part under its name now ('rigid.dt' -> 'rigid.scan_period')."""
    parts = []
    for part in dotted.split("."):
        part = getattr(model, "renamed", {}).get(part, part)
        parts.append(part)
        model = _section_of(model, part)
    return ".".join(parts)


# Reading YAML


class _LimitError(yaml.MarkedYAMLError):
    """A document the safe reader refuses (too deep, too large, recursive alias, repeated key)."""


class _SafeLoader(yaml.SafeLoader):
    """PyYAML's safe loader, bounded: depth, expanded size, no recursive aliases, no repeated keys."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._open_anchors: list[str] = []

    def compose_node(self, parent: Node | None, index: object) -> Node:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            if event.anchor in self._open_anchors:
                raise _LimitError(
                    problem=f"alias *{event.anchor} refers to a node that contains it (recursive alias)",
                    problem_mark=event.start_mark,
                )
            return super().compose_node(parent, index)
        event = self.peek_event()
        if self._depth >= MAX_YAML_DEPTH:
            raise _LimitError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels", problem_mark=event.start_mark)
        anchor = getattr(event, "anchor", None)
        self._depth += 1
        if anchor is not None:
            self._open_anchors.append(anchor)
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1
            if anchor is not None:
                self._open_anchors.pop()

    def compose_mapping_node(self, anchor: str | None) -> MappingNode:
        node = super().compose_mapping_node(anchor)
        seen: set[tuple[str, str]] = set()
        for key, _ in node.value:
            if not isinstance(key, ScalarNode) or key.tag == _MERGE_TAG:
                continue
            if (key.tag, key.value) in seen:
                raise _LimitError(problem=f"key '{key.value}' appears twice in one mapping", problem_mark=key.start_mark)
            seen.add((key.tag, key.value))
        return node

    def get_single_data(self) -> Any:
        node = self.get_single_node()
        if node is None:
            return None
        _measure(node, 0, {})
        return self.construct_document(node)


# YAML 1.2 floats without a dot (1e30, 1e-5) are floats, as ROS 2 reads them, not strings.
_SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def _measure(node: Node, depth: int, sizes: dict[int, tuple[int, int]]) -> tuple[int, int]:
    """(values, height) of a node with aliases expanded; raise when either passes its bound."""
    if depth > MAX_YAML_DEPTH:
        raise _LimitError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels once aliases are expanded",
                          problem_mark=node.start_mark)
    known = sizes.get(id(node))
    if known is not None:
        if depth + known[1] > MAX_YAML_DEPTH:
            raise _LimitError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels once aliases are expanded",
                              problem_mark=node.start_mark)
        return known
    if isinstance(node, SequenceNode):
        children = list(node.value)
    elif isinstance(node, MappingNode):
        children = [part for pair in node.value for part in pair]
    else:
        children = []
    size, height = 1, 0
    for child in children:
        child_size, child_height = _measure(child, depth + 1, sizes)
        size += child_size
        height = max(height, child_height + 1)
        if size > MAX_YAML_VALUES:
            raise _LimitError(problem=f"expands to more than {MAX_YAML_VALUES} values (aliases)",
                              problem_mark=node.start_mark)
    sizes[id(node)] = (size, height)
    return size, height


def _yaml_problem(err: Exception) -> str:
    """' at line L, column C: problem' (one line) from any error PyYAML raises."""
    where = ""
    if isinstance(err, yaml.MarkedYAMLError):
        mark = err.problem_mark or err.context_mark
        problem = err.problem or err.context or "unreadable"
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    elif isinstance(err, yaml.reader.ReaderError) and isinstance(err.character, int):
        where, problem = f" at character {err.position}", f"unacceptable character #x{err.character:04x}"
    else:
        problem = str(err)
    return f"{where}: {' '.join(str(problem).split())}"


def load_yaml_text(text: str, source: str) -> Any:
    """Parse YAML text with the bounded safe loader; every failure is one ConfigError line naming `source`."""
    try:
        return yaml.load(text, Loader=_SafeLoader)  # noqa: S506 - _SafeLoader is a SafeLoader
    except _LimitError as err:
        raise ConfigError(f"{source}: refused{_yaml_problem(err)}") from None
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: not valid YAML{_yaml_problem(err)}") from None
    except (ValueError, OverflowError, TypeError) as err:  # a constructor on a value it cannot take
        raise ConfigError(f"{source}: not valid YAML{_yaml_problem(err)}") from None
    except RecursionError:
        raise ConfigError(f"{source}: refused: nested too deeply") from None


def decode_text(raw: bytes, source: str) -> str:
    """UTF-8 text of a file's bytes, or one ConfigError line naming the first bad byte."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{source}: not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start})") from None


def read_yaml_document(path: str | Path) -> Any:
    """The one YAML document of a file (any type), read with the limits above."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such file")
    if not path.is_file():
        raise ConfigError(f"{path}: not a regular file")
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_YAML_BYTES + 1)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read ({err.strerror or type(err).__name__})") from None
    if len(raw) > MAX_YAML_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_YAML_BYTES // (1024 * 1024)} MiB, too large for a YAML file here")
    return load_yaml_text(decode_text(raw, str(path)), str(path))


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping, turning every failure into one ConfigError line."""
    data = read_yaml_document(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings, got {type(data).__name__}")
    return data


# NAME:=VALUE overrides


def parse_override(item: str, flag: str = "-p") -> tuple[str, Any]:
    """One `NAME:=VALUE` (or `NAME=VALUE`) with its value read as YAML; ConfigError on anything malformed."""
    index = item.find("=")
    name = item[:index].removesuffix(":").strip() if index >= 0 else ""
    if index < 0 or not name:
        raise ConfigError(f"{flag} expects NAME:=VALUE, got {item!r}")
    if not _NAME.fullmatch(name):
        raise ConfigError(f"{flag} {item!r}: {name!r} is not a parameter name (letters, digits, '_', dotted)")
    text = item[index + 1 :]
    if not text.strip():
        raise ConfigError(f"{flag} {name}: the value is empty (write {name}:=\"\" for an empty string)")
    if len(text) > MAX_VALUE_CHARS:
        raise ConfigError(f"{flag} {name}: value longer than {MAX_VALUE_CHARS} characters")
    return name, load_yaml_text(text, f"{flag} {name}")


def param_text(value: Any) -> str:
    """The YAML text that reads back as `value` (what `-p NAME:=TEXT` carries)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = repr(value)
        mantissa, _, exponent = text.partition("e")
        return f"{mantissa}.0e{exponent}" if exponent and "." not in mantissa else text
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(param_text(item) for item in value) + "]"
    if isinstance(value, str):
        plain = value and value == value.strip() and all(char in _PLAIN_TEXT for char in value)
        if plain and load_yaml_text(value, "value") == value:
            return value
        return json.dumps(value)
    return str(value)


def parse_overrides(items: list[str], flag: str = "-p") -> dict[str, Any]:
    """Dotted settings from `NAME:=VALUE` items (as ROS 2 `-p`; `NAME=VALUE` too), values read as YAML; later wins."""
    return dict(parse_override(item, flag) for item in items)


# Layers and models


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
        if isinstance(node.get(leaf), dict) and not isinstance(value, dict):
            raise ConfigError(f"'{name}' is a section, not a value")
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
    field = field if field.isprintable() else repr(field)[1:-1]
    got = first.get("input")
    got_text = "" if isinstance(got, (dict, list)) else f" (got {_short(got)})"
    more = len(err.errors()) - 1
    tail = f"; and {more} more problem{'s' if more > 1 else ''}" if more else ""
    message = " ".join(str(first["msg"]).split())
    return f"{source}: field '{field}': {message}{got_text}{tail}"


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def build(model: type[ModelT], *layers: dict[str, Any], source: str = "config") -> ModelT:
    """Validate the deep merge of layers (nested or dotted dicts, later wins) into a config model."""
    merged: dict[str, Any] = {}
    try:
        for layer in layers:  # each under today's names first: an old name in a later layer still wins
            merged = merge(merged, current_names(model, unflatten(flatten(layer))))
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
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
