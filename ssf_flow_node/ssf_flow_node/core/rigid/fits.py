"""How well scan t+1 explains a cluster under one motion hypothesis, and whether a motion is proven against standing
still."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ssf_common.geometry.labels import label_means
from ssf_common.geometry.neighbours import PointIndex
from ssf_flow_node.core.rigid.config import RigidConfig


class Fit(NamedTuple):
    """How well scan t+1 explains each cluster under one motion hypothesis."""

    residual: np.ndarray  # mean distance to the same component in scan t+1, each capped at residual_cap (m)
    plane: np.ndarray  # mean distance to its surfaces (along their normals) over the points near them (m)
    unexplained: np.ndarray  # share of points not near it, or farther than inlier_gate from its surfaces


def surface_distance(moved: np.ndarray, tree: PointIndex, points2: np.ndarray, normals2: np.ndarray | None, cap: float,
                     allowed: np.ndarray | None = None, labels2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per point, the distance to the nearest point of scan t+1 (capped) and to its surface along the normal there
    (NaN where no point lies within the cap); `allowed`: the component each point must land on (labels2: the
    components of scan t+1)."""
    gap, index = tree.query(moved, distance_upper_bound=cap)
    hit = np.isfinite(gap)
    if allowed is not None:
        hit[hit] = labels2[index[hit]] == allowed[hit]
    point = np.where(hit, gap, cap)
    plane = np.full(len(moved), np.nan)
    if normals2 is None:
        plane[hit] = gap[hit]
    else:
        plane[hit] = np.abs(np.einsum("ij,ij->i", moved[hit] - points2[index[hit]], normals2[index[hit]]))
    return point, plane


def fit_quality(moved: np.ndarray, labels: np.ndarray, tree: PointIndex, labels2: np.ndarray, allowed: np.ndarray,
                config: RigidConfig, count: int, normals2: np.ndarray | None = None,
                points2: np.ndarray | None = None) -> Fit:
    """Per label, residuals and unexplained share of its moved points against their component in scan t+1
    (`allowed`: each point's component)."""
    point, plane = surface_distance(moved, tree, points2, normals2, config.residual_cap, allowed, labels2)
    return fit_of(point, plane, labels, count, config)


def fit_of(point: np.ndarray, plane: np.ndarray, labels: np.ndarray, count: int, config: RigidConfig) -> Fit:
    """Per label, the fit of its points' distances to the points and surfaces of scan t+1 (plane NaN: nothing near)."""
    near = np.isfinite(plane)
    sizes = np.maximum(np.bincount(labels, minlength=count), 1)
    return Fit(np.bincount(labels, point, count) / sizes,
               label_means(np.where(near, plane, 0.0), labels, count, near.astype(np.float64)),
               np.bincount(labels, ~near | (np.where(near, plane, 0.0) > config.inlier_gate), count) / sizes)


def no_worse(fit_moving: Fit, fit_static: Fit, floor: np.ndarray, config: RigidConfig, slack: float = 0.0) -> np.ndarray:
    """Per cluster, whether its motion lays it on the surfaces of scan t+1 (within the noise floor) and near its
    points no worse than standing still (by more than the `slack` share), and explains all but max_unexplained of it."""
    allowed = 1.0 + slack
    return ((fit_moving.plane <= allowed * np.maximum(fit_static.plane, floor))
            & (fit_moving.residual <= allowed * fit_static.residual) & (fit_moving.unexplained <= config.max_unexplained))


def unprovable(fit_static: Fit, floor: np.ndarray, counted: np.ndarray, config: RigidConfig) -> np.ndarray:
    """Per cluster, whether no motion could be proven by `explains` (without the mask's belief): standing still misses
    the surfaces by no more than the noise floor, and leaves too few of its points unexplained for a motion to explain
    min_explained_gain of them newly."""
    margin = 1.0 + np.sqrt(config.min_cluster_points / counted)
    return (fit_static.plane <= floor * margin) & (fit_static.unexplained < config.min_explained_gain)


def explains(fit_moving: Fit, fit_static: Fit, believed: np.ndarray, floor: np.ndarray, counted: np.ndarray,
             config: RigidConfig) -> np.ndarray:
    """Per cluster, whether its motion explains scan t+1 better than standing still (`floor`: its noise floor, m;
    `counted`: its points in the fits; `believed`: the mask calls it dynamic)."""
    keep = np.where(believed, 1.0 - config.mask_gain, 1.0 - config.min_gain)
    keep_point = np.where(believed, 1.0 - config.mask_gain, 1.0 - config.min_point_gain)
    margin = np.where(believed, 1.0, 1.0 + np.sqrt(config.min_cluster_points / counted))  # few points: wider margin
    misfit = fit_static.plane > floor * margin  # unless the mask already calls the cluster dynamic
    closer = fit_moving.residual < (1.0 - config.support_gain) * fit_static.residual  # not just sliding along planes
    proven = ((misfit & (((fit_moving.plane < keep * fit_static.plane) & closer)
                         | (fit_moving.residual < keep_point * fit_static.residual)))
              | (fit_static.unexplained - fit_moving.unexplained >= config.min_explained_gain))
    return no_worse(fit_moving, fit_static, floor, config) & proven


def static_fit(still: np.ndarray, sensed: np.ndarray, labels: np.ndarray, tree: PointIndex, labels2: np.ndarray,
               allowed: np.ndarray, config: RigidConfig, count: int, normals2: np.ndarray | None,
               points2: np.ndarray, floor: np.ndarray) -> Fit:
    """How well standing still, as the moved sensor samples it again (`sensed`: the points as scan t saw them), explains
    each cluster (`floor`: each point's noise floor, m)."""
    point, plane = surface_distance(still, tree, points2, normals2, config.residual_cap, allowed, labels2)
    if len(points2) < 2:
        return fit_of(point, plane, labels, count, config)
    # the sensor slid along the surfaces (standing still leaves most of the cluster on them, unlike a car ahead at the
    # ego's speed) and scan t+1 samples them along the slide no finer than half of it (far walls at grazing angles,
    # unlike a car beside us at the ego's speed; and coarser than resample_spacing, unlike a car's flank moving with a
    # crawling ego): there its beams land on a still surface's points up to a slide away
    resampled, resampled_plane = surface_distance(sensed, tree, points2, normals2, config.residual_cap, allowed,
                                                  labels2)
    slide = np.linalg.norm(sensed - still, axis=1)
    on_surface = np.nan_to_num(plane, nan=np.inf) < 0.5 * slide
    spacing = spacing_along(points2, tree, tree.query(still)[1], (sensed - still) / np.maximum(slide, 1e-9)[:, None])
    slid = ((spacing >= np.maximum(0.5 * slide, config.resample_spacing))
            & (label_means(on_surface.astype(np.float64), labels, count) > 0.5)[labels])
    # each point where it was, or where the beam that saw it lands again if that lies closer to the points of scan
    # t+1 and no farther from its surfaces (beyond the noise floor)
    along = slid & (resampled < point) & (np.nan_to_num(resampled_plane, nan=np.inf)
                                          <= np.maximum(np.nan_to_num(plane, nan=np.inf), floor))
    point, plane = np.where(along, resampled, point), np.where(along, resampled_plane, plane)
    # in clusters the resampling explains, a beam that now finds nothing passed the surface's end: no evidence
    passed = ((label_means(along.astype(np.float64), labels, count) >= 0.5)[labels] & np.isnan(resampled_plane)
              & ~(plane <= config.inlier_gate))
    return fit_of(point, np.where(passed, 0.0, plane), labels, count, config)


def spacing_along(points: np.ndarray, tree: PointIndex, index: np.ndarray, direction: np.ndarray,
                  neighbours: int = 8) -> np.ndarray:
    """Per query, how far the points of the tree lie apart along `direction` at points[index]: the distance to the
    nearest of its neighbours within 45 degrees of that direction (either way), else to the farthest neighbour."""
    gaps, near = tree.query(points[index], k=min(neighbours + 1, len(points)))
    offsets = points[near[:, 1:]] - points[index][:, None]
    aligned = np.abs(np.einsum("nkj,nj->nk", offsets, direction)) >= np.sqrt(0.5) * gaps[:, 1:]
    return np.where(aligned.any(axis=1), np.where(aligned, gaps[:, 1:], np.inf).min(axis=1), gaps[:, -1])
