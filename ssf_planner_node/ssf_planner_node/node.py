"""ssf_planner_node: RDA-style MPC around moving obstacles (issue: ssf_planner_node).

Until that stage's algorithm lands, the node joins the graph on its input topic and reports what arrives.
"""

from __future__ import annotations

from ssf_common import topics
from ssf_common.graph_node import ListeningNode
from ssf_common.middleware import QOS_DEFAULT, run


class PlannerNode(ListeningNode):
    """Graph shell of ssf_planner_node."""

    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_planner_node", {topics.OBSTACLES: ("ssf_interfaces/msg/ObstacleArray", QOS_DEFAULT)}, argv=argv)


def main(argv: list[str] | None = None) -> int:
    """Console script: ros2 run ssf_planner_node ssf_planner_node."""
    return run(PlannerNode, argv)
