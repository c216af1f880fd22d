"""The ground under a scan: height of each point above the lowest point around it on a grid."""

from __future__ import annotations

import numpy as np

DENSE_GRID_CELLS = 1 << 22  # beyond this many grid cells (scattered outliers) the sparse path is used


def ground_mask(points: np.ndarray, cell: float = 2.0, height: float = 0.3) -> np.ndarray:
    """Flag points within `height` of the local ground."""
    return height_above_ground(points, cell) < height


def height_above_ground(points: np.ndarray, cell: float = 2.0) -> np.ndarray:
    """Height of each point above the lowest point of its grid cell (or its 8 neighbours, slope-tolerant)."""
    if points.shape[0] == 0:
        return np.zeros(0)
    keys = np.floor(points[:, :2] / cell).astype(np.int64)
    keys -= keys.min(axis=0) - 1  # a border of empty cells around the scan
    rows, cols = (int(n) + 2 for n in keys.max(axis=0))
    if rows * cols > DENSE_GRID_CELLS:
        return sparse_height_above_ground(points, keys, cols, cell)
    cells = keys[:, 0] * cols + keys[:, 1]
    lowest = np.full(rows * cols, np.inf)
    np.minimum.at(lowest, cells, points[:, 2])
    grid = lowest.reshape(rows, cols)
    neighbour_lowest = np.full_like(grid, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                np.minimum(neighbour_lowest[1:-1, 1:-1], grid[1 + dx:rows - 1 + dx, 1 + dy:cols - 1 + dy],
                           out=neighbour_lowest[1:-1, 1:-1])
    floor = np.minimum(grid, neighbour_lowest + 0.15 * cell).ravel()  # a cell without visible ground borrows its neighbours'
    return points[:, 2] - floor[cells]


def sparse_height_above_ground(points: np.ndarray, keys: np.ndarray, cols: int, cell: float) -> np.ndarray:
    """height_above_ground over the occupied cells only, for scans spread over a huge area."""
    cells = keys[:, 0] * cols + keys[:, 1]
    unique, inverse = np.unique(cells, return_inverse=True)
    lowest = np.full(unique.shape[0], np.inf, dtype=np.float64)
    np.minimum.at(lowest, inverse, points[:, 2])
    neighbour_lowest = np.full_like(lowest, np.inf)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                shifted = np.minimum(np.searchsorted(unique, unique + dx * cols + dy), unique.shape[0] - 1)
                found = unique[shifted] == unique + dx * cols + dy
                neighbour_lowest[found] = np.minimum(neighbour_lowest[found], lowest[shifted[found]])
    floor = np.minimum(lowest, neighbour_lowest + 0.15 * cell)
    return points[:, 2] - floor[inverse]
