"""The compiled point loops give numpy's own results to the last bit."""

import numpy as np
import pytest

from ssf_common.geometry.compiled import posed_points
from ssf_common.geometry.se3 import interpolate_poses, make_pose
from ssf_common.geometry.sweep import deskew, reskew


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_posed_points_equal_the_numpy_expression(dtype):
    rng = np.random.default_rng(3)
    points = rng.uniform(-80.0, 80.0, (20000, 3)).astype(dtype)
    table = interpolate_poses(np.eye(4), make_pose(1.2, 0.1, 0.03, 0.04), np.arange(-5, 300) / 4096)[:, :3, :]
    table = table.reshape(-1, 12).copy()
    steps = rng.integers(-5, 300, len(points))
    pose = table[steps + 5]
    x, y, z = (points[:, column].astype(np.float64) for column in range(3))
    expected = np.stack([pose[:, 4 * row] * x + pose[:, 4 * row + 1] * y + pose[:, 4 * row + 2] * z
                         + pose[:, 4 * row + 3] for row in range(3)], axis=1).astype(np.float32)
    found = posed_points(points, steps, -5, table)
    assert found.dtype == np.float32 and np.array_equal(found, expected)
    assert posed_points(points[:0], steps[:0], -5, table).shape == (0, 3)


def test_a_sweep_deskewed_and_reskewed_comes_back_and_extra_columns_are_left_out():
    rng = np.random.default_rng(4)
    points = np.c_[rng.uniform(-50.0, 50.0, (5000, 3)), rng.uniform(0, 1, 5000)].astype(np.float32)  # x y z intensity
    time = np.sort(rng.uniform(-0.1, 0.0, 5000)).astype(np.float32)
    motion = make_pose(1.0, 0.02, 0.0, 0.05)
    moved = deskew(points, time, motion, 0.1)
    assert moved.shape == (5000, 3) and np.abs(moved - points[:, :3]).max() > 0.5
    np.testing.assert_allclose(reskew(moved, time, motion, 0.1), points[:, :3], atol=1e-4)
