"""What the scan formats share: the format error, field names, and ASCII tables of values."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.lib import recfunctions

from ssf_common.errors import DataError

XYZ = ("x", "y", "z")
MAX_HEADER_BYTES = 1 << 16


class FormatError(Exception):
    """A problem inside a file; the reader adds the path."""


def parse_ascii(body: bytes, dtype: np.dtype, count: int, names: Sequence[str]) -> np.ndarray:
    """Whitespace-separated values, one point per line, in field order."""
    per_point = values_per_point(dtype)
    if count * per_point > len(body):  # each value takes at least one byte
        raise FormatError(f"truncated: {len(body)} bytes of ASCII data cannot hold {count} points × {per_point} values")
    tokens = np.array(body.split()[: count * per_point])
    if tokens.size < count * per_point:
        raise FormatError(f"truncated: {tokens.size} ASCII values, expected {count} points × {per_point}")
    table = tokens.reshape(count, per_point)
    points = np.empty(count, dtype=dtype)
    column = 0
    for name, label in zip(names, dtype.names):
        field_dtype = dtype.fields[label][0]
        base, width = (field_dtype.subdtype[0], field_dtype.shape[0]) if field_dtype.shape else (field_dtype, 1)
        try:
            values = table[:, column : column + width].astype(base)
        except (ValueError, OverflowError) as err:
            raise FormatError(f"field '{name}' holds a value that is not {base} ({err})") from None
        points[label] = values if width > 1 else values[:, 0]
        column += width
    return points


def values_per_point(dtype: np.dtype) -> int:
    """Scalar values in one point of a structured dtype (fields with a count count that often)."""
    return sum(int(np.prod(dtype.fields[name][0].shape, dtype=np.int64)) for name in dtype.names)


def structured(points: np.ndarray) -> np.ndarray:
    """Structured view of the points: as given, or x, y, z[, intensity] columns."""
    if points.dtype.names is not None:
        return points
    if points.ndim != 2 or points.shape[1] not in (3, 4):
        raise DataError(f"expected a structured array or an N×3 / N×4 array, got {points.dtype} {points.shape}")
    names = [*XYZ, "intensity"][: points.shape[1]]
    return recfunctions.unstructured_to_structured(np.ascontiguousarray(points), names=names)
