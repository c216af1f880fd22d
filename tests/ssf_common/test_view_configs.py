"""The viewer configurations in docs/viewer: the Foxglove layout is what the code builds, both configurations show
the same topics, every topic and plotted field exists with the type the graph publishes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from ssf_common import messages, topics
from ssf_common.config import read_yaml
from ssf_common.viewer.layout import LAYOUT_TOPICS, foxglove_layout, layout_text

REPO = Path(__file__).resolve().parents[2]
LAYOUT = REPO / "docs" / "viewer" / "ssf.foxglove-layout.json"
RVIZ = REPO / "docs" / "viewer" / "ssf.rviz"
RVIZ_CLASSES = {
    "sensor_msgs/msg/PointCloud2": "rviz_default_plugins/PointCloud2",
    "visualization_msgs/msg/MarkerArray": "rviz_default_plugins/MarkerArray",
    "nav_msgs/msg/Path": "rviz_default_plugins/Path",
    "nav_msgs/msg/Odometry": "rviz_default_plugins/Odometry",
}
NUMERIC = {"float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}
PUBLISHER = re.compile(r'create_publisher\(\s*"([\w/]+)",\s*topics\.(\w+)')


def test_the_shipped_layout_is_what_the_code_builds():
    assert LAYOUT.read_text(encoding="utf-8") == layout_text(), \
        "regenerate: python -m ssf_common.viewer.layout docs/viewer/ssf.foxglove-layout.json"
    layout = json.loads(LAYOUT.read_text())
    assert set(layout) >= {"configById", "layout", "globalVariables", "userNodes"}
    placed = re.findall(r'"((?:3D|Plot)![\w]+)"', json.dumps(layout["layout"]))
    assert sorted(placed) == sorted(layout["configById"])  # every panel is placed, once


def field_type(type_name: str, path: list[str]) -> str:
    """The ROS type of a field path such as ['linear', 'x'] in a message type."""
    store = messages.typestore()
    for name in path:
        fields = dict(store.fielddefs[type_name][1])
        kind, detail = fields[name]
        if kind.name == "BASE":
            return detail[0]
        type_name = detail
    return type_name


def test_every_topic_and_plotted_field_exists():
    layout = foxglove_layout()
    scene = layout["configById"]["3D!ssf"]
    assert set(scene["topics"]) <= set(LAYOUT_TOPICS)
    assert scene["topics"][topics.SEMANTIC_FLOW]["colorField"] == "label"  # the scan coloured by label
    assert scene["followTf"] == "base_link"
    plotted = [series["value"] for panel_id, config in layout["configById"].items() if panel_id.startswith("Plot!")
               for series in config["paths"]]
    plotted += [config["xAxisPath"]["value"] for config in layout["configById"].values() if "xAxisPath" in config]
    assert f"{topics.FUSION_STATE}.delta_total" in plotted
    for value in plotted:
        topic, *path = value.split(".")
        assert field_type(LAYOUT_TOPICS[topic], path) in NUMERIC, value
    for type_name in LAYOUT_TOPICS.values():
        messages.msgdef(type_name)  # a schema the viewer can advertise


def test_the_graph_publishes_the_layout_topics_with_those_types():
    published: dict[str, set[str]] = {}
    packages = [manifest.parent for manifest in REPO.glob("*/package.xml")]
    for source in (path for package in packages for path in (package / package.name).rglob("*.py")):
        for type_name, name in PUBLISHER.findall(source.read_text(encoding="utf-8")):
            published.setdefault(getattr(topics, name), set()).add(type_name)
    for topic, type_name in LAYOUT_TOPICS.items():
        assert published.get(topic, {type_name}) == {type_name}, topic
    assert {topics.SEMANTIC_FLOW, topics.LIDAR_POINTS, topics.SSF_MARKERS, topics.MARKERS, topics.FUSION_STATE} \
        <= set(published)


def rviz_displays() -> list[dict]:
    return read_yaml(RVIZ)["Visualization Manager"]["Displays"]


def test_rviz_shows_the_same_topics_with_matching_displays():
    shown = {display["Topic"]["Value"]: display for display in rviz_displays() if "Topic" in display}
    assert set(shown) == set(foxglove_layout()["configById"]["3D!ssf"]["topics"])
    for topic, display in shown.items():
        assert display["Class"] == RVIZ_CLASSES[LAYOUT_TOPICS[topic]], topic
    labelled = shown[topics.SEMANTIC_FLOW]
    assert labelled["Color Transformer"] == "Intensity" and labelled["Channel Name"] == "label"
    assert (labelled["Min Intensity"], labelled["Max Intensity"]) == (0, 1)
    assert shown[topics.LIDAR_POINTS]["Topic"]["Reliability Policy"] == "Best Effort"  # the scan is sensor-data QoS
    assert read_yaml(RVIZ)["Visualization Manager"]["Global Options"]["Fixed Frame"] == "world"


@pytest.mark.parametrize("display", rviz_displays(), ids=lambda display: display["Name"])
def test_rviz_displays_are_default_plugins(display):
    assert display["Class"].startswith("rviz_default_plugins/") and isinstance(display["Enabled"], bool)
