"""NumPy .npy scans: an N×3 / N×4 numeric array, or a structured array with x, y, z fields."""

from __future__ import annotations

import numpy as np
from numpy.lib import recfunctions

from ssf_common.arrays import NpyFormatError, load_npy
from ssf_common.scans.common import XYZ, FormatError


def read_npy(raw: bytes) -> np.ndarray:
    """(N, 3) / (N, 4) numeric or structured .npy as a flat structured array."""
    try:
        array = load_npy(raw)
    except NpyFormatError as err:
        raise FormatError(str(err)) from None
    if array.dtype.names is not None:
        return array.reshape(-1)
    if array.ndim != 2 or array.shape[1] not in (3, 4) or array.dtype.kind not in "iuf":
        raise FormatError(f"expected a numeric N×3 or N×4 array, got {array.dtype} {array.shape}")
    names = [*XYZ, "intensity"][: array.shape[1]]
    return recfunctions.unstructured_to_structured(np.ascontiguousarray(array), names=names)
