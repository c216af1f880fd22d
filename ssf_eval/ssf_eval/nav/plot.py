"""The paper's navigation table as a figure: success rate (Wilson 95 % intervals), time and average speed against
the number of agents, one line per perception source."""

from __future__ import annotations

from pathlib import Path

from ssf_common.render.figures import save_figure
from ssf_eval.nav.stats import CellSummary

COLOURS = {"gt": "tab:green", "ssf": "tab:orange", "ssf + ssf pose": "tab:red", "dbscan": "tab:blue", "dbscan0": "tab:cyan",
           "follower": "tab:grey"}


def plot_cells(cells: list[CellSummary], path: Path, title: str) -> str:
    """Draw three panels to path (PNG); returns a line saying where."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    for source in dict.fromkeys(cell.source for cell in cells):
        rows = sorted((cell for cell in cells if cell.source == source), key=lambda cell: cell.agents)
        agents = [cell.agents for cell in rows]
        colour = COLOURS.get(source)
        rate = [cell.success_rate for cell in rows]
        errors = [[cell.success_rate - cell.success_ci95[0] for cell in rows],
                  [cell.success_ci95[1] - cell.success_rate for cell in rows]]
        axes[0].errorbar(agents, rate, yerr=errors, marker="o", capsize=3, label=source, color=colour)
        for axis, values, style in ((axes[1], [cell.navigation_time_s for cell in rows], "-"),
                                    (axes[2], [cell.average_speed_mps for cell in rows], "-"),
                                    (axes[2], [cell.moving_speed_mps for cell in rows], "--")):
            shown = [(a, v) for a, v in zip(agents, values) if v is not None]
            if shown:
                axis.plot(*zip(*shown), style, marker="o", label=source if style == "-" else None, color=colour)
    for axis, label in zip(axes, ("success rate (95 % Wilson interval)", "navigation time of successes (s)",
                                  "speed of successes (m/s): average —, while moving --")):
        axis.set_xlabel("moving agents")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(loc="lower left")
    figure.suptitle(f"closed-loop navigation: {title}")
    figure.tight_layout()
    save_figure(figure, path, dpi=110)
    return f"figure -> {path}"
