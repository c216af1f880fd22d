"""Segmenter configuration and the factory that builds a segmenter by name."""

from __future__ import annotations

from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError
from ssf_seg_node.core.base import SegInput, Segmenter
from ssf_seg_node.core.selection import StaticSelectionConfig

SEGMENTERS: tuple[str, ...] = ()


class SegConfig(Section):
    """Everything a segmenter needs; the same dotted names in YAML, ROS parameters and CLI flags."""

    method: str = Field("geometric", description="segmenter name")
    input: SegInput = Field(SegInput.BOTH, description="what the segmenter looks at: points | flow | both")
    selection: StaticSelectionConfig = StaticSelectionConfig()


def make_segmenter(name: str | None = None, config: SegConfig | None = None, device: str = "cpu") -> Segmenter:
    """The segmenter called `name` (default: config.method) built from its config."""
    config = config or SegConfig()
    name = name or config.method
    raise ConfigError(f"unknown segmenter '{name}'; choose one of {', '.join(SEGMENTERS) or '(none yet)'}")
