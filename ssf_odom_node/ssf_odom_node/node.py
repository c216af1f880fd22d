"""ssf_odom_node: odometry from the static points and their flow (issue: ssf_odom_node).

Until that stage's algorithm lands, the node joins the graph on its input topic and reports what arrives.
"""

from __future__ import annotations

from ssf_common import topics
from ssf_common.graph_node import ListeningNode
from ssf_common.middleware import QOS_DEFAULT, run


class OdomNode(ListeningNode):
    """Graph shell of ssf_odom_node."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_odom_node", {topics.SEMANTIC_FLOW: ("sensor_msgs/msg/PointCloud2", QOS_DEFAULT)}, argv=argv)


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_odom_node ssf_odom_node."""
    return run(OdomNode, argv)
