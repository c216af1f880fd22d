"""Step 3, per-cluster motion: histogram-initialised batched ICP, kept only where it explains the data, clusters split
where parts changed, and every point moved with its cluster."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.fitting import planar_kabsch, planar_plane_step
from ssf_common.geometry.labels import label_counts, label_extents, label_means, ragged_arange
from ssf_common.geometry.reductions import vector_lengths
from ssf_common.geometry.se3 import yaw_translate
from ssf_common.geometry.neighbours import PointIndex
from ssf_flow_node.core.rigid.carry import Carried, carried_motions, continue_carried
from ssf_flow_node.core.rigid.clusters import (Clusters, Surfaces, component_count, joint_clusters, noise_floors,
                                               priorities, ranked_per_label)
from ssf_flow_node.core.rigid.config import RigidConfig
from ssf_flow_node.core.rigid.ends import Bands, end_shifts
from ssf_flow_node.core.rigid.fits import Fit, explains, fit_quality, no_worse, static_fit, surface_distance, unprovable


class ClusterMotions(NamedTuple):
    """Per cluster: rotation about z, translation (in scan t+1's frame, after ego compensation), moving flag; and, over
    the pairs of a stream, how many pairs its motion has been carried without the pair's own evidence (-1: still, 0:
    this pair proved it) and how many pairs proved it on their own evidence (0: still)."""

    yaw: np.ndarray
    translation: np.ndarray
    moving: np.ndarray
    carried: np.ndarray
    proven: np.ndarray


def initial_translations(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, active: np.ndarray,
                         config: RigidConfig, tree: PointIndex, previous: np.ndarray | None = None,
                         carried: np.ndarray | None = None) -> np.ndarray:
    """Per cluster, the best of: no motion, the centroid shift, the peaks of the displacement histogram, the mean
    motion its points had in the previous estimate on this pair, and the motion carried from the previous pair."""
    count = clusters.count
    picks1 = ranked_per_label(clusters.labels1, active, config.histogram_points, priorities(len(points1)))
    present = np.zeros(component_count(clusters), bool)
    present[clusters.parent[active]] = True
    picks2 = ranked_per_label(clusters.labels2, present, config.histogram_points, priorities(len(points2), 1))
    candidates = [np.zeros((count, 3)), centroid_shift(points1, points2, clusters)]
    if previous is not None:
        candidates.append(label_means(previous, clusters.labels1, count))
    if carried is not None:
        candidates.append(carried)
    if picks1.size and picks2.size:
        candidates += histogram_peaks(points1, points2, clusters, picks1, picks2, config)
    labels = clusters.labels1[picks1]
    shifts = np.stack(candidates)  # (candidates, clusters, 3)
    moved = (points1[picks1][None] + shifts[:, labels]).reshape(-1, 3)
    tries = np.repeat(np.arange(len(candidates)), labels.size) * count + np.tile(labels, len(candidates))
    scores = fit_quality(moved, tries, tree, clusters.labels2, np.tile(clusters.parent[labels], len(candidates)),
                         config, len(candidates) * count).residual
    best = scores.reshape(len(candidates), count).argmin(axis=0)
    return shifts[best, np.arange(count)]


def centroid_shift(points1: np.ndarray, points2: np.ndarray, clusters: Clusters) -> np.ndarray:
    """Per cluster, the horizontal shift between its centroid in scan t and its component's in scan t+1."""
    shift = np.zeros((clusters.count, 3))
    means2 = label_means(points2[:, :2], clusters.labels2, component_count(clusters))
    shift[:, :2] = means2[clusters.parent] - label_means(points1[:, :2], clusters.labels1, clusters.count)
    return shift


def histogram_peaks(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, picks1: np.ndarray,
                    picks2: np.ndarray, config: RigidConfig) -> list[np.ndarray]:
    """Per cluster, the `peaks` most frequent horizontal displacements between its points in the two scans."""
    count = clusters.count
    picks2 = picks2[np.argsort(clusters.labels2[picks2], kind="stable")]
    labels2 = clusters.labels2[picks2]
    wanted = clusters.parent[clusters.labels1[picks1]]
    starts = np.searchsorted(labels2, wanted, side="left")
    lengths = np.searchsorted(labels2, wanted, side="right") - starts
    first = np.repeat(picks1, lengths)
    second = picks2[np.repeat(starts, lengths) + ragged_arange(lengths)]
    displacement = points2[second, :2] - points1[first, :2]
    max_step = config.max_speed * config.scan_period
    near = vector_lengths(displacement) <= max_step
    first, displacement = first[near], displacement[near]
    half = int(np.ceil(max_step / config.histogram_bin)) + 1
    width = 2 * half + 1
    cells = np.round(displacement / config.histogram_bin).astype(np.int64) + half
    codes = clusters.labels1[first] * width * width + cells[:, 0] * width + cells[:, 1]
    votes = np.bincount(codes, minlength=count * width * width).reshape(count, width * width)
    rows = np.arange(count)
    peaks = []
    for _ in range(config.histogram_peaks):  # the most voted cell of each cluster (ties: the first), then the next
        cell = votes.argmax(axis=1)
        voted = votes[rows, cell] > 0
        votes[rows, cell] = -1
        shift = np.zeros((count, 3))
        shift[voted, 0] = (cell[voted] // width - half) * config.histogram_bin
        shift[voted, 1] = (cell[voted] % width - half) * config.histogram_bin
        peaks.append(shift)
    return peaks


def cluster_motions(points1: np.ndarray, points2: np.ndarray, clusters: Clusters, config: RigidConfig,
                    belief: np.ndarray | None, normals2: np.ndarray | None, floors: np.ndarray,
                    tree: PointIndex | None = None, candidates: np.ndarray | None = None,
                    previous: np.ndarray | None = None, sensed: np.ndarray | None = None,
                    carried: Carried | None = None, bands: Bands | None = None) -> ClusterMotions:
    """Histogram-initialised batched ICP per cluster; a motion is kept where it explains the points better than
    standing still (as the moved sensor samples a still surface: `sensed`, the points where scan t saw them), and
    standing still misses the surfaces by more than its component's noise floor (`floors`, m); or where both of its
    ends moved alike (a flank sliding along itself) or the previous pair of the stream saw the cluster moving
    (`carried`), and that motion explains them no worse than standing still."""
    count = clusters.count
    yaw, translation = np.zeros(count), np.zeros((count, 3))
    if count == 0 or points1.shape[0] == 0 or points2.shape[0] == 0:
        return ClusterMotions(yaw, translation, np.zeros(count, dtype=bool), np.full(count, -1), np.zeros(count, np.int64))
    sizes1 = label_counts(clusters.labels1, count)
    sizes2 = label_counts(clusters.labels2, component_count(clusters))[clusters.parent]
    sizes = np.minimum(sizes1, sizes2)
    active = (sizes >= config.min_cluster_points) & (label_extents(points1, clusters.labels1, count) <= config.max_extent)
    believed = np.zeros(count, dtype=bool)
    if belief is not None:
        believed = label_means(belief, clusters.labels1, count) > config.mask_threshold
        active |= believed & (sizes >= config.min_masked_points)
    if candidates is not None:
        active &= candidates
    tree = PointIndex(points2) if tree is None else tree
    carry = None if carried is None else carried_motions(clusters, carried, config)
    members = ranked_per_label(clusters.labels1, active, config.icp_points, priorities(len(points1), 2))
    source, labels = points1[members], clusters.labels1[members]
    allowed = clusters.parent[labels]
    floor = floors[clusters.parent]
    counted = np.maximum(label_counts(labels, count), 1)

    def quality(moved: np.ndarray) -> Fit:
        return fit_quality(moved, labels, tree, clusters.labels2, allowed, config, count, normals2, points2)

    # clusters that standing still explains within their noise floor cannot be shown moving by a fitted motion (see
    # `explains`): they are not fitted (their ends, and a carried motion, are still tried below)
    fit = active.copy()
    if config.screen_still and previous is None:
        still = quality(source)
        carried_here = np.zeros(count, bool) if carry is None else carry.present
        fit &= ~(unprovable(still, floor, counted, config) & ~believed & ~carried_here)
    translation = initial_translations(points1, points2, clusters, fit, config, tree, previous,
                                       None if carry is None else carry.translation)
    max_yaw = config.max_yaw_rate * config.scan_period
    fitting = fit[labels]
    icp_source, icp_labels, icp_allowed = source[fitting], labels[fitting], allowed[fitting]
    for gate in np.geomspace(config.icp_gates[0], config.icp_gates[1], config.icp_iterations):
        moved = yaw_translate(icp_source, yaw[icp_labels], translation[icp_labels])
        gap, index = tree.query(moved, distance_upper_bound=gate)
        good = np.isfinite(gap)
        good[good] = clusters.labels2[index[good]] == icp_allowed[good]
        fitted = np.bincount(icp_labels[good], minlength=count) >= 3
        if normals2 is None:
            new_yaw, new_translation = planar_kabsch(icp_source[good], points2[index[good]], icp_labels[good], count,
                                                     max_yaw)
        else:
            new_yaw, new_translation = planar_plane_step(moved[good], points2[index[good]], normals2[index[good]],
                                                         icp_labels[good], yaw, translation, count, config.point_weight,
                                                         max_yaw)
        yaw[fitted], translation[fitted] = new_yaw[fitted], new_translation[fitted]
    translation[~fit], yaw[~fit] = 0.0, 0.0

    moved = yaw_translate(source, yaw[labels], translation[labels])
    fit_moving = quality(moved)
    if previous is not None:  # the loop never trades a motion for one that fits worse
        yaw, translation, fit_moving = better_of(source, labels, previous[members], yaw, translation, fit_moving,
                                                 quality, max_yaw)
        moved = yaw_translate(source, yaw[labels], translation[labels])
    height = np.column_stack([np.zeros((len(source), 2)), translation[labels, 2]])  # still, but at the height
    fit_static = quality(source + height)
    speed = np.linalg.norm(label_means((moved - source)[:, :2], labels, count), axis=1) / config.scan_period
    moving = active & (speed > config.min_speed) & explains(fit_moving, fit_static, believed, floor, counted, config)
    ends = np.zeros(count, dtype=bool)  # moved by the shift of their two ends: flanks sliding along themselves
    spare = active & ~moving & (sizes1 >= config.end_points)
    shifted, fit_ends = np.zeros(count, dtype=bool), None
    tried = spare | (moving & (sizes1 >= config.end_points))  # a motion may yet fail as the sensor resamples still
    if config.end_spacings > 0 and tried.any():
        shift = end_shifts(points1, points2, clusters, tried, config, bands)
        shifted = np.linalg.norm(shift[:, :2], axis=1) > config.min_speed * config.scan_period
        if shifted.any():  # judged on those clusters' points only
            on = shifted[labels]
            fit_ends = fit_quality(yaw_translate(source[on], np.zeros(np.count_nonzero(on)), shift[labels[on]]),
                                   labels[on], tree, clusters.labels2, allowed[on], config, count, normals2, points2)
            ends = spare & shifted & no_worse(fit_ends, fit_static, floor, config, config.end_slack)
            yaw, translation = np.where(ends, 0.0, yaw), np.where(ends[:, None], shift, translation)
            fit_moving = Fit(*(np.where(ends, mine, theirs) for mine, theirs in zip(fit_ends, fit_moving)))
    continued = np.zeros(count, dtype=bool)
    if carry is not None and (carry.usable & active & ~moving & ~ends).any():
        continued, yaw, translation, fit_moving = continue_carried(
            source, labels, carry, active & ~moving & ~ends, yaw, translation, fit_moving, fit_static, floor, config,
            quality)
    if sensed is not None and (moving | continued | ends).any():  # standing still once more, as the sensor samples it
        either = moving | continued | ends
        check = either[labels]
        resampled = static_fit(source[check] + height[check], sensed[members][check] + height[check], labels[check],
                               tree, clusters.labels2, allowed[check], config, count, normals2, points2,
                               floors[allowed][check])
        fit_static = Fit(*(np.where(either, again, first) for again, first in zip(resampled, fit_static)))
        fitted = moving.copy()
        moving &= explains(fit_moving, fit_static, believed, floor, counted, config)
        continued &= no_worse(fit_moving, fit_static, floor, config)
        ends &= no_worse(fit_moving, fit_static, floor, config, config.end_slack)
        if fit_ends is not None:  # a fitted motion the resampling explains away: its ends may still have moved
            rescued = fitted & ~moving & shifted & no_worse(fit_ends, fit_static, floor, config, config.end_slack)
            yaw, translation = np.where(rescued, 0.0, yaw), np.where(rescued[:, None], shift, translation)
            ends |= rescued
    moving |= ends
    streak, proven = np.where(moving, 0, -1), moving.astype(np.int64)  # a first sighting, or still
    if carry is not None:  # a motion seen before: one more pair that proved it, or one more carried
        streak = np.where(continued, carry.streak + 1, streak)
        proven = np.where(continued, carry.proven, np.where(moving & carry.present, carry.proven + 1, proven))
    moving |= continued
    yaw[~moving], translation[~moving] = 0.0, 0.0
    return ClusterMotions(yaw, translation, moving, streak, proven)


def better_of(source: np.ndarray, labels: np.ndarray, previous: np.ndarray, yaw: np.ndarray, translation: np.ndarray,
              fit: Fit, quality, max_yaw: float) -> tuple[np.ndarray, np.ndarray, Fit]:
    """Per cluster, the new motion or the one its points had before (as a planar rigid fit of their displacements),
    whichever lies closer to scan t+1 (surface plus point distance)."""
    count = yaw.size
    old_yaw, old_translation = planar_kabsch(source, source + previous, labels, count, max_yaw)
    old_fit = quality(yaw_translate(source, old_yaw[labels], old_translation[labels]))
    moved_before = label_means(np.abs(previous).sum(axis=1), labels, count) > 0
    keep = moved_before & (old_fit.plane + old_fit.residual < fit.plane + fit.residual)
    chosen = Fit(*(np.where(keep, old, new) for old, new in zip(old_fit, fit)))
    return np.where(keep, old_yaw, yaw), np.where(keep[:, None], old_translation, translation), chosen


def split_motions(points1: np.ndarray, surfaces: Surfaces, clusters: Clusters, config: RigidConfig,
                  belief: np.ndarray | None, previous: np.ndarray | None = None,
                  sensed: np.ndarray | None = None, carried: Carried | None = None,
                  bands: Bands | None = None) -> tuple[Clusters, ClusterMotions]:
    """Motions of the clusters; then components whose clusters stay still although enough of their points miss the
    surfaces of scan t+1 are clustered with the finer voxel, and their pieces get motions of their own (`sensed`:
    the points as scan t saw them, before the ego compensation)."""
    points2, normals2, tree = surfaces.points, surfaces.normals, surfaces.tree
    _, still = surface_distance(points1, tree, points2, normals2, config.residual_cap,
                                clusters.parent[clusters.labels1], clusters.labels2)
    near = np.isfinite(still)
    floors = noise_floors(surfaces, clusters, float(np.median(still[near])) if near.any() else 0.0, config)
    still = np.where(near, still, 0.0)  # points with nothing near them say nothing
    motions = cluster_motions(points1, points2, clusters, config, belief, normals2, floors, tree, previous=previous,
                              sensed=sensed, carried=carried, bands=bands)
    if config.split_voxel <= 0 or clusters.count == 0:
        return clusters, motions
    changed = still > floors[clusters.parent[clusters.labels1]]
    changed_clusters = label_counts(clusters.labels1[changed], clusters.count) >= config.min_cluster_points
    components = np.unique(clusters.parent[changed_clusters & ~motions.moving])
    if components.size == 0:
        return clusters, motions
    inside1 = np.isin(clusters.parent[clusters.labels1], components)
    inside2 = np.isin(clusters.labels2, components)
    pieces = joint_clusters(points1[inside1], points2[inside2], config.split_voxel,
                            None if belief is None else belief[inside1] > config.mask_threshold)
    offset, component_offset = clusters.count, component_count(clusters)
    labels1, labels2 = clusters.labels1.copy(), clusters.labels2.copy()
    labels1[inside1] = pieces.labels1 + offset
    labels2[inside2] = pieces.labels2 + component_offset
    split = Clusters(labels1, labels2, offset + pieces.count,
                     np.concatenate([clusters.parent, pieces.parent + component_offset]))
    origin = np.zeros(component_count(pieces), np.int64)  # the component each piece was cut from
    origin[pieces.parent[pieces.labels1]] = clusters.parent[clusters.labels1[inside1]]
    floors = np.concatenate([floors, floors[origin]])
    # pieces are tried only where they miss the surfaces of their whole component, not just of their own piece
    fresh = (np.arange(split.count) >= offset) & (
        label_means(still, split.labels1, split.count, near.astype(np.float64)) > floors[split.parent])
    more = cluster_motions(points1, points2, split, config, belief, normals2, floors, tree, fresh, previous, sensed,
                           carried, bands)
    return split, ClusterMotions(np.where(fresh, more.yaw, np.pad(motions.yaw, (0, pieces.count))),
                                 np.where(fresh[:, None], more.translation, np.pad(motions.translation, ((0, pieces.count), (0, 0)))),
                                 np.where(fresh, more.moving, np.pad(motions.moving, (0, pieces.count))),
                                 np.where(fresh, more.carried, np.pad(motions.carried, (0, pieces.count), constant_values=-1)),
                                 np.where(fresh, more.proven, np.pad(motions.proven, (0, pieces.count))))


def attach_to_moving(points: np.ndarray, clustered: np.ndarray, labels: np.ndarray, motions: ClusterMotions,
                     surfaces: Surfaces, config: RigidConfig) -> np.ndarray:
    """Label of the moving cluster within attach_distance of each point, where that cluster's motion brings the point
    onto the surfaces of scan t+1 clearly better than standing still (-1 elsewhere)."""
    attached = np.full(points.shape[0], -1)
    on_moving = (labels >= 0) & motions.moving[np.maximum(labels, 0)]
    points2, normals, tree = surfaces.points, surfaces.normals, surfaces.tree
    if not on_moving.any() or points.shape[0] == 0 or points2.shape[0] == 0:
        return attached
    gap, index = PointIndex(clustered[on_moving]).query(points, distance_upper_bound=config.attach_distance)
    near = np.flatnonzero(np.isfinite(gap))
    if near.size == 0:
        return attached
    cluster = labels[on_moving][index[near]]
    moved = yaw_translate(points[near], motions.yaw[cluster], motions.translation[cluster])
    still = np.nan_to_num(surface_distance(points[near], tree, points2, normals, config.residual_cap)[1],
                          nan=config.residual_cap)
    carried = np.nan_to_num(surface_distance(moved, tree, points2, normals, config.residual_cap)[1],
                            nan=config.residual_cap)
    better = (carried < (1.0 - config.min_gain) * still) & (still - carried > 0.5 * config.min_speed * config.scan_period)
    attached[near[better]] = cluster[better]
    return attached


def apply_motions(points: np.ndarray, labels: np.ndarray, motions: ClusterMotions) -> np.ndarray:
    """Move each clustered point with its cluster's motion."""
    moved = points.copy()
    on = labels >= 0
    moved[on] = yaw_translate(points[on], motions.yaw[labels[on]], motions.translation[labels[on]])
    return moved.astype(np.float32)
