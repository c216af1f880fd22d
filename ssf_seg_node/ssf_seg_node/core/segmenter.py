"""Segmenter configuration and the factory that builds a segmenter by name."""

from __future__ import annotations

import importlib
from typing import Callable

from pydantic import Field

from ssf_common.config import Section
from ssf_common.errors import ConfigError
from ssf_seg_node.core.base import SegInput, Segmenter
from ssf_seg_node.core.baselines import DbscanConfig, GmmConfig
from ssf_seg_node.core.geometric import GeometricConfig
from ssf_seg_node.core.ogc.config import NetworkRunConfig
from ssf_seg_node.core.selection import StaticSelectionConfig

# name -> "module:function" building it as function(config: SegConfig, device: str) -> Segmenter (imported lazily)
SEGMENTER_BUILDERS: dict[str, str] = {
    "geometric": "ssf_seg_node.core.geometric:build_geometric",
    "ogc": "ssf_seg_node.core.ogc.segmenter:build_ogc",
    "pointnet": "ssf_seg_node.core.ogc.segmenter:build_pointnet",
    "gmm": "ssf_seg_node.core.baselines:build_gmm",
    "dbscan": "ssf_seg_node.core.baselines:build_dbscan",
}


class SegConfig(Section):
    """Everything a segmenter needs; the same dotted names in YAML, ROS parameters and CLI flags."""

    method: str = Field("geometric", description="segmenter name")
    input: SegInput = Field(SegInput.BOTH, description="what the segmenter looks at: points | flow | both")
    selection: StaticSelectionConfig = StaticSelectionConfig()
    geometric: GeometricConfig = GeometricConfig()
    ogc: NetworkRunConfig = NetworkRunConfig()
    pointnet: NetworkRunConfig = NetworkRunConfig()
    gmm: GmmConfig = GmmConfig()
    dbscan: DbscanConfig = DbscanConfig()


def make_segmenter(name: str | None = None, config: SegConfig | None = None, device: str = "cpu") -> Segmenter:
    """The segmenter called `name` (default: config.method; `method-input` picks the input too) built from its config."""
    config = config or SegConfig()
    name = name or config.method
    method, _, suffix = name.partition("-")
    if suffix:
        if suffix not in {item.value for item in SegInput}:
            raise ConfigError(f"segmenter '{name}': input '{suffix}' is not one of points, flow, both")
        config = config.model_copy(update={"input": SegInput(suffix)})
    if method not in SEGMENTER_BUILDERS:
        raise ConfigError(f"unknown segmenter '{name}'; choose one of {', '.join(sorted(SEGMENTER_BUILDERS)) or '(none)'}")
    module, _, function = SEGMENTER_BUILDERS[method].partition(":")
    build: Callable[[SegConfig, str], Segmenter] = getattr(importlib.import_module(module), function)
    return build(config, device)
