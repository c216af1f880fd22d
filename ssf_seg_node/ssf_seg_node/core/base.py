"""The segmenter interface: points of scan t and their flow (and optionally the previous mask) in, soft masks over K
slots out, turned into per-point static/dynamic labels, dynamic probabilities and instance ids."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from ssf_common.records import Segmentation


class SegInput(str, Enum):
    """What a segmenter looks at (the paper's segmentation table has a column for each)."""

    POINTS = "points"
    FLOW = "flow"
    BOTH = "both"


@dataclass(frozen=True)
class SegmentationResult:
    """A segmentation of one scan: per-point labels, and the K soft slot masks and static slots it came from."""

    segmentation: Segmentation
    slots: np.ndarray  # (N, K) float32 soft masks, rows sum to 1
    static_slots: np.ndarray  # (K,) bool: the slots that make up the static scene

    def __len__(self) -> int:
        return len(self.segmentation)


class Segmenter(Protocol):
    """Anything that segments a scan into the static scene and moving objects from its points and flow."""

    name: str

    def segment(self, points: np.ndarray, flow: np.ndarray, previous: np.ndarray | None = None,
                ego: np.ndarray | None = None) -> SegmentationResult:
        """Segment scan t: points (N, 3), flow (N, 3) towards t+1 in the same frame, optionally the previous dynamic
        probability (N,) and the ego motion (4x4, scan-t coordinates of static points -> scan t+1)."""
        ...


def hard_slots(slots: np.ndarray) -> np.ndarray:
    """(N,) index of each point's most likely slot."""
    return np.asarray(slots).argmax(axis=1) if len(slots) else np.zeros(0, np.int64)


def result_from_slots(slots: np.ndarray, static_slots: np.ndarray, min_instance_points: int = 1) -> SegmentationResult:
    """Per-point labels from soft slots and the static choice: dynamic probability = mass on non-static slots;
    each dynamic slot with at least min_instance_points points becomes one instance (1..M, largest first)."""
    slots = np.asarray(slots, dtype=np.float32)
    static_slots = np.asarray(static_slots, dtype=bool)
    prob = slots[:, ~static_slots].sum(axis=1) if slots.size else np.zeros(len(slots), np.float32)
    segmentation = Segmentation.from_probability(prob)
    hard = hard_slots(slots)
    dynamic = segmentation.dynamic & ~static_slots[hard] if len(hard) else segmentation.dynamic
    sizes = np.bincount(hard[dynamic], minlength=slots.shape[1]) if slots.size else np.zeros(0, np.int64)
    kept = np.flatnonzero(sizes >= min_instance_points)
    order = kept[np.argsort(-sizes[kept], kind="stable")]
    instance_of_slot = np.zeros(slots.shape[1], np.int32)
    instance_of_slot[order] = np.arange(1, order.size + 1)
    instance = np.where(dynamic, instance_of_slot[hard] if len(hard) else 0, 0).astype(np.int32)
    return SegmentationResult(Segmentation(segmentation.dynamic_prob, segmentation.label, instance), slots, static_slots)


def one_hot(labels: np.ndarray, count: int) -> np.ndarray:
    """(N, count) float32 one-hot slots of hard labels; label -1 (noise) goes to an extra last slot."""
    labels = np.asarray(labels)
    width = count + int((labels < 0).any())
    slots = np.zeros((len(labels), max(width, 1)), np.float32)
    slots[np.arange(len(labels)), np.where(labels < 0, width - 1, labels)] = 1.0
    return slots
