"""Bird's-eye drawings with matplotlib: one frame (`draw_frame`), the animation's pixels (`FrameDrawer`), and the
episode picture (route overview, the last moment, the fusion loop's Δ per iteration, the perception scan by scan
against the truth)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ssf_common.records import MotionLabel, ObstacleKind, Obstacles
from ssf_common.render.counts import FrameCounts, moving, summary_line
from ssf_common.render.frames import NS, EpisodeTrack, FusionLog, RenderConfig, ViewFrame
from ssf_common.render.figures import save_figure

STATIC_COLOUR = "#9aa0a6"
RAW_COLOUR = "#7f9fbf"
TRUE_COLOURS = {ObstacleKind.VEHICLE: "#3d8bff", ObstacleKind.PEDESTRIAN: "#c58cff", ObstacleKind.UNKNOWN: "#b0b0b0"}
STANDING_COLOUR = "#5d6b7e"  # true agents standing still: queued, parked, waiting
PERCEIVED_COLOUR = "#e8413c"  # moving obstacles the perception saw
STILL_COLOUR = "#d8d8d8"  # still obstacles the perception saw: parked cars, poles, walls
ARROW_COLOUR = "#ffd21f"
MISSED_COLOUR = "#ff9f1c"
PLAN_COLOUR = "#21c45d"
EGO_COLOUR = "#e0218a"
ODOMETRY_COLOUR = "#19b5c8"
INSTANCE_COLOURS = ("#3cb44b", "#42d4f4", "#bfef45", "#aaffc3", "#dcbeff", "#46f0f0", "#00b3a4", "#9a6324",
                    "#808000", "#e6e6e6")  # bright on the dark ground; no red, yellow, orange or magenta: those mark
# the perception, its arrows, its misses and the ego
PERCEIVED_FILL = (0.91, 0.25, 0.24, 0.35)
BACKGROUND = "#1e1f24"
OVERVIEW_MARGIN_M = 40.0
OUTCOME_WORDS = {"success": "goal reached", "collision": "collision",
                 "timeout": "the scenario's time limit reached before the goal"}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_frame(ax: Any, frame: ViewFrame, config: RenderConfig, *, legend: bool = True,
               legend_below: bool = False) -> None:
    """Draw one frame on a matplotlib axes, centred on the ego, `view_radius_m` around it (the legend inside, or
    below the axes)."""
    from matplotlib.patches import Polygon

    ax.set_facecolor(BACKGROUND)
    centre = frame.ego_pose[:2, 3]
    radius = config.view_radius_m
    _draw_points(ax, frame)
    if frame.agents is not None and len(frame.agents):
        _draw_agents(ax, frame.agents, config)
    if frame.perceived is not None and len(frame.perceived):
        _draw_perceived(ax, frame.perceived, config)
    if frame.judged is not None and frame.agents is not None:
        _draw_judgement(ax, frame.judged, frame.agents)
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
    add_scale_bar(ax, 2 * radius)
    if legend and legend_below:
        ax.legend(handles=_legend_handles(frame, config), loc="upper center", bbox_to_anchor=(0.5, -0.06), ncol=3,
                  fontsize=7, framealpha=0.9)
    elif legend:
        handles = _legend_handles(frame, config)
        ax.legend(handles=handles, loc="upper left", fontsize=5.5, ncol=2 if len(handles) > 6 else 1, framealpha=0.6,
                  handlelength=1.5, columnspacing=0.8)


def add_scale_bar(ax: Any, width_m: float, colour: str = "white") -> None:
    """A bar of a round length (about a fifth of the width shown) in the lower right corner."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    target = width_m / 5
    magnitude = 10 ** np.floor(np.log10(target))
    length = max((step * magnitude for step in (1, 2, 5, 10) if step * magnitude <= target), default=magnitude)
    bar = AnchoredSizeBar(ax.transData, length, f"{length:g} m", "lower right", pad=0.4, color=colour, frameon=False,
                          size_vertical=width_m / 250, fontproperties={"size": 7})
    ax.add_artist(bar)


def _legend_handles(frame: ViewFrame, config: RenderConfig) -> list[Any]:
    """Legend entries for the layers this frame shows."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    present = lambda item: item is not None and len(item) > 0  # noqa: E731
    agents_moving = moving(frame.agents, config.moving_speed) if present(frame.agents) else np.zeros(0, bool)
    perceived_moving = moving(frame.perceived, config.moving_speed) if present(frame.perceived) else np.zeros(0, bool)
    dynamic = frame.labels is not None and bool((frame.labels == MotionLabel.DYNAMIC).any())
    judged = frame.judged
    layers = [
        (frame.labels is None, Line2D([], [], ls="", marker=".", color=RAW_COLOUR, label="LiDAR scan")),
        (frame.labels is not None, Line2D([], [], ls="", marker=".", color=STATIC_COLOUR, label="static points")),
        (dynamic, Line2D([], [], ls="", marker="o", ms=4, color=INSTANCE_COLOURS[0],
                         label="dynamic points (colour per object)")),
        (agents_moving.any(), Patch(facecolor="none", edgecolor=TRUE_COLOURS[ObstacleKind.VEHICLE], lw=1.5,
                                    label="true moving agents (vehicle / pedestrian)")),
        ((~agents_moving).any(), Patch(facecolor="none", edgecolor=STANDING_COLOUR, label="true agents standing")),
        (perceived_moving.any(), Patch(facecolor=PERCEIVED_FILL, edgecolor=PERCEIVED_COLOUR, lw=1.5,
                                       label="perceived moving obstacles")),
        (perceived_moving.any(), Line2D([], [], color=ARROW_COLOUR, label="their velocity (where in 1 s)")),
        ((~perceived_moving).any(), Patch(facecolor="none", edgecolor=STILL_COLOUR, lw=0.7,
                                          label="perceived still obstacles (parked, structure)")),
        (judged is not None and bool(judged.missed_ids), Line2D([], [], ls="", marker="o", mfc="none", ms=8,
                                                                 mec=MISSED_COLOUR, label="missed (seen, not perceived)")),
        (judged is not None and len(judged.phantom_centres) > 0,
         Line2D([], [], ls="", marker="X", ms=7, color=PERCEIVED_COLOUR, mec="white", label="phantom (moves, nothing there)")),
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
    if dynamic.any():  # above the boxes, large enough to see at a glance
        instances = frame.instances[dynamic] if frame.instances is not None else np.zeros(int(dynamic.sum()), int)
        palette = np.array(INSTANCE_COLOURS)
        ax.scatter(xy[dynamic, 0], xy[dynamic, 1], s=4.0, c=palette[instances % len(palette)], lw=0, zorder=8)


def _draw_agents(ax: Any, agents: Obstacles, config: RenderConfig) -> None:
    """The true agents: moving ones outlined in their kind's colour, standing ones faintly."""
    from matplotlib.collections import PolyCollection

    going = moving(agents, config.moving_speed)
    corners = agents.corners()
    colours = [TRUE_COLOURS.get(ObstacleKind(int(k)), TRUE_COLOURS[ObstacleKind.UNKNOWN]) for k in agents.kinds[going]]
    ax.add_collection(PolyCollection(corners[~going], facecolors="none", edgecolors=STANDING_COLOUR, linewidths=0.7,
                                     zorder=3))
    ax.add_collection(PolyCollection(corners[going], facecolors="none", edgecolors=colours, linewidths=1.5, zorder=6))


def _draw_perceived(ax: Any, perceived: Obstacles, config: RenderConfig) -> None:
    """The perceived obstacles: moving ones as red boxes with their velocity, still ones as thin light outlines."""
    from matplotlib.collections import PolyCollection

    going = moving(perceived, config.moving_speed)
    corners = perceived.corners()
    ax.add_collection(PolyCollection(corners[~going], facecolors="none", edgecolors=STILL_COLOUR, alpha=0.8,
                                     linewidths=0.7, zorder=4))
    ax.add_collection(PolyCollection(corners[going], facecolors=PERCEIVED_FILL, edgecolors=PERCEIVED_COLOUR,
                                     linewidths=1.5, zorder=5))
    if going.any():
        ax.quiver(perceived.centres[going, 0], perceived.centres[going, 1], perceived.velocities[going, 0],
                  perceived.velocities[going, 1], angles="xy", scale_units="xy", scale=1.0, color=ARROW_COLOUR,
                  width=0.004, zorder=9)


def _draw_judgement(ax: Any, judged: Any, agents: Obstacles) -> None:
    """Rings around the true agents the perception missed, crosses on its phantoms."""
    missed = np.isin(agents.ids, list(judged.missed_ids))
    if missed.any():
        reach = 0.5 * np.hypot(agents.sizes[missed, 0], agents.sizes[missed, 1]) + 1.5
        for (x, y), radius in zip(agents.centres[missed, :2], reach):
            ax.add_patch(_circle(x, y, radius))
    if len(judged.phantom_centres):
        ax.scatter(judged.phantom_centres[:, 0], judged.phantom_centres[:, 1], marker="X", s=60, c=PERCEIVED_COLOUR,
                   edgecolors="white", linewidths=0.8, zorder=10)


def _circle(x: float, y: float, radius: float) -> Any:
    from matplotlib.patches import Circle

    return Circle((x, y), radius, fill=False, edgecolor=MISSED_COLOUR, lw=1.6, ls="--", zorder=10)


def frame_title(frame: ViewFrame, start_ns: int) -> str:
    """What the frame shows, in one line: the time, the scan, and how the perception did on it."""
    segmented = "segmented scan" if frame.labels is not None else "raw scan (no recent segmentation)"
    line = f"t = {(frame.stamp_ns - start_ns) / NS:5.1f} s   {segmented}"
    if frame.judged is not None:
        c = frame.judged.counts
        return (f"{line}\ntrue moving agents seen {c.true}: perceived {c.matched}, missed {c.missed}; "
                f"phantoms {c.phantoms}; still obstacles {c.still}")
    if frame.perceived is not None:
        return f"{line}   {len(frame.perceived)} obstacles perceived"
    return line


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
        ax = fig.add_axes((0.07, 0.05, 0.9, 0.84))
        draw_frame(ax, frame, self.config)
        ax.set_title(f"{self.title}\n{frame_title(frame, self.start_ns)}".strip(), fontsize=8)
        fig.canvas.draw()
        return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Free the figure."""
        self._plt.close(self._fig)


def draw_episode_picture(path: Any, last: ViewFrame, overview: np.ndarray, track: EpisodeTrack, config: RenderConfig,
                         title: str = "", counts: list[FrameCounts] | None = None) -> None:
    """The episode picture: the route overview (the static map seen, the whole path, how it ended), the last moment
    with every layer, the fusion loop's Δ per iteration, and below, scan by scan, the true moving agents the LiDAR
    saw against what the perception made of them."""
    plt = _pyplot()
    counts = counts or []
    fig = plt.figure(figsize=(17, 10.5), dpi=100)
    grid = fig.add_gridspec(2, 3, width_ratios=(1.0, 1.0, 0.7), height_ratios=(1.0, 0.45), wspace=0.2, hspace=0.45)
    _draw_overview(fig.add_subplot(grid[0, 0]), last, overview, track)
    moment = fig.add_subplot(grid[0, 1])
    draw_frame(moment, last, config, legend_below=True)
    start = int(track.truth.stamps[0]) if len(track.truth) else last.stamp_ns
    moment.set_title(f"last moment: {frame_title(last, start)}", fontsize=9)
    _draw_fusion(fig.add_subplot(grid[0, 2]), track.fusion)
    _draw_counts(fig.add_subplot(grid[1, :]), counts, start, config)
    fig.suptitle(title or episode_name(track), fontsize=12)
    save_figure(fig, path, bbox_inches="tight")


def episode_name(track: EpisodeTrack) -> str:
    """`urban_100, seed 2, 100 agents` from the episode result (empty without one)."""
    return f"{track.scenario}, seed {track.seed}, {track.agent_count} agents" if track.scenario else ""


def outcome_words(track: EpisodeTrack) -> str:
    """How the drive ended, in words: `duration reached at 20.0 s`, `collision after 12.3 s`."""
    if not track.outcome:
        return "no episode result recorded"
    if track.outcome in OUTCOME_WORDS:
        return f"{OUTCOME_WORDS[track.outcome]} after {track.outcome_time_s:.1f} s"
    end_s = (int(track.truth.stamps[-1]) - int(track.truth.stamps[0])) / NS if len(track.truth) else 0.0
    if track.outcome_time_s >= end_s - 0.05:  # the simulator's last word: it ran its set time
        return f"duration reached at {track.outcome_time_s:.1f} s, still driving"
    return f"stopped from outside at {end_s:.1f} s, still driving"


def _draw_overview(ax: Any, last: ViewFrame, overview: np.ndarray, track: EpisodeTrack) -> None:
    ax.set_facecolor(BACKGROUND)
    if len(overview):
        ax.scatter(overview[:, 0], overview[:, 1], s=0.3, c=STATIC_COLOUR, lw=0, zorder=1)
    path = track.truth.matrices[:, :2, 3]
    ax.plot(path[:, 0], path[:, 1], color=EGO_COLOUR, lw=2, zorder=3, label="ego path (true)")
    odometry = ""
    if last.odometry_path is not None and len(last.odometry_path):
        ax.plot(last.odometry_path[:, 0], last.odometry_path[:, 1], "--", color=ODOMETRY_COLOUR, lw=1.3, zorder=3,
                label="odometry")
        odometry = f"; odometry ends {np.linalg.norm(last.odometry_path[-1] - last.path[-1]):.2f} m off"
    ax.plot(*path[0], "o", color="white", mec="black", ms=8, zorder=4, label="start")
    ax.plot(*path[-1], "*", color="gold", mec="black", ms=14, zorder=4, label="end")
    lo, hi = path.min(axis=0) - OVERVIEW_MARGIN_M, path.max(axis=0) + OVERVIEW_MARGIN_M
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    add_scale_bar(ax, float(hi[0] - lo[0]))
    distance = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0
    ax.set_title(f"route: {distance:.0f} m driven, {outcome_words(track)}{odometry}", fontsize=9)
    ax.legend(loc="upper left", fontsize=7, framealpha=0.8)


def _draw_fusion(ax: Any, fusion: FusionLog) -> None:
    scans = np.unique(fusion.stamps)
    ax.set_xlabel("fusion iteration")
    ax.set_ylabel("Δ_total (/ssf/fusion_state)")
    if not len(scans):
        ax.set_title("fusion loop", fontsize=9)
        ax.text(0.5, 0.5, "no /ssf/fusion_state recorded", ha="center", va="center", transform=ax.transAxes)
        ax.axis("off")
        return
    if not fusion.iterations.any() and fusion.delta_mask is not None:  # one iteration per scan: no Δ between two
        _draw_prior_change(ax, fusion)
        return
    converged = len(np.unique(fusion.stamps[fusion.converged]))
    ax.set_title(f"fusion loop: Δ per iteration, {converged} of {len(scans)} scans converged (green)", fontsize=9)
    finite = np.isfinite(fusion.delta_total)
    if not finite.any():
        ax.text(0.5, 0.5, f"no Δ to draw: every state of {len(scans)} scans has none (first iterations only)",
                ha="center", va="center", transform=ax.transAxes, fontsize=9, wrap=True)
        return
    iterations, deltas = fusion.iterations[finite], fusion.delta_total[finite]
    positive = deltas > 0
    floor = deltas[positive].min() / 10 if positive.any() else 1e-9
    shown = np.maximum(deltas, floor)  # Δ = 0 (nothing changed) sits on the floor
    ax.boxplot([shown[iterations == i] for i in np.unique(iterations)], positions=np.unique(iterations), widths=0.5,
               showfliers=False)
    jitter = np.random.default_rng(0).uniform(-0.15, 0.15, len(iterations))
    ax.scatter(iterations + jitter, shown, s=6, alpha=0.5,
               c=np.where(fusion.converged[finite], PLAN_COLOUR, PERCEIVED_COLOUR), zorder=3)
    ax.set_yscale("log")
    notes = []
    if (~finite).any():
        notes.append("iteration 0 of each scan has no Δ (no earlier flow to compare)")
    if (~positive).any():
        notes.append(f"{int((~positive).sum())} with Δ = 0 drawn at the bottom")
    if notes:
        ax.text(0.02, 0.02, "\n".join(notes), ha="left", va="bottom", transform=ax.transAxes, fontsize=7,
                bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "none"})


def _draw_prior_change(ax: Any, fusion: FusionLog) -> None:
    """One iteration per scan: how far each scan's segmentation moved from the mask it started from (the previous scan's,
    carried by its flow), over time."""
    seconds = (fusion.stamps - fusion.stamps.min()) / NS
    change = np.nan_to_num(fusion.delta_mask, nan=0.0)
    ax.plot(seconds, change, ".", ms=3, color=PERCEIVED_COLOUR)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("mean |M(1) − M(0)| per point")
    ax.set_title(f"fusion: one iteration per scan ({len(np.unique(fusion.stamps))} scans)\nthe segmentation against "
                 "the prior it started from", fontsize=9)
    ax.text(0.02, 0.98, f"median {np.median(change):.2e}", ha="left", va="top", transform=ax.transAxes, fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "none"})


def _draw_counts(ax: Any, counts: list[FrameCounts], start_ns: int, config: RenderConfig) -> None:
    """Scan by scan: the true moving agents the LiDAR saw, stacked as perceived (green) and missed (orange), and the
    phantoms below the line (red)."""
    ax.set_xlabel("simulated time (s)")
    if not counts:
        ax.set_title("perception against the truth", fontsize=9)
        ax.text(0.5, 0.5, "no scan with both perceived obstacles (/ssf/obstacles) and true agents "
                "(/sim/ground_truth/obstacles) recorded", ha="center", va="center", transform=ax.transAxes)
        ax.axis("off")
        return
    t = (np.array([c.stamp_ns for c in counts]) - start_ns) / NS
    width = 0.9 * float(np.median(np.diff(t))) if len(t) > 1 else 0.09
    matched = np.array([c.matched for c in counts])
    missed = np.array([c.missed for c in counts])
    phantoms = np.array([c.phantoms for c in counts])
    ax.bar(t, matched, width, color=PLAN_COLOUR, label="true moving agents seen and perceived")
    ax.bar(t, missed, width, bottom=matched, color=MISSED_COLOUR, label="seen, missed")
    ax.bar(t, -phantoms, width, color=PERCEIVED_COLOUR, label="phantoms: perceived moving, no moving agent there")
    ax.axhline(0.0, color="black", lw=0.8)
    top, bottom = max(int((matched + missed).max()), 1), max(int(phantoms.max()), 1)
    ax.set_ylim(-bottom - 0.5, top + 1.5)
    ax.set_yticks(np.arange(-bottom, top + 1, max(1, (top + bottom) // 8)))
    ax.set_yticklabels([str(abs(int(v))) for v in ax.get_yticks()])
    ax.set_ylabel("phantoms  |  true moving agents", fontsize=8)
    ax.set_xlim(t.min() - width, t.max() + width)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(loc="upper left", fontsize=7.5, ncol=3, framealpha=0.85)
    ax.set_title(f"perception scan by scan, within {config.count_radius_m:g} m of the ego, moving = at least "
                 f"{config.moving_speed:g} m/s: {summary_line(counts)}", fontsize=9)
