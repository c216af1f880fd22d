"""PCD v0.5-0.7 scans (the Point Cloud Library's format): any field types and counts; ascii, binary and
binary_compressed (LZF) data."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.lib import recfunctions

from ssf_common.errors import DataError
from ssf_common.scans.common import MAX_HEADER_BYTES, FormatError, parse_ascii, structured

PCD_ENCODINGS = ("ascii", "binary", "binary_compressed")
LZF_MAX_RATIO = 100  # LZF cannot expand data more than ~88 times: a larger claim is a corrupt header
_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8"} | {
    (kind, size): f"{kind.lower()}{size}" for kind in "IU" for size in (1, 2, 4, 8)
}


def read_pcd(raw: bytes) -> np.ndarray:
    """PCD v0.5-0.7: any field types and counts, DATA ascii, binary or binary_compressed."""
    header, body = _pcd_header(raw)
    fields, dtype, count = _pcd_layout(header)
    encoding = header["DATA"][0].lower() if header["DATA"] else ""
    if encoding == "binary":
        needed = count * dtype.itemsize
        if len(body) < needed:
            raise FormatError(f"truncated: {len(body)} bytes of binary point data, expected {needed}")
        packed = np.frombuffer(body, dtype=dtype, count=count)
    elif encoding == "ascii":
        packed = parse_ascii(body, dtype, count, [name for name, *_ in fields])
    elif encoding == "binary_compressed":
        packed = _pcd_uncompress(body, fields, dtype, count)
    else:
        raise FormatError(f"unknown DATA encoding '{encoding}' (expected one of {', '.join(PCD_ENCODINGS)})")
    return _drop_padding(packed)


def _pcd_header(raw: bytes) -> tuple[dict[str, list[str]], bytes]:
    """Header keywords with their values, and the bytes after the DATA line."""
    header: dict[str, list[str]] = {}
    position = 0
    while "DATA" not in header:
        end = raw.find(b"\n", position, MAX_HEADER_BYTES)
        if end < 0:
            raise FormatError("not a PCD file: no DATA line in the header")
        line = raw[position:end].split(b"#", 1)[0].strip()
        position = end + 1
        if not line:
            continue
        try:
            words = line.decode("ascii").split()
        except UnicodeDecodeError:
            raise FormatError("not a PCD file: header is not ASCII text") from None
        if words:
            header[words[0].upper()] = words[1:]
    if "COLUMNS" in header and "FIELDS" not in header:
        header["FIELDS"] = header["COLUMNS"]
    return header, raw[position:]


def _pcd_layout(header: dict[str, list[str]]) -> tuple[list[tuple[str, np.dtype, int]], np.dtype, int]:
    """(name, scalar dtype, count) per field, the packed point dtype, and the number of points."""
    for key in ("FIELDS", "SIZE", "TYPE"):
        if not header.get(key):
            raise FormatError(f"PCD header has no {key} line")
    names, sizes, kinds = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT") or ["1"] * len(names)
    if not len(names) == len(sizes) == len(kinds) == len(counts):
        raise FormatError(
            f"PCD header lists {len(names)} FIELDS, {len(sizes)} SIZE, {len(kinds)} TYPE, {len(counts)} COUNT values"
        )
    fields = []
    for name, size, kind, field_count in zip(names, sizes, kinds, counts):
        code = _PCD_TYPES.get((kind.upper(), _int(size, "SIZE")))
        if code is None:
            raise FormatError(f"PCD field '{name}' has unsupported TYPE {kind} with SIZE {size}")
        number = _int(field_count, "COUNT")
        if number < 1:
            raise FormatError(f"PCD field '{name}' has COUNT {number}")
        fields.append((name, np.dtype("<" + code), number))
    real = [name for name, *_ in fields if name != "_"]
    if len(set(real)) != len(real):
        raise FormatError(f"PCD header repeats a field name ({' '.join(names)})")
    width = _int(header["WIDTH"][0], "WIDTH") if header.get("WIDTH") else None
    height = _int(header["HEIGHT"][0], "HEIGHT") if header.get("HEIGHT") else 1
    points = _int(header["POINTS"][0], "POINTS") if header.get("POINTS") else None
    if width is None and points is None:
        raise FormatError("PCD header has neither WIDTH nor POINTS")
    count = points if points is not None else width * height
    if width is not None and points is not None and width * height != points:
        raise FormatError(f"PCD header says WIDTH {width} × HEIGHT {height} but POINTS {points}")
    return fields, _packed_dtype(fields), count


def _int(text: str, key: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise FormatError(f"PCD header {key} value '{text}' is not an integer") from None
    if value < 0:
        raise FormatError(f"PCD header {key} value {value} is negative")
    return value


def _packed_dtype(fields: Sequence[tuple[str, np.dtype, int]]) -> np.dtype:
    """Fields back to back in file order; padding fields '_' get unique placeholder names."""
    layout = []
    for index, (name, base, count) in enumerate(fields):
        label = f"_pad{index}" if name == "_" else name
        layout.append((label, base) if count == 1 else (label, base, (count,)))
    return np.dtype(layout)


def _drop_padding(packed: np.ndarray) -> np.ndarray:
    """A writeable copy without the '_' padding fields."""
    keep = [name for name in packed.dtype.names if not name.startswith("_pad")]
    if len(keep) == len(packed.dtype.names):
        return packed.copy()
    return recfunctions.repack_fields(packed[keep])


def _pcd_uncompress(
    body: bytes, fields: Sequence[tuple[str, np.dtype, int]], dtype: np.dtype, count: int
) -> np.ndarray:
    """binary_compressed: two uint32 sizes, then LZF of the fields stored one after the other."""
    if len(body) < 8:
        raise FormatError("truncated: binary_compressed data has no size words")
    compressed_size, raw_size = struct.unpack("<II", body[:8])
    if raw_size != count * dtype.itemsize:
        raise FormatError(f"binary_compressed data unpacks to {raw_size} bytes, expected {count * dtype.itemsize}")
    if len(body) - 8 < compressed_size:
        raise FormatError(f"truncated: {len(body) - 8} bytes of compressed data, expected {compressed_size}")
    if raw_size > LZF_MAX_RATIO * max(compressed_size, 1):
        raise FormatError(f"binary_compressed data claims {raw_size} bytes from {compressed_size}; LZF cannot do that")
    columns = lzf_decompress(body[8 : 8 + compressed_size], raw_size) if raw_size else b""
    points = np.empty(count, dtype=dtype)
    position = 0
    for (_, base, number), label in zip(fields, dtype.names):
        size = count * number * base.itemsize
        values = np.frombuffer(columns, dtype=base, count=count * number, offset=position)
        points[label] = values.reshape(count, number) if number > 1 else values
        position += size
    return points


def lzf_decompress(data: bytes, size: int) -> bytes:
    """Decompress LZF (liblzf format, as PCL uses) into exactly `size` bytes."""
    out = bytearray()
    position = 0
    while position < len(data):
        control = data[position]
        position += 1
        if control < 32:
            length = control + 1
            if position + length > len(data):
                raise FormatError("corrupt compressed data: a literal run passes the end")
            out += data[position : position + length]
            position += length
            continue
        length = control >> 5
        if length == 7:
            length += _byte_at(data, position)
            position += 1
        start = len(out) - ((control & 0x1F) << 8) - _byte_at(data, position) - 1
        position += 1
        length += 2
        if start < 0:
            raise FormatError("corrupt compressed data: a back reference points before the start")
        period = len(out) - start
        out += (out[start:] * math.ceil(length / period))[:length] if length > period else out[start : start + length]
        if len(out) > size:
            break
    if len(out) != size:
        raise FormatError(f"corrupt compressed data: unpacks to {len(out)} bytes, expected {size}")
    return bytes(out)


def _byte_at(data: bytes, position: int) -> int:
    if position >= len(data):
        raise FormatError("corrupt compressed data: a back reference passes the end")
    return data[position]


def lzf_compress(data: bytes) -> bytes:
    """Compress with LZF (greedy matching over 3-byte prefixes, 8 KiB window)."""
    out = bytearray()
    literals = bytearray()

    def flush() -> None:
        for start in range(0, len(literals), 32):
            chunk = literals[start : start + 32]
            out.append(len(chunk) - 1)
            out.extend(chunk)
        literals.clear()

    last_seen: dict[bytes, int] = {}
    position, end = 0, len(data)
    while position < end - 2:
        key = data[position : position + 3]
        earlier = last_seen.get(key)
        last_seen[key] = position
        if earlier is None or position - earlier > 8192:
            literals.append(data[position])
            position += 1
            continue
        length, longest = 3, min(264, end - position)
        while length < longest and data[earlier + length] == data[position + length]:
            length += 1
        flush()
        distance, code = position - earlier - 1, length - 2
        if code < 7:
            out.append((code << 5) | (distance >> 8))
        else:
            out += bytes(((7 << 5) | (distance >> 8), code - 7))
        out.append(distance & 0xFF)
        position += length
    literals.extend(data[position:])
    flush()
    return bytes(out)


def write_pcd(path: str | Path, points: np.ndarray, *, encoding: str = "binary") -> None:
    """Write a structured array, or float (N, 3) / (N, 4) x, y, z[, intensity], as a PCD v0.7 file."""
    if encoding not in PCD_ENCODINGS:
        raise DataError(f"unknown PCD encoding '{encoding}' (expected one of {', '.join(PCD_ENCODINGS)})")
    packed = _as_packed_little_endian(structured(points))
    shape = packed.shape if packed.ndim == 2 else (1, packed.size)
    packed = packed.reshape(-1)
    names = packed.dtype.names
    bases = [_field_base(packed.dtype, name) for name in names]
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format",
            "VERSION 0.7",
            "FIELDS " + " ".join(names),
            "SIZE " + " ".join(str(base.itemsize) for base, _ in bases),
            "TYPE " + " ".join(base.kind.upper() for base, _ in bases),
            "COUNT " + " ".join(str(number) for _, number in bases),
            f"WIDTH {shape[1]}",
            f"HEIGHT {shape[0]}",
            "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {packed.size}",
            f"DATA {encoding}",
            "",
        ]
    ).encode("ascii")
    if encoding == "binary":
        body = packed.tobytes()
    elif encoding == "ascii":
        body = _format_ascii(packed)
    else:
        columns = b"".join(np.ascontiguousarray(packed[name]).tobytes() for name in names)
        compressed = lzf_compress(columns)
        body = struct.pack("<II", len(compressed), len(columns)) + compressed
    Path(path).write_bytes(header + body)


def _field_base(dtype: np.dtype, name: str) -> tuple[np.dtype, int]:
    field_dtype = dtype.fields[name][0]
    base, shape = field_dtype.subdtype if field_dtype.subdtype else (field_dtype, ())
    if base.kind not in "iuf" or base.names is not None:
        raise DataError(f"field '{name}' has dtype {base}, which PCD cannot store (int, uint or float)")
    return base, int(np.prod(shape, dtype=np.int64))


def _as_packed_little_endian(points: np.ndarray) -> np.ndarray:
    """Fields back to back, little-endian, in the array's field order."""
    layout = []
    for name in points.dtype.names:
        base, number = _field_base(points.dtype, name)
        little = base.newbyteorder("<")
        layout.append((name, little) if number == 1 else (name, little, points.dtype.fields[name][0].shape))
    return points.astype(np.dtype(layout))


def _format_ascii(points: np.ndarray) -> bytes:
    """One line per point; floats with enough digits to read back bit-exact."""
    columns: list[np.ndarray] = []
    for name in points.dtype.names:
        values = points[name].reshape(len(points), -1)
        base = values.dtype
        fmt = {4: "%.9g", 8: "%.17g"}.get(base.itemsize, "%d") if base.kind == "f" else "%d"
        columns.extend(np.char.mod(fmt, values[:, column]) for column in range(values.shape[1]))
    if not columns or len(points) == 0:
        return b""
    lines = columns[0].astype(object)
    for column in columns[1:]:
        lines = lines + " " + column.astype(object)
    return ("\n".join(lines) + "\n").encode("ascii")
