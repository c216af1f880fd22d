"""Top-down PNG of an episode: road, structure, route, ego trajectory, agents and collisions."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim_bridge.footprints import Rectangles
from sim_bridge.simulator import Simulator
from sim_bridge.agents import AgentKind
from sim_bridge.world import PointClass, World
from ssf_common.render.figures import save_figure

STRUCTURE_COLOURS = {PointClass.BUILDING: "#9a9a9a", PointClass.PARKED_CAR: "#5f7f9f"}


def _band(world: World, inner: float, outer: float) -> np.ndarray:
    line = world.centreline
    s = line.s
    left = line.to_xy(s, np.full(len(s), outer))
    right = line.to_xy(s[::-1], np.full(len(s), inner))
    return np.concatenate([left, right])


def render_episode(sim: Simulator, path: str | Path, title: str = "") -> Path:
    """Draw the simulator's episode so far (route, structure, ego trajectory, agents, collisions) to a PNG."""
    world, log, frame = sim.world, sim.log, sim.frame
    agents, status = frame.agents, frame.status
    title = title or f"{sim.scenario.name} seed {sim.seed}"
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle, Polygon

    section = world.section
    fig, ax = plt.subplots(figsize=(12, 9), dpi=110)
    ax.add_patch(Polygon(_band(world, -section.road_edge, section.road_edge), closed=True, color="#3a3a3a", zorder=0))
    for side in (-1, 1):
        ax.add_patch(
            Polygon(
                _band(world, side * section.sidewalk_inner, side * section.sidewalk_outer),
                closed=True,
                color="#d8cfb8",
                zorder=0,
            )
        )
    structure = world.structure
    if len(structure.boxes):
        corners = Rectangles(
            structure.boxes[:, :2], structure.boxes[:, 2], structure.boxes[:, 3], structure.boxes[:, 4]
        ).corners()
        colours = [STRUCTURE_COLOURS.get(PointClass(c), "#888888") for c in structure.box_classes]
        ax.add_collection(
            PatchCollection([Polygon(c) for c in corners], facecolors=colours, edgecolors="none", zorder=1)
        )
    trees = structure.cylinder_classes == PointClass.VEGETATION
    ax.scatter(structure.crowns[:, 0], structure.crowns[:, 1], s=6, c="#3f8f3f", zorder=1, label="trees")
    ax.scatter(structure.cylinders[~trees, 0], structure.cylinders[~trees, 1], s=2, c="black", zorder=1, label="poles")
    route_s = np.linspace(0.0, world.route_length, 400)
    lane = sim.lane_offset
    route = world.centreline.to_xy(route_s, np.full(len(route_s), lane))
    ax.plot(route[:, 0], route[:, 1], "--", color="#f2d44b", lw=1, zorder=2, label="route")
    vehicles = agents.kind == AgentKind.VEHICLE
    if vehicles.any():
        boxes = Rectangles(
            agents.position[vehicles, :2], agents.yaw[vehicles], agents.size[vehicles, 0], agents.size[vehicles, 1]
        )
        ax.add_collection(
            PatchCollection([Polygon(c) for c in boxes.corners()], facecolors="#2f74d0", edgecolors="none", zorder=3)
        )
    people = ~vehicles
    if people.any():
        ax.add_collection(
            PatchCollection(
                [Circle(p, r) for p, r in zip(agents.position[people, :2], agents.size[people, 0] / 2)],
                facecolors="#f08c1a",
                edgecolors="none",
                zorder=3,
            )
        )
    trajectory = np.asarray(log.trajectory).reshape(-1, 2)
    ax.plot(trajectory[:, 0], trajectory[:, 1], color="#e0218a", lw=2, zorder=4, label="ego trajectory")
    ax.plot(*route[0], "o", color="white", mec="black", zorder=5, label="start")
    ax.plot(*route[-1], "*", color="gold", mec="black", ms=14, zorder=5, label="goal")
    for x, y, what in log.collisions:
        ax.plot(x, y, "x", color="red", ms=16, mew=3, zorder=6)
        ax.annotate(f"collision: {what}", (x, y), textcoords="offset points", xytext=(8, 8), color="red", fontsize=9)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{title}  outcome {status.outcome.name.lower()}, {status.time:.1f} s, {status.distance:.0f} m, "
        f"{status.average_speed:.2f} m/s, min clearance {status.min_clearance:.2f} m"
    )
    ax.legend(loc="upper left", fontsize=8)
    return save_figure(fig, path, bbox_inches="tight")
