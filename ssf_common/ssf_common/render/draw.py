"""Bird's-eye drawings with matplotlib: one frame (`draw_frame`), the animation's pixels (`FrameDrawer`), and the
episode picture (route overview, the last moments, the fusion loop's Δ per iteration)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ssf_common.records import MotionLabel, ObstacleKind, Obstacles
from ssf_common.render.frames import NS, EpisodeTrack, FusionLog, RenderConfig, ViewFrame

STATIC_COLOUR = "#9aa0a6"
RAW_COLOUR = "#7f9fbf"
TRUE_COLOURS = {ObstacleKind.VEHICLE: "#2f74d0", ObstacleKind.PEDESTRIAN: "#f08c1a", ObstacleKind.UNKNOWN: "#888888"}
PERCEIVED_COLOUR = "#e8413c"
ARROW_COLOUR = "#ffd21f"
PLAN_COLOUR = "#21c45d"
EGO_COLOUR = "#e0218a"
ODOMETRY_COLOUR = "#19b5c8"
INSTANCE_COLOURS = ("#3cb44b", "#42d4f4", "#f58231", "#911eb4", "#4363d8", "#f032e6", "#bfef45", "#9a6324",
                    "#fabed4", "#808000")  # no red: red is what the perception saw
BACKGROUND = "#1e1f24"
OVERVIEW_MARGIN_M = 40.0


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_frame(ax: Any, frame: ViewFrame, config: RenderConfig, *, legend: bool = True) -> None:
    """Draw one frame on a matplotlib axes, centred on the ego, `view_radius_m` around it."""
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Polygon

    ax.set_facecolor(BACKGROUND)
    centre = frame.ego_pose[:2, 3]
    radius = config.view_radius_m
    _draw_points(ax, frame)
    if frame.agents is not None and len(frame.agents):
        colours = [TRUE_COLOURS.get(ObstacleKind(int(k)), "#888888") for k in frame.agents.kinds]
        ax.add_collection(PolyCollection(frame.agents.corners(), facecolors="none", edgecolors=colours, linewidths=1.2,
                                         zorder=3))
    if frame.perceived is not None and len(frame.perceived):
        _draw_perceived(ax, frame.perceived)
    if len(frame.path):
        ax.plot(frame.path[:, 0], frame.path[:, 1], color=EGO_COLOUR, lw=1.8, zorder=4)
    if frame.odometry_path is not None:
        ax.plot(frame.odometry_path[:, 0], frame.odometry_path[:, 1], "--", color=ODOMETRY_COLOUR, lw=1.2, zorder=4)
    if frame.plan is not None and len(frame.plan):
        ax.plot(frame.plan[:, 0], frame.plan[:, 1], "-o", color=PLAN_COLOUR, lw=2, ms=2.5, zorder=6)
    ego = Obstacles(frame.stamp_ns, "world", ids=[0], kinds=[ObstacleKind.VEHICLE], centres=[frame.ego_pose[:3, 3]],
                    sizes=[[config.ego_length, config.ego_width, 1.5]], yaws=[np.arctan2(frame.ego_pose[1, 0],
                                                                                      frame.ego_pose[0, 0])],
                    velocities=[[0.0, 0.0, 0.0]])
    ax.add_patch(Polygon(ego.corners()[0], closed=True, facecolor=EGO_COLOUR, edgecolor="white", lw=0.8, zorder=7))
    ax.set_xlim(centre[0] - radius, centre[0] + radius)
    ax.set_ylim(centre[1] - radius, centre[1] + radius)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    if legend:
        ax.legend(handles=_legend_handles(frame), loc="upper left", fontsize=6.5, framealpha=0.75)


def _legend_handles(frame: ViewFrame) -> list[Any]:
    """Legend entries for the layers this frame has."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    present = lambda item: item is not None and len(item) > 0  # noqa: E731
    layers = [
        (frame.labels is None, Line2D([], [], ls="", marker=".", color=RAW_COLOUR, label="LiDAR scan")),
        (frame.labels is not None, Line2D([], [], ls="", marker=".", color=STATIC_COLOUR, label="static points")),
        (frame.labels is not None, Line2D([], [], ls="", marker=".", color=INSTANCE_COLOURS[0],
                                          label="dynamic points (per object)")),
        (present(frame.agents), Patch(facecolor="none", edgecolor=TRUE_COLOURS[ObstacleKind.VEHICLE],
                                      label="true agents")),
        (present(frame.perceived), Patch(facecolor=PERCEIVED_COLOUR, alpha=0.5, edgecolor=PERCEIVED_COLOUR,
                                         label="perceived obstacles")),
        (present(frame.perceived), Line2D([], [], color=ARROW_COLOUR, label="their velocity (1 s)")),
        (present(frame.plan), Line2D([], [], color=PLAN_COLOUR, marker="o", ms=3, label="MPC plan")),
        (True, Line2D([], [], color=EGO_COLOUR, label="ego path")),
        (present(frame.odometry_path), Line2D([], [], color=ODOMETRY_COLOUR, ls="--", label="odometry")),
    ]
    return [handle for shown, handle in layers if shown]


def _draw_points(ax: Any, frame: ViewFrame) -> None:
    xy = frame.points[:, :2]
    if frame.labels is None:
        ax.scatter(xy[:, 0], xy[:, 1], s=0.4, c=RAW_COLOUR, lw=0, zorder=1)
        return
    dynamic = frame.labels == MotionLabel.DYNAMIC
    ax.scatter(xy[~dynamic, 0], xy[~dynamic, 1], s=0.4, c=STATIC_COLOUR, lw=0, zorder=1)
    if dynamic.any():
        instances = frame.instances[dynamic] if frame.instances is not None else np.zeros(int(dynamic.sum()), int)
        palette = np.array(INSTANCE_COLOURS)
        ax.scatter(xy[dynamic, 0], xy[dynamic, 1], s=2.0, c=palette[instances % len(palette)], lw=0, zorder=2)


def _draw_perceived(ax: Any, perceived: Obstacles) -> None:
    from matplotlib.collections import PolyCollection

    ax.add_collection(PolyCollection(perceived.corners(), facecolors=PERCEIVED_COLOUR, edgecolors=PERCEIVED_COLOUR,
                                     alpha=0.45, linewidths=1.0, zorder=5))
    moving = np.linalg.norm(perceived.velocities[:, :2], axis=1) > 0.2
    if moving.any():
        ax.quiver(perceived.centres[moving, 0], perceived.centres[moving, 1], perceived.velocities[moving, 0],
                  perceived.velocities[moving, 1], angles="xy", scale_units="xy", scale=1.0, color=ARROW_COLOUR,
                  width=0.004, zorder=6)


def frame_title(frame: ViewFrame, start_ns: int) -> str:
    """What the frame shows, in one line."""
    perceived = 0 if frame.perceived is None else len(frame.perceived)
    segmented = "segmented scan" if frame.labels is not None else "raw scan (no segmentation yet)"
    return f"t = {(frame.stamp_ns - start_ns) / NS:5.1f} s   {segmented}   {perceived} obstacles perceived"


class FrameDrawer:
    """Draws frames into RGB pixel arrays of one square size."""

    def __init__(self, config: RenderConfig, start_ns: int = 0, title: str = "") -> None:
        plt = _pyplot()
        self.config = config
        self.start_ns = start_ns
        self.title = title
        dpi = 100
        side = (config.size_px // 16) * 16 / dpi  # a multiple of 16 pixels: what video codecs want
        self._fig = plt.figure(figsize=(side, side), dpi=dpi)
        self._plt = plt

    def draw(self, frame: ViewFrame) -> np.ndarray:
        """(H, W, 3) uint8 pixels of one frame."""
        fig = self._fig
        fig.clear()
        ax = fig.add_axes((0.07, 0.05, 0.9, 0.88))
        draw_frame(ax, frame, self.config)
        ax.set_title(f"{self.title}\n{frame_title(frame, self.start_ns)}".strip(), fontsize=8)
        fig.canvas.draw()
        return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Free the figure."""
        self._plt.close(self._fig)


def draw_episode_picture(path: Any, last: ViewFrame, overview: np.ndarray, track: EpisodeTrack, config: RenderConfig,
                         title: str = "") -> None:
    """The episode picture: the route overview (the static map seen, the whole path), the last moments with every
    layer, and the fusion loop's Δ per iteration."""
    plt = _pyplot()
    has_fusion = len(track.fusion.stamps) > 0
    fig = plt.figure(figsize=(17 if has_fusion else 12.5, 6.2), dpi=110)
    columns = (1.0, 1.0, 0.75) if has_fusion else (1.0, 1.0)
    grid = fig.add_gridspec(1, len(columns), width_ratios=columns, wspace=0.18)
    _draw_overview(fig.add_subplot(grid[0, 0]), last, overview, track)
    moment = fig.add_subplot(grid[0, 1])
    draw_frame(moment, last, config)
    start = int(track.truth.stamps[0]) if len(track.truth) else last.stamp_ns
    moment.set_title(f"last moments: {frame_title(last, start)}", fontsize=9)
    if has_fusion:
        _draw_fusion(fig.add_subplot(grid[0, 2]), track.fusion)
    fig.suptitle(title, fontsize=11)
    try:
        fig.savefig(path, bbox_inches="tight")
    except OSError as err:
        from ssf_common.errors import DataError

        raise DataError(f"{path}: cannot write the picture ({err.strerror})") from None
    finally:
        plt.close(fig)


def _draw_overview(ax: Any, last: ViewFrame, overview: np.ndarray, track: EpisodeTrack) -> None:
    ax.set_facecolor(BACKGROUND)
    if len(overview):
        ax.scatter(overview[:, 0], overview[:, 1], s=0.3, c=STATIC_COLOUR, lw=0, zorder=1)
    path = track.truth.matrices[:, :2, 3]
    ax.plot(path[:, 0], path[:, 1], color=EGO_COLOUR, lw=2, zorder=3, label="ego path (true)")
    if last.odometry_path is not None:
        ax.plot(last.odometry_path[:, 0], last.odometry_path[:, 1], "--", color=ODOMETRY_COLOUR, lw=1.3, zorder=3,
                label="odometry")
    ax.plot(*path[0], "o", color="white", mec="black", zorder=4, label="start")
    ax.plot(*path[-1], "*", color="gold", mec="black", ms=13, zorder=4, label="end")
    lo, hi = path.min(axis=0) - OVERVIEW_MARGIN_M, path.max(axis=0) + OVERVIEW_MARGIN_M
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    distance = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0
    outcome = f", outcome {track.outcome}" if track.outcome else ""
    ax.set_title(f"route overview: {distance:.0f} m driven{outcome}", fontsize=9)
    ax.legend(loc="upper left", fontsize=7, framealpha=0.75)


def _draw_fusion(ax: Any, fusion: FusionLog) -> None:
    scans = len(np.unique(fusion.stamps))
    ax.set_xlabel("fusion iteration")
    ax.set_ylabel("Δ_total (/ssf/fusion_state)")
    ax.set_title(f"fusion loop: Δ per iteration ({scans} scans; green: converged)", fontsize=9)
    finite = np.isfinite(fusion.delta_total) & (fusion.delta_total > 0)
    if not finite.any():
        ax.text(0.5, 0.5, f"no finite Δ > 0 among {len(fusion.delta_total)} states\n"
                f"({int(np.isinf(fusion.delta_total).sum())} inf, {int(np.isnan(fusion.delta_total).sum())} NaN)",
                ha="center", va="center", transform=ax.transAxes, fontsize=9)
        return
    iterations, deltas = fusion.iterations[finite], fusion.delta_total[finite]
    shown = np.unique(iterations)
    ax.boxplot([deltas[iterations == i] for i in shown], positions=shown, widths=0.5, showfliers=False)
    jitter = np.random.default_rng(0).uniform(-0.15, 0.15, len(iterations))
    ax.scatter(iterations + jitter, deltas, s=6, alpha=0.5,
               c=np.where(fusion.converged[finite], PLAN_COLOUR, PERCEIVED_COLOUR), zorder=3)
    ax.set_yscale("log")
    hidden = int((~finite).sum())
    if hidden:
        ax.text(0.98, 0.98, f"{hidden} states with Δ = inf/NaN/0 not drawn", ha="right", va="top",
                transform=ax.transAxes, fontsize=7)
