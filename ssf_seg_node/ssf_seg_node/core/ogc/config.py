"""How a segmentation network is run (weights, ego compensation, points); torch-free, so the config models load fast."""

from __future__ import annotations

from pydantic import Field

from ssf_common.config import Section
from ssf_seg_node.core.selection import StaticRule


class NetworkRunConfig(Section):
    """Running a trained segmentation network on a scan."""

    weights: str = Field("", description="checkpoint path; empty = the shipped weights for the input")
    compensate_ego: bool = Field(True, description="feed the flow relative to the static scene (ego motion given or "
                                 "fitted to the flow) instead of the raw sensor-frame flow")
    points: int = Field(8192, ge=64, description="the network sees at most this many points; the others take the "
                        "masks of their nearest seen points")
    static_rule: StaticRule | None = Field(StaticRule.VELOCITY, description="the static selection rule for this "
                                           "network (null: selection.rule); ogc spreads the static scene over several "
                                           "slots, so the largest slot is only part of it")
    min_instance_points: int = Field(5, ge=1, description="smaller moving segments get no instance id")
    instance_voxel: float = Field(0.6, gt=0.0, description="pointnet: voxel edge (m) joining moving points into instances")
