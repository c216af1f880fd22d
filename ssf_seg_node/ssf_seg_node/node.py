"""ssf_seg_node: segmentation of points + flow into the static scene and moving objects (issue: ssf_seg_node).

Until that stage's algorithm lands, the node joins the graph on its input topic and reports what arrives.
"""

from __future__ import annotations

from ssf_common import topics
from ssf_common.graph_node import ListeningNode
from ssf_common.middleware import QOS_DEFAULT, run


class SegNode(ListeningNode):
    """Graph shell of ssf_seg_node."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_seg_node", {topics.FLOW: ("sensor_msgs/msg/PointCloud2", QOS_DEFAULT)}, argv=argv)


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_seg_node ssf_seg_node."""
    return run(SegNode, argv)
