"""Ends of flanks: a cluster sliding along itself, whose sides say nothing, moved by the shift of its two ends."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.labels import label_counts, label_main_axes, label_spans
from ssf_common.geometry.neighbours import PointIndex, may_be_near
from ssf_flow_node.core.preprocess import PreprocessConfig, object_top
from ssf_flow_node.core.rigid.clusters import Clusters, component_count
from ssf_flow_node.core.rigid.config import RigidConfig

FLAT_HEIGHT = 0.3  # m: a cluster flatter than this counts as this tall when its sampling spacing is estimated


class Bands(NamedTuple):
    """The whole scans' points between the ground and object_height (scan t ego-compensated), where the sample is too
    coarse to say where a flank ends."""

    points1: np.ndarray
    points2: np.ndarray


def end_shifts(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, candidates: np.ndarray,
               config: RigidConfig, bands: Bands | None = None) -> np.ndarray:
    """Per candidate cluster alone in its component, the shift along its main horizontal axis by which both of its ends
    moved from scan t to scan t+1, where the two agree within end_agreement and the shift is end_spacings times its
    sampling spacing or more (zero elsewhere): a flank's ends, where its sides say nothing. With the whole scans'
    `bands`, the ends and the spacing are those of all the points within a sampling spacing of the cluster's."""
    count = clusters.count
    shift = np.zeros((count, 3))
    alone = candidates & (np.bincount(clusters.parent, minlength=component_count(clusters)) == 1)[clusters.parent]
    on1 = (clusters.labels1 >= 0) & alone[np.maximum(clusters.labels1, 0)]
    if not on1.any():
        return shift
    cluster_of = np.full(component_count(clusters), -1)  # each component's only cluster
    cluster_of[clusters.parent[alone]] = np.flatnonzero(alone)
    on2 = (clusters.labels2 >= 0) & (cluster_of[np.maximum(clusters.labels2, 0)] >= 0)
    labels1, labels2 = clusters.labels1[on1], cluster_of[clusters.labels2[on2]]
    axis = label_main_axes(points1[on1, :2], labels1, count)
    along1, along2 = (np.einsum("ij,ij->i", points[:, :2], axis[labels]) for points, labels in
                      ((points1[on1], labels1), (points2[on2], labels2)))
    low1, high1 = label_spans(along1, labels1, count)
    low2, high2 = label_spans(along2, labels2, count)
    bottom, top = label_spans(points1[on1, 2], labels1, count)
    with np.errstate(invalid="ignore"):  # empty labels: inf - inf
        # a flank of length L and height H sampled with n points has them about sqrt(L H / n) apart
        spacing = np.sqrt((high1 - low1) * np.maximum(top - bottom, FLAT_HEIGHT) / np.maximum(label_counts(labels1, count), 1))
        if bands is not None:  # the sample's outermost points lie up to a spacing from the ends
            reach = np.where(np.isfinite(spacing), np.minimum(spacing, config.cluster_voxel), 0.0)
            low1, high1, denser = band_ends(bands.points1, points1[on1], labels1, along1, low1, high1, axis, reach)
            low2, high2, _ = band_ends(bands.points2, points2[on2], labels2, along2, low2, high2, axis, reach)
            spacing = spacing / np.sqrt(np.maximum(denser, 1.0))
        lows, highs = low2 - low1, high2 - high1
        middle = 0.5 * (lows + highs)
        agree = (alone & np.isfinite(middle) & (np.abs(lows - highs) <= config.end_agreement * np.abs(middle))
                 & (np.abs(middle) >= config.end_spacings * spacing))
    if agree.any():  # a window through a gap between nearer things slides along a wall as the sensor moves: not ends
        agree[agree] = ~hidden_ends(points2, on2, labels2, axis, np.flatnonzero(agree), spacing, config.end_occlusion)
    shift[agree, :2] = middle[agree, None] * axis[agree]
    return shift


def band_ends(band: np.ndarray, sampled: np.ndarray, labels: np.ndarray, along: np.ndarray, low: np.ndarray,
              high: np.ndarray, axis: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per label, where along its axis the band's points within `reach` of its sampled points near either end (two
    reaches from it or less) end, and how many band points lie there per such sampled point (the ends found in the
    sample, inf and -inf, and zero where none lie there)."""
    count = len(low)
    outer = (along <= low[labels] + 2.0 * reach[labels]) | (along >= high[labels] - 2.0 * reach[labels])
    sampled, labels = sampled[outer], labels[outer]
    cap = max(float(reach.max(initial=0.0)), 1e-9)
    near = np.flatnonzero(may_be_near(sampled, band, cap))
    gap, index = PointIndex(sampled).query(band[near], distance_upper_bound=cap)
    found = np.isfinite(gap)
    label = labels[index[found]]
    inside = gap[found] <= reach[label]
    points, label = band[near[found][inside]], label[inside]
    ends_low, ends_high = label_spans(np.einsum("ij,ij->i", points[:, :2], axis[label]), label, count)
    seen = label_counts(label, count) > 0
    density = label_counts(label, count) / np.maximum(label_counts(labels, count), 1)
    return np.where(seen, ends_low, low), np.where(seen, ends_high, high), density


def band_points(points: np.ndarray, height: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """A whole scan's points above the ground and below object_height (all above the ground where that is 0)."""
    return points[(height >= config.ground_height) & (height < object_top(config))]


def hidden_ends(points2: np.ndarray, on2: np.ndarray, labels2: np.ndarray, axis: np.ndarray, clusters: np.ndarray,
                spacing: np.ndarray, margin: float) -> np.ndarray:
    """Per given cluster, whether either end of its points in scan t+1 (`points2[on2]`, labelled `labels2`) along its
    axis has points of scan t+1 nearer the sensor by `margin` within three sampling spacings of it in azimuth."""
    azimuth2 = np.arctan2(points2[:, 1], points2[:, 0])
    range2 = np.hypot(points2[:, 0], points2[:, 1])
    own = np.flatnonzero(on2)
    hidden = np.zeros(len(clusters), dtype=bool)
    for row, cluster in enumerate(clusters):
        members = own[labels2 == cluster]
        along = points2[members, :2] @ axis[cluster]
        for end in members[[np.argmin(along), np.argmax(along)]]:
            window = 3.0 * spacing[cluster] / max(range2[end], 1e-6)
            nearer = np.flatnonzero(range2 < range2[end] - margin)  # few: the angle is wrapped for these alone
            beside = np.abs(np.angle(np.exp(1j * (azimuth2[nearer] - azimuth2[end])))) <= window
            beside[np.isin(nearer, members)] = False
            hidden[row] |= bool(np.any(beside))
    return hidden
