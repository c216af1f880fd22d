"""Pictures of the odometry evaluation: every method's trajectory against the truth, and the static maps with
the voxels that lie on agents' paths."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ssf_common.geometry.se3 import invert
from ssf_common.render.figures import save_figure

COLOURS = {"truth": "black", "points": "tab:orange", "flow": "tab:blue", "ssf": "tab:green", "kiss-icp": "tab:red",
           "ssf+twist": "tab:purple"}


def plot_trajectories(results: dict, path: Path) -> Path:
    """One panel per scenario: the true path and each method's (x, y in the first scan's frame)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(results), figsize=(5.0 * len(results), 4.6), squeeze=False)
    for axis, (title, result) in zip(axes[0], results.items()):
        truth = np.stack(result.truth)
        truth = invert(truth[0]) @ truth
        axis.plot(truth[:, 0, 3], truth[:, 1, 3], color=COLOURS["truth"], lw=2.5, label="ground truth")
        for name, run in result.runs.items():
            poses = np.stack(run.poses)
            score = result.scores[name]
            axis.plot(poses[:, 0, 3], poses[:, 1, 3], color=COLOURS.get(name), lw=1.2,
                      label=f"{name}: RPE {score.rpe_translation.rmse:.3f} m, end {score.endpoint_pct:.2f} %")
        axis.set_title(title)
        axis.set_aspect("equal", adjustable="datalim")
        axis.set_xlabel("x (m)")
        axis.set_ylabel("y (m)")
        axis.legend(fontsize=7)
    figure.suptitle("trajectories in the first scan's frame")
    path = save_figure(figure, path, dpi=110, bbox_inches="tight")
    return path


def plot_maps(result, title: str, path: Path, names: tuple[str, ...] = ("points", "ssf", "kiss-icp")) -> Path:
    """Bird's-eye view of each method's local map at the last sample, voxels on agents' paths in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [name for name in names if name in result.runs and result.runs[name].last_map is not None]
    figure, axes = plt.subplots(1, max(1, len(shown)), figsize=(5.5 * max(1, len(shown)), 5.2), squeeze=False)
    for axis, name in zip(axes[0], shown):
        run = result.runs[name]
        world, trails = run.last_map, run.last_trails
        keep = world[:, 2] > np.percentile(world[:, 2], 5) + 0.3  # above the ground, so structure and trails show
        axis.scatter(world[keep & ~trails, 0], world[keep & ~trails, 1], s=0.3, c="0.45")
        axis.scatter(world[trails, 0], world[trails, 1], s=2.0, c="red")
        axis.set_title(f"{name}: {100 * run.trail_share:.2f} % of map voxels on agents' paths")
        axis.set_aspect("equal", adjustable="datalim")
        axis.set_xlabel("x (m)")
    figure.suptitle(f"{title}: local maps (above ground) at the last sample; red = on agents' paths")
    path = save_figure(figure, path, dpi=110, bbox_inches="tight")
    return path
