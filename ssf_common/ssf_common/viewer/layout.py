"""The shipped Foxglove layout (docs/viewer/ssf.foxglove-layout.json), built from foxglove-sdk's typed panel
configurations and written in the form the Foxglove app's "Import from file" reads (`configById` + `layout`).

The 3D panel shows the scan coloured by its static/dynamic label, the perceived obstacle boxes with their velocity
arrows and the plan (`/ssf/markers`), the true agents (`/sim/markers`), the plan as a path, the odometry path and
the static map; the plots show the fusion loop's Δ per iteration, the planner's commands and the MPC's solve time.

Regenerate the shipped file with `python -m ssf_common.viewer.layout docs/viewer/ssf.foxglove-layout.json`."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from ssf_common import topics

STATIC_GREY, DYNAMIC_RED = "#9aa0a6", "#e8413c"
APP_PANEL_TYPES = {"ThreeDee": "3D", "Plot": "Plot"}  # the SDK's panel names -> the app's panel id prefixes
# Topics the layout shows, with the ROS 2 type each must have (checked against the graph by the tests).
LAYOUT_TOPICS = {
    topics.SEMANTIC_FLOW: "sensor_msgs/msg/PointCloud2",
    topics.LIDAR_POINTS: "sensor_msgs/msg/PointCloud2",
    topics.MAP: "sensor_msgs/msg/PointCloud2",
    topics.SSF_MARKERS: "visualization_msgs/msg/MarkerArray",
    topics.MARKERS: "visualization_msgs/msg/MarkerArray",
    topics.PLAN: "nav_msgs/msg/Path",
    topics.PATH: "nav_msgs/msg/Path",
    topics.ODOM: "nav_msgs/msg/Odometry",
    topics.FUSION_STATE: "ssf_interfaces/msg/FusionState",
    topics.CMD_VEL: "geometry_msgs/msg/Twist",
    topics.PLANNER_STATE: "ssf_interfaces/msg/PlannerState",
}


def panels() -> dict[str, Any]:
    """The layout's panels (foxglove-sdk objects) by their Foxglove panel id."""
    import foxglove.layouts as fl

    scene = fl.ThreeDeePanel(title="SSF-PAN: scan by label, obstacles, plan, odometry", config=fl.ThreeDeeConfig(
        follow_tf="base_link", follow_mode="follow-position",
        camera_state=fl.ThreeDeeCameraState(distance=70.0, perspective=True, phi=45.0, theta_offset=-90.0,
                                            target_offset=(0.0, 0.0, 0.0), fovy=45.0, near=0.5, far=2000.0),
        scene=fl.BaseRendererSceneSettings(background_color="#1e1f24"),
        topics={
            topics.SEMANTIC_FLOW: fl.BaseRendererPointCloudTopicSettings(
                visible=True, color_mode="gradient", color_field="label", gradient=(STATIC_GREY, DYNAMIC_RED),
                min_value=0.0, max_value=1.0, point_size=2.5, decay_time=0.0),
            topics.LIDAR_POINTS: fl.BaseRendererPointCloudTopicSettings(
                visible=False, color_mode="colormap", color_field="intensity", color_map="turbo", point_size=1.5),
            topics.MAP: fl.BaseRendererPointCloudTopicSettings(
                visible=True, color_mode="flat", flat_color="#5f6b7a", point_size=1.0),
            topics.SSF_MARKERS: fl.BaseRendererRosMarkerTopicSettings(visible=True),
            topics.MARKERS: fl.BaseRendererRosMarkerTopicSettings(visible=True),
            topics.PLAN: fl.BaseRendererPosesTopicSettings(visible=True, type="line", line_width=0.25,
                                                           gradient=("#21c45d", "#21c45d")),
            topics.PATH: fl.BaseRendererPosesTopicSettings(visible=True, type="line", line_width=0.2,
                                                           gradient=("#19b5c8", "#19b5c8")),
            topics.ODOM: fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color="#e0218a"),
        },
    ))
    delta = fl.PlotPanel(title="Fusion loop: Δ_total per iteration", config=fl.PlotConfig(
        x_axis_val="custom", x_axis_path=fl.PlotXAxisPath(value=f"{topics.FUSION_STATE}.iteration", enabled=True),
        x_axis_label="iteration", y_axis_label="Δ", show_legend=True, time_range="all",
        paths=[fl.PlotSeries(value=f"{topics.FUSION_STATE}.delta_total", label="Δ_total", enabled=True,
                             show_line=False, color="#e8413c")],
    ))
    delta_time = fl.PlotPanel(title="Fusion loop: Δ over time", config=fl.PlotConfig(
        x_axis_val="timestamp", show_legend=True, y_axis_label="Δ",
        paths=[fl.PlotSeries(value=f"{topics.FUSION_STATE}.{field}", label=label, enabled=True,
                             timestamp_method="receiveTime")
               for field, label in (("delta_total", "Δ_total"), ("delta_flow", "Δ flow"), ("delta_mask", "Δ mask"))],
    ))
    planner = fl.PlotPanel(title="Planner: commands", config=fl.PlotConfig(
        x_axis_val="timestamp", show_legend=True,
        paths=[fl.PlotSeries(value=f"{topics.CMD_VEL}.linear.x", label="speed command (m/s)", enabled=True,
                             timestamp_method="receiveTime"),
               fl.PlotSeries(value=f"{topics.CMD_VEL}.angular.z", label="yaw rate command (rad/s)", enabled=True,
                             timestamp_method="receiveTime")],
    ))
    solve = fl.PlotPanel(title="Planner: MPC solve time and fallbacks", config=fl.PlotConfig(
        x_axis_val="timestamp", show_legend=True, y_axis_label="ms",
        paths=[fl.PlotSeries(value=f"{topics.PLANNER_STATE}.{field}", label=label, enabled=True,
                             timestamp_method="receiveTime")
               for field, label in (("solve_ms", "solve time (ms)"), ("fallbacks", "fallbacks so far"))],
    ))
    return {"3D!ssf": scene, "Plot!fusion_delta": delta, "Plot!fusion_time": delta_time, "Plot!planner": planner,
            "Plot!planner_solve": solve}


def foxglove_layout() -> dict[str, Any]:
    """The layout as the Foxglove app exports and imports it."""
    config_by_id = {}
    for panel_id, panel in panels().items():
        shape = json.loads(panel.to_json())
        assert panel_id.split("!")[0] == APP_PANEL_TYPES[shape["panelType"]], panel_id
        config_by_id[panel_id] = {**shape["config"], "foxglovePanelTitle": panel.title}
    return {
        "configById": config_by_id,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {
            "direction": "row", "splitPercentage": 64, "first": "3D!ssf",
            "second": {"direction": "column", "splitPercentage": 36, "first": "Plot!fusion_delta",
                       "second": {"direction": "column", "splitPercentage": 33, "first": "Plot!fusion_time",
                                  "second": {"direction": "column", "splitPercentage": 50, "first": "Plot!planner",
                                             "second": "Plot!planner_solve"}}},
        },
    }


def layout_text() -> str:
    """The layout file's text."""
    return json.dumps(foxglove_layout(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the layout to the file named on the command line."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m ssf_common.viewer.layout FILE.json", file=sys.stderr)
        return 2
    Path(args[0]).write_text(layout_text(), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
