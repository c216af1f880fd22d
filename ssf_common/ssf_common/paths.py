"""Input files read and output paths checked before the work starts, each failure one error line."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ssf_common.errors import DataError


def read_input(path: str | Path, what: str = "input") -> bytes:
    """The bytes of an input file, or one DataError line saying why it cannot be read (missing, a folder, ...)."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{path}: no such {what} file") from None
    except IsADirectoryError:
        raise DataError(f"{path}: is a folder, not a {what} file") from None
    except OSError as err:
        raise DataError(f"{path}: cannot read ({_reason(err)})") from None


def check_writable(path: str | Path, what: str = "output") -> Path:
    """Fail now, in one line, unless `path` can be written as a file; its folder is created when missing."""
    path = Path(path)
    if path.is_dir():
        raise DataError(f"{path}: is a folder; the {what} needs a file name")
    _make_folder(path.parent, path, what)
    existed = path.exists()
    try:
        with path.open("ab"):
            pass
    except OSError as err:
        raise DataError(f"{path}: cannot write the {what} ({_reason(err)})") from None
    if not existed:
        path.unlink(missing_ok=True)
    return path


def check_writable_dir(path: str | Path, what: str = "output folder") -> Path:
    """Fail now, in one line, unless `path` is (or can be made) a folder we can create files in."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise DataError(f"{path}: is a file; the {what} must be a folder")
    _make_folder(path, path, what)
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".ssf_write_check_"):
            pass
    except OSError as err:
        raise DataError(f"{path}: cannot write into the {what} ({_reason(err)})") from None
    return path


def save_npy(path: str | Path, values: np.ndarray) -> Path:
    """np.save to exactly `path` (no suffix added), with one error line on failure."""
    path = Path(path)
    try:
        with path.open("wb") as handle:
            np.save(handle, values)
    except OSError as err:
        raise DataError(f"{path}: cannot write ({_reason(err)})") from None
    return path


def _make_folder(folder: Path, path: Path, what: str) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{path}: cannot create the folder of the {what} ({_reason(err)})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise DataError(f"{path}: the folder {folder} is not writable (for the {what})")


def _reason(err: OSError) -> str:
    return err.strerror or type(err).__name__
