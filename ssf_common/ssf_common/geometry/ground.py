"""The ground under a scan: height of each point above the lowest point around it on a grid, or in its zone."""

from __future__ import annotations

import numpy as np

from ssf_common.geometry.sampling import grid_cells

DENSE_GRID_CELLS = 1 << 22  # beyond this many grid cells (scattered outliers) the sparse path is used
ZONE_BINS = 512  # at most this many range bins per azimuth sector (their size grows for scans with far outliers)
SPREAD_FLOOR = 0.01  # m: the ground's spread about its zone fit is taken as at least this (no range sensor is finer)
SLOPE_RIDGE = 1.0  # pulls a zone's ground slope towards level where its returns span little range (weight x m^2)


def ground_mask(points: np.ndarray, cell: float = 2.0, height: float = 0.3, zones: bool = False) -> np.ndarray:
    """Flag points within `height` of the local ground."""
    return height_above_ground(points, cell, zones) < height


def height_above_ground(points: np.ndarray, cell: float = 2.0, zones: bool = False) -> np.ndarray:
    """Height of each point above the grid's ground, or (`zones`: sensor frame) its zone's where that is lower."""
    if points.shape[0] == 0:
        return np.zeros(0)
    height = grid_height_above_ground(points, cell)
    if zones:  # a cell without a ground return (under a car, past the last ground ring) takes its zone's ground
        ground, margin = zone_ground(points, cell)
        height = np.maximum(height, points[:, 2] - (ground + margin))
    return height


def grid_height_above_ground(points: np.ndarray, cell: float) -> np.ndarray:
    """Height of each point above the lowest point of its grid cell (or its 8 neighbours, slope-tolerant)."""
    cells, (rows, cols) = grid_cells(points[:, :2], cell, border=1)  # a border of empty cells around the scan
    if rows * cols > DENSE_GRID_CELLS:
        return sparse_height_above_ground(points, cells, cols, cell)
    lowest = np.full(rows * cols, np.inf)
    np.minimum.at(lowest, cells, np.asarray(points[:, 2], np.float64))  # same dtype: ufunc.at's fast path
    grid = lowest.reshape(rows, cols)
    neighbour_lowest = np.full_like(grid, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                np.minimum(neighbour_lowest[1:-1, 1:-1], grid[1 + dx:rows - 1 + dx, 1 + dy:cols - 1 + dy],
                           out=neighbour_lowest[1:-1, 1:-1])
    floor = np.minimum(grid, neighbour_lowest + 0.15 * cell).ravel()  # a cell without visible ground borrows its neighbours'
    return points[:, 2] - floor[cells]


def sparse_height_above_ground(points: np.ndarray, cells: np.ndarray, cols: int, cell: float) -> np.ndarray:
    """height_above_ground over the occupied cells only (`cells`: each point's code on a grid `cols` wide), for scans
    spread over a huge area."""
    unique, inverse = np.unique(cells, return_inverse=True)
    lowest = np.full(unique.shape[0], np.inf, dtype=np.float64)
    np.minimum.at(lowest, inverse, np.asarray(points[:, 2], np.float64))
    neighbour_lowest = np.full_like(lowest, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                shifted = np.minimum(np.searchsorted(unique, unique + dx * cols + dy), unique.shape[0] - 1)
                found = unique[shifted] == unique + dx * cols + dy
                neighbour_lowest[found] = np.minimum(neighbour_lowest[found], lowest[shifted[found]])
    floor = np.minimum(lowest, neighbour_lowest + 0.15 * cell)
    return points[:, 2] - floor[inverse]


def zone_ground(points: np.ndarray, cell: float = 2.0, sectors: int = 64, bandwidth: float = 0.25,
                tolerance: float = 0.3, iterations: int = 4) -> tuple[np.ndarray, float]:
    """Ground under each point of a scan in its sensor's frame, fitted per azimuth sector (+inf: none), and a margin."""
    # per sector, a line in range fitted locally (a window growing with range: `bandwidth` x range) to the lowest
    # return of each range bin, refitted on the bins within 3 spreads of it (objects' bottoms lie above), so that it
    # passes under objects whose cells hold no ground return and reaches past the last ground ring; the margin is 2
    # spreads of the ground about its fit, measured on the scan
    distance = np.hypot(points[:, 0], points[:, 1])
    sector = np.floor((np.arctan2(points[:, 1], points[:, 0]) + np.pi) * (sectors / (2 * np.pi))).astype(np.int64)
    sector %= sectors
    size = max(cell, float(distance.max()) / ZONE_BINS)
    bins = int(distance.max() // size) + 1
    radial = np.minimum((distance // size).astype(np.int64), bins - 1)
    lowest = np.full(sectors * bins, np.inf)
    np.minimum.at(lowest, sector * bins + radial, np.asarray(points[:, 2], np.float64))
    lowest = lowest.reshape(sectors, bins)
    seen = np.isfinite(lowest)
    heights = np.where(seen, lowest, 0.0)
    centre = (np.arange(bins) + 0.5) * size
    offset = centre[None, :] - centre[:, None]  # (target bin, source bin): source range - target range
    kernel = np.exp(-0.5 * (offset / np.maximum(size, bandwidth * centre)[:, None]) ** 2)
    moments = [(kernel * offset ** power).T for power in range(3)]
    inliers, spread = seen, tolerance / 3.0
    for _ in range(iterations):
        weight = inliers.astype(np.float64)
        s0, s1, s2 = (weight @ moment for moment in moments)
        t0, t1 = ((weight * heights) @ moment for moment in moments[:2])
        s2 += SLOPE_RIDGE
        det = s0 * s2 - s1 * s1
        supported = s0 > 0.5
        safe = np.where(supported, det, 1.0)
        level = np.where(supported, (s2 * t0 - s1 * t1) / safe, np.inf)
        slope = np.where(supported, (s0 * t1 - s1 * t0) / safe, 0.0)
        residual = np.where(seen & supported, lowest - np.where(supported, level, 0.0), np.inf)
        inliers = residual < min(tolerance, 3.0 * spread)
        if not inliers.any():
            break
        spread = max(SPREAD_FLOOR, 1.4826 * float(np.median(np.abs(residual[inliers]))))
    ground = level[sector, radial] + slope[sector, radial] * (distance - centre[radial])
    return ground, 2.0 * spread
