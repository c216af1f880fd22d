"""Which slots are the static scene, as the paper chooses them: quantity-based (the largest slot) or, when the slot
sizes differ little, velocity-based (slots whose mean speed is within theta of the ego speed)."""

from __future__ import annotations

from enum import Enum
from typing import ClassVar

import numpy as np
from pydantic import Field

from ssf_common.config import Section
from ssf_common.geometry.labels import label_counts, label_means


class StaticRule(str, Enum):
    """How the static slots are chosen."""

    AUTO = "auto"  # quantity-based unless the slot sizes are similar, then velocity-based (the paper)
    QUANTITY = "quantity"
    VELOCITY = "velocity"


class StaticSelectionConfig(Section):
    """The paper's static-set selection."""

    rule: StaticRule = StaticRule.AUTO
    size_variation: float = Field(0.5, ge=0.0, description="slot sizes with a coefficient of variation (std / mean) "
                                  "below this count as similar, and the velocity rule decides")
    velocity_threshold: float = Field(1.0, gt=0.0, description="theta (m/s): a slot is static when its mean speed is "
                                      "within this of the ego speed")
    scan_period: float = Field(0.1, gt=0.0, description="time between the two scans (s)")
    renamed: ClassVar[dict[str, str]] = {"dt": "scan_period"}


def slot_speeds(flow: np.ndarray, hard: np.ndarray, count: int, dt: float) -> np.ndarray:
    """V_k = (1 / (N_k dt)) sum_i |S_i| over the points of each slot (m/s)."""
    return label_means(np.linalg.norm(flow, axis=1), hard, count) / dt


def select_static(sizes: np.ndarray, speeds: np.ndarray, ego_speed: float, config: StaticSelectionConfig) -> np.ndarray:
    """(K,) bool: the static slots among those with points (empty slots are never static)."""
    sizes = np.asarray(sizes, dtype=np.float64)
    occupied = sizes > 0
    static = np.zeros(sizes.shape, dtype=bool)
    if not occupied.any():
        return static
    rule = config.rule
    if rule is StaticRule.AUTO:
        present = sizes[occupied]
        variation = present.std() / present.mean() if present.size > 1 else np.inf
        rule = StaticRule.VELOCITY if variation < config.size_variation else StaticRule.QUANTITY
    if rule is StaticRule.QUANTITY:
        static[int(np.argmax(sizes))] = True
    else:
        static = occupied & (np.abs(np.asarray(speeds) - ego_speed) < config.velocity_threshold)
    return static


def ego_speed_of(ego: np.ndarray | None, flow: np.ndarray, points: np.ndarray, dt: float) -> float:
    """Mean speed (m/s) a static point of this scan shows: from the ego motion when known, else the median flow."""
    if ego is not None:
        moved = points @ ego[:3, :3].T + ego[:3, 3]
        return float(np.linalg.norm(moved - points, axis=1).mean() / dt)
    return float(np.median(np.linalg.norm(flow, axis=1)) / dt) if len(flow) else 0.0


def static_slots_of(slots: np.ndarray, flow: np.ndarray, points: np.ndarray, ego: np.ndarray | None,
                    config: StaticSelectionConfig) -> np.ndarray:
    """Apply the selection to soft slots: sizes and speeds from each point's most likely slot."""
    count = slots.shape[1]
    hard = slots.argmax(axis=1)
    return select_static(label_counts(hard, count), slot_speeds(flow, hard, count, config.scan_period),
                         ego_speed_of(ego, flow, points, config.scan_period), config)
