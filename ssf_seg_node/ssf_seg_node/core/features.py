"""What the learned and the clustering segmenters look at: the points, their motion relative to the static scene,
or both.

In the sensor frame every static point moves with the inverse ego motion, so the raw flow of the static scene
varies with the position (the ego's rotation) and is large wherever the ego drives fast. Subtracting the ego
motion's flow (given by the flow estimator, or fitted robustly to the flow) leaves what the objects themselves do;
`compensate_ego: false` keeps the raw flow."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.se3 import rigid_flow
from ssf_seg_node.core.base import SegInput
from ssf_seg_node.core.geometric import GeometricConfig, fit_ego_motion
from ssf_seg_node.core.selection import StaticRule, StaticSelectionConfig


class MotionInput(NamedTuple):
    """The flow a segmenter sees, and the ego motion it was taken relative to (identity when raw)."""

    flow: np.ndarray  # (N, 3) float32
    ego: np.ndarray  # (4, 4)


def motion_input(points: np.ndarray, flow: np.ndarray, ego: np.ndarray | None, previous: np.ndarray | None,
                 compensate_ego: bool, ego_fit: GeometricConfig = GeometricConfig()) -> MotionInput:
    """The flow relative to the static scene (ego given, or fitted to the flow), or the raw flow."""
    points, flow = np.asarray(points, np.float64)[:, :3], np.asarray(flow, np.float64)
    if not compensate_ego:
        return MotionInput(flow.astype(np.float32), np.eye(4))
    ego = fit_ego_motion(points, flow, previous, ego_fit) if ego is None else np.asarray(ego, np.float64)
    return MotionInput((flow - rigid_flow(ego, points)).astype(np.float32), ego)


def feature_columns(points: np.ndarray, flow: np.ndarray, kind: SegInput) -> np.ndarray:
    """(N, 3) or (N, 6) float64 columns: the points, the flow, or both."""
    columns = {SegInput.POINTS: [points], SegInput.FLOW: [flow], SegInput.BOTH: [points, flow]}[SegInput(kind)]
    return np.column_stack([np.asarray(column, np.float64)[:, :3] for column in columns])


def standardised(features: np.ndarray) -> np.ndarray:
    """Each column to zero mean and unit standard deviation (constant columns to zero)."""
    spread = features.std(axis=0)
    return (features - features.mean(axis=0)) / np.where(spread > 1e-9, spread, 1.0)


def selection_for(selection: StaticSelectionConfig, rule: StaticRule | None, kind: SegInput) -> StaticSelectionConfig:
    """The static selection a method applies: its own rule when it names one; quantity-based whenever it sees only
    the points (it never looks at the flow, so it cannot compare speeds)."""
    if SegInput(kind) is SegInput.POINTS:
        rule = StaticRule.QUANTITY
    return selection if rule is None else selection.model_copy(update={"rule": rule})
