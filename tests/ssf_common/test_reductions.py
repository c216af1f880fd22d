"""Vector lengths and column bounds equal numpy's own reductions to the last bit."""

import numpy as np
import pytest

from ssf_common.geometry.reductions import column_bounds, vector_lengths


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("columns", [1, 2, 3, 4])
def test_vector_lengths_equal_numpys(dtype, columns):
    vectors = (np.random.default_rng(columns).normal(size=(5000, columns)) * 40.0).astype(dtype)
    vectors[7] = 0.0
    expected = np.linalg.norm(vectors, axis=1)
    found = vector_lengths(vectors)
    assert found.dtype == expected.dtype
    assert np.array_equal(found, expected)


def test_vector_lengths_of_a_strided_slice_and_of_no_rows():
    points = np.random.default_rng(0).normal(size=(300, 4))
    assert np.array_equal(vector_lengths(points[:, :2]), np.linalg.norm(points[:, :2], axis=1))
    assert vector_lengths(np.zeros((0, 3))).shape == (0,)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int64])
def test_column_bounds_equal_numpys(dtype):
    values = (np.random.default_rng(1).normal(size=(2000, 3)) * 100).astype(dtype)
    low, high = column_bounds(values[:, :2])
    assert np.array_equal(low, values[:, :2].min(axis=0)) and np.array_equal(high, values[:, :2].max(axis=0))
    assert low.dtype == dtype and low.shape == (2,)


def test_column_bounds_of_one_row():
    low, high = column_bounds(np.array([[1.0, -2.0]]))
    assert low.tolist() == [1.0, -2.0] and high.tolist() == [1.0, -2.0]


def test_vector_lengths_along_the_last_axis_of_any_shape():
    vectors = np.random.default_rng(2).normal(size=(4, 7, 2))
    assert np.array_equal(vector_lengths(vectors), np.linalg.norm(vectors, axis=-1))
    assert np.array_equal(vector_lengths(np.array([3.0, 4.0])), 5.0)
