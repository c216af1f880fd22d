"""Point loops numpy runs slowly, compiled with numba (once, cached beside this file): the same arithmetic in the same
order as the numpy expressions they replace, so their results are the same bits."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def posed_points(points: np.ndarray, steps: np.ndarray, low: int, table: np.ndarray) -> np.ndarray:
    """Each point (N, 3) through the pose of its step, row `steps[i] - low` of `table` (K, 12: the top three rows of a
    4x4 pose), in float64, returned as float32."""
    moved = np.empty((points.shape[0], 3), dtype=np.float32)
    for i in range(points.shape[0]):
        pose = table[steps[i] - low]
        x, y, z = np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2])
        for row in range(3):
            moved[i, row] = pose[4 * row] * x + pose[4 * row + 1] * y + pose[4 * row + 2] * z + pose[4 * row + 3]
    return moved
