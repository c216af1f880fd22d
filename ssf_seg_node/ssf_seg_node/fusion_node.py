"""ssf_fusion_node: mutual-promotion loop of flow and segmentation (issue: fusion).

Until that stage's algorithm lands, the node joins the graph on its input topic and reports what arrives.
"""

from __future__ import annotations

from ssf_common import topics
from ssf_common.graph_node import ListeningNode
from ssf_common.middleware import QOS_DEFAULT, run


class FusionNode(ListeningNode):
    """Graph shell of ssf_fusion_node."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_fusion_node", {topics.MASK: ("sensor_msgs/msg/PointCloud2", QOS_DEFAULT)}, argv=argv)


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_seg_node ssf_fusion_node."""
    return run(FusionNode, argv)
