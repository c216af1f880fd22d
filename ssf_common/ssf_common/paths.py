"""Output paths checked before the work starts, and files written with one error line on failure."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ssf_common.errors import DataError


def check_writable(path: str | Path, what: str = "output") -> Path:
    """Fail early, with one line, when `path` cannot be written (its folder is created when missing)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{path}: cannot create the {what} folder ({err.strerror})") from None
    if path.is_dir():
        raise DataError(f"{path}: is a folder; give a file name for the {what}")
    if not os.access(path.parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise DataError(f"{path}: the {what} cannot be written here")
    return path


def save_npy(path: str | Path, values: np.ndarray) -> Path:
    """np.save to exactly `path` (no suffix added), with one error line on failure."""
    path = Path(path)
    try:
        with path.open("wb") as handle:
            np.save(handle, values)
    except OSError as err:
        raise DataError(f"{path}: cannot write ({err.strerror})") from None
    return path
