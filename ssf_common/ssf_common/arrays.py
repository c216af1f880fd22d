"""Numeric arrays from files (.npy, or whitespace-separated text), checked for dtype, shape and finiteness."""

from __future__ import annotations

import io
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ssf_common.errors import DataError
from ssf_common.paths import read_input

NUMERIC_KINDS = "biuf"  # bool, int, uint, float
_KIND_NAMES = {"b": "bool", "i": "int", "u": "uint", "f": "float", "c": "complex", "U": "str", "S": "bytes",
               "O": "object", "V": "structured", "M": "datetime", "m": "timedelta"}


class NpyFormatError(ValueError):
    """Bytes that are not a readable .npy array (the caller adds the file name)."""


def load_npy(raw: bytes) -> np.ndarray:
    """One array from .npy bytes: no pickles, and no header that promises more data than the bytes hold."""
    stream = io.BytesIO(raw)
    try:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
        elif version in ((2, 0), (3, 0)):
            shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
        else:
            raise NpyFormatError(f"not a .npy file of a known version ({version})")
    except NpyFormatError:
        raise
    except Exception as err:  # noqa: BLE001 - numpy's header parser raises many kinds on junk
        raise NpyFormatError(f"not a valid .npy file ({_first_line(err)})") from None
    if dtype.hasobject:
        raise NpyFormatError(f"holds Python objects ({dtype}), which are never unpickled")
    count = int(np.prod(shape, dtype=object)) if shape else 1
    needed, held = count * dtype.itemsize, len(raw) - stream.tell()
    if held < needed:
        raise NpyFormatError(f"truncated: the header promises {needed} bytes of data, the file holds {held}")
    try:
        return np.load(io.BytesIO(raw), allow_pickle=False)
    except (ValueError, EOFError, OSError) as err:
        raise NpyFormatError(f"not a valid .npy file ({_first_line(err)})") from None


def read_array(
    path: str | Path,
    *,
    what: str = "array",
    kinds: str = NUMERIC_KINDS,
    ndim: int | Sequence[int] | None = None,
    shape: Sequence[int | None] | None = None,
    finite: bool = False,
) -> np.ndarray:
    """A plain numeric array from .npy or text, with dtype kind, dimensions, shape and finiteness checked.

    kinds: allowed numpy kinds ('b' bool, 'i' int, 'u' uint, 'f' float); shape: None entries match any size.
    Every failure is one DataError line naming the file and what it holds.
    """
    path = Path(path)
    raw = read_input(path, what)
    try:
        array = load_npy(raw) if path.suffix.lower() == ".npy" else _load_text(raw)
    except NpyFormatError as err:
        raise DataError(f"{path}: {err}") from None
    check_array(array, str(path), what=what, kinds=kinds, ndim=ndim, shape=shape, finite=finite)
    return array


def check_array(
    array: np.ndarray,
    source: str,
    *,
    what: str = "array",
    kinds: str = NUMERIC_KINDS,
    ndim: int | Sequence[int] | None = None,
    shape: Sequence[int | None] | None = None,
    finite: bool = False,
) -> np.ndarray:
    """The checks of read_array on an array already in memory (source names it in the error)."""
    if array.dtype.names is not None or array.dtype.kind not in kinds:
        allowed = "/".join(_KIND_NAMES.get(kind, kind) for kind in kinds)
        raise DataError(f"{source}: the {what} holds {_KIND_NAMES.get(array.dtype.kind, 'other')} values "
                        f"({array.dtype}); expected {allowed}")
    allowed_ndim = (ndim,) if isinstance(ndim, int) else tuple(ndim) if ndim is not None else None
    if allowed_ndim is not None and array.ndim not in allowed_ndim:
        raise DataError(f"{source}: the {what} has {array.ndim} dimensions {array.shape}; expected "
                        f"{' or '.join(map(str, allowed_ndim))}")
    if shape is not None and (len(shape) != array.ndim or any(s is not None and s != n for s, n in zip(shape, array.shape))):
        wanted = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise DataError(f"{source}: the {what} has shape {array.shape}; expected {wanted}")
    if finite and array.dtype.kind == "f" and not np.isfinite(array).all():
        bad = int(array.size - np.count_nonzero(np.isfinite(array)))
        raise DataError(f"{source}: the {what} holds {bad} NaN or infinite values of {array.size}")
    return array


def _load_text(raw: bytes) -> np.ndarray:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise NpyFormatError(f"not text (byte 0x{raw[err.start]:02x} at offset {err.start}) and not .npy") from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file is an empty array, checked by the caller
            return np.loadtxt(io.StringIO(text), ndmin=1)
    except ValueError as err:
        raise NpyFormatError(f"not whitespace-separated numbers ({_first_line(err)})") from None


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__
