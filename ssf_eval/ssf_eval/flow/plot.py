"""Bird's-eye pictures of one pair: the true motion of the scene, and each estimator's per-point error."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ssf_common.dataset.pairs import ScanPair
from ssf_common.geometry.se3 import rigid_flow
from ssf_common.render.figures import save_figure
from ssf_flow_node.core.base import FlowResult

ERROR_SCALE_M = 0.3  # colour saturates here (the outlier threshold)


def plot_pair(pair: ScanPair, results: Mapping[str, FlowResult], path: str | Path, title: str = "") -> Path:
    """One panel with the ground-truth motion relative to the ego, then one per estimator coloured by EPE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy = pair.pc1[:, :2]
    relative = pair.flow - rigid_flow(pair.ego, pair.pc1)
    panels = 1 + len(results)
    figure, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 5.6), squeeze=False, constrained_layout=True)
    truth = axes[0, 0]
    truth.scatter(xy[:, 0], xy[:, 1], s=1.0, c="#9a9a9a", linewidths=0)
    moving = pair.dynamic1
    truth.quiver(xy[moving, 0], xy[moving, 1], relative[moving, 0], relative[moving, 1], color="#d62728",
                 angles="xy", scale_units="xy", scale=0.25, width=0.002)
    truth.set_title(f"truth: {int(moving.sum())} moving points (arrows x4)")
    for axis, (name, result) in zip(axes[0, 1:], results.items()):
        error = np.linalg.norm(result.flow - pair.flow, axis=1)
        order = np.argsort(error)  # large errors drawn last, on top
        image = axis.scatter(xy[order, 0], xy[order, 1], s=1.5, c=error[order], cmap="viridis", vmin=0.0,
                             vmax=ERROR_SCALE_M, linewidths=0)
        dynamic = f", dynamic {error[moving].mean():.3f}" if moving.any() else ""
        axis.set_title(f"{name}: EPE {error.mean():.3f} m{dynamic}")
    if results:
        figure.colorbar(image, ax=axes[0, 1:].tolist(), label="end-point error (m)", shrink=0.8)
    for axis in axes[0]:
        axis.set_aspect("equal")
        axis.set_xlabel("x (m)")
    axes[0, 0].set_ylabel("y (m)")
    if title:
        figure.suptitle(title)
    return save_figure(figure, path, dpi=110)
