"""KITTI velodyne .bin scans: little-endian float32 x, y, z, intensity per point, no header."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ssf_common.errors import DataError
from ssf_common.scans.common import XYZ, FormatError

POINT_BYTES = 16


def read_kitti_bin(raw: bytes) -> np.ndarray:
    """The points of a KITTI .bin as a structured array of x, y, z, intensity."""
    if len(raw) % POINT_BYTES:
        raise FormatError(f"size {len(raw)} bytes is not a multiple of 16 (float32 x, y, z, intensity)")
    return np.frombuffer(raw, dtype=kitti_dtype()).copy()


def kitti_dtype() -> np.dtype:
    """x, y, z, intensity as little-endian float32."""
    return np.dtype([(name, "<f4") for name in (*XYZ, "intensity")])


def write_bin(path: str | Path, points: np.ndarray) -> None:
    """Write float (N, 3) or (N, 4) points as a KITTI .bin (intensity 0 when absent)."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] not in (3, 4):
        raise DataError(f"write_bin needs an N×3 or N×4 array, got shape {points.shape}")
    out = np.zeros((len(points), 4), dtype="<f4")
    out[:, : points.shape[1]] = points
    Path(path).write_bytes(out.tobytes())
