"""LiDAR scan files: .npy, KITTI .bin, PCD (ascii, binary, binary_compressed) and PLY vertices.

`read_points` returns every field of a file as a numpy structured array, bit for bit;
`read_scan` returns the float32 (N, 3) or (N, 4) x, y, z[, intensity] that the cores use.
Malformed or truncated files raise DataError with one line that names the file and the problem.
"""

from __future__ import annotations

import io
import math
import struct
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.lib import recfunctions

from ssf_common.errors import DataError

XYZ = ("x", "y", "z")
PCD_ENCODINGS = ("ascii", "binary", "binary_compressed")
_MAX_HEADER_BYTES = 1 << 16
_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8"} | {
    (kind, size): f"{kind.lower()}{size}" for kind in "IU" for size in (1, 2, 4, 8)
}
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def read_scan(path: str | Path) -> np.ndarray:
    """float32 (N, 3) x, y, z, or (N, 4) with intensity when the file has it; non-finite points dropped."""
    path = Path(path)
    points = read_points(path)
    names = points.dtype.names
    missing = [name for name in XYZ if name not in names]
    if missing:
        raise DataError(f"{path}: no {'/'.join(missing)} field (fields: {', '.join(names) or 'none'})")
    columns = [*XYZ, "intensity"] if "intensity" in names else list(XYZ)
    scan = np.empty((points.size, len(columns)), dtype=np.float32)
    for index, name in enumerate(columns):
        if points.dtype.fields[name][0].shape:
            raise DataError(f"{path}: field '{name}' has count > 1; expected one value per point")
        scan[:, index] = points[name].reshape(-1)
    scan = scan[np.isfinite(scan[:, :3]).all(axis=1)]
    if len(scan) == 0:
        raise DataError(f"{path}: no point with finite x, y, z ({points.size} points in the file)")
    return scan


def read_points(path: str | Path) -> np.ndarray:
    """Every field of every point of a scan file as a flat structured array, values bit-exact."""
    path = Path(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise DataError(f"{path}: unsupported scan format '{path.suffix}' (supported: {', '.join(_READERS)})")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as err:
        raise DataError(f"{path}: cannot read ({err.strerror or err})") from None
    try:
        return reader(raw)
    except _FormatError as err:
        raise DataError(f"{path}: {err}") from None


class _FormatError(Exception):
    """A problem inside a file; read_points adds the path."""


def _read_npy(raw: bytes) -> np.ndarray:
    """(N, 3) / (N, 4) numeric or structured .npy."""
    try:
        array = np.load(io.BytesIO(raw), allow_pickle=False)
    except (ValueError, EOFError, OSError) as err:
        raise _FormatError(f"not a valid .npy file ({err})") from None
    if not isinstance(array, np.ndarray):
        raise _FormatError("holds an archive, not one array")
    if array.dtype.names is not None:
        return array.reshape(-1)
    if array.ndim != 2 or array.shape[1] not in (3, 4) or array.dtype.kind not in "iuf":
        raise _FormatError(f"expected a numeric N×3 or N×4 array, got {array.dtype} {array.shape}")
    names = [*XYZ, "intensity"][: array.shape[1]]
    return recfunctions.unstructured_to_structured(np.ascontiguousarray(array), names=names)


def _read_kitti_bin(raw: bytes) -> np.ndarray:
    """KITTI velodyne .bin: little-endian float32 x, y, z, intensity per point."""
    if len(raw) % 16:
        raise _FormatError(f"size {len(raw)} bytes is not a multiple of 16 (float32 x, y, z, intensity)")
    return np.frombuffer(raw, dtype=_kitti_dtype()).copy()


def _kitti_dtype() -> np.dtype:
    return np.dtype([(name, "<f4") for name in (*XYZ, "intensity")])


# PCD


def _read_pcd(raw: bytes) -> np.ndarray:
    """PCD v0.5-0.7: any field types and counts, DATA ascii, binary or binary_compressed."""
    header, body = _pcd_header(raw)
    fields, dtype, count = _pcd_layout(header)
    encoding = header["DATA"][0].lower() if header["DATA"] else ""
    if encoding == "binary":
        needed = count * dtype.itemsize
        if len(body) < needed:
            raise _FormatError(f"truncated: {len(body)} bytes of binary point data, expected {needed}")
        packed = np.frombuffer(body, dtype=dtype, count=count)
    elif encoding == "ascii":
        packed = _parse_ascii(body, dtype, count, [name for name, *_ in fields])
    elif encoding == "binary_compressed":
        packed = _pcd_uncompress(body, fields, dtype, count)
    else:
        raise _FormatError(f"unknown DATA encoding '{encoding}' (expected one of {', '.join(PCD_ENCODINGS)})")
    return _drop_padding(packed)


def _pcd_header(raw: bytes) -> tuple[dict[str, list[str]], bytes]:
    """Header keywords with their values, and the bytes after the DATA line."""
    header: dict[str, list[str]] = {}
    position = 0
    while "DATA" not in header:
        end = raw.find(b"\n", position, _MAX_HEADER_BYTES)
        if end < 0:
            raise _FormatError("not a PCD file: no DATA line in the header")
        line = raw[position:end].split(b"#", 1)[0].strip()
        position = end + 1
        if not line:
            continue
        try:
            key, *values = line.decode("ascii").split()
        except UnicodeDecodeError:
            raise _FormatError("not a PCD file: header is not ASCII text") from None
        header[key.upper()] = values
    if "COLUMNS" in header and "FIELDS" not in header:
        header["FIELDS"] = header["COLUMNS"]
    return header, raw[position:]


def _pcd_layout(header: dict[str, list[str]]) -> tuple[list[tuple[str, np.dtype, int]], np.dtype, int]:
    """(name, scalar dtype, count) per field, the packed point dtype, and the number of points."""
    for key in ("FIELDS", "SIZE", "TYPE"):
        if not header.get(key):
            raise _FormatError(f"PCD header has no {key} line")
    names, sizes, kinds = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT") or ["1"] * len(names)
    if not len(names) == len(sizes) == len(kinds) == len(counts):
        raise _FormatError(
            f"PCD header lists {len(names)} FIELDS, {len(sizes)} SIZE, {len(kinds)} TYPE, {len(counts)} COUNT values"
        )
    fields = []
    for name, size, kind, field_count in zip(names, sizes, kinds, counts):
        code = _PCD_TYPES.get((kind.upper(), _int(size, "SIZE")))
        if code is None:
            raise _FormatError(f"PCD field '{name}' has unsupported TYPE {kind} with SIZE {size}")
        number = _int(field_count, "COUNT")
        if number < 1:
            raise _FormatError(f"PCD field '{name}' has COUNT {number}")
        fields.append((name, np.dtype("<" + code), number))
    real = [name for name, *_ in fields if name != "_"]
    if len(set(real)) != len(real):
        raise _FormatError(f"PCD header repeats a field name ({' '.join(names)})")
    width = _int(header["WIDTH"][0], "WIDTH") if header.get("WIDTH") else None
    height = _int(header["HEIGHT"][0], "HEIGHT") if header.get("HEIGHT") else 1
    points = _int(header["POINTS"][0], "POINTS") if header.get("POINTS") else None
    if width is None and points is None:
        raise _FormatError("PCD header has neither WIDTH nor POINTS")
    count = points if points is not None else width * height
    if width is not None and points is not None and width * height != points:
        raise _FormatError(f"PCD header says WIDTH {width} × HEIGHT {height} but POINTS {points}")
    return fields, _packed_dtype(fields), count


def _int(text: str, key: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise _FormatError(f"PCD header {key} value '{text}' is not an integer") from None
    if value < 0:
        raise _FormatError(f"PCD header {key} value {value} is negative")
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


def _parse_ascii(body: bytes, dtype: np.dtype, count: int, names: Sequence[str]) -> np.ndarray:
    """Whitespace-separated values, one point per line, in field order."""
    tokens = np.array(body.split()[: count * _values_per_point(dtype)])
    per_point = _values_per_point(dtype)
    if tokens.size < count * per_point:
        raise _FormatError(f"truncated: {tokens.size} ASCII values, expected {count} points × {per_point}")
    table = tokens.reshape(count, per_point)
    points = np.empty(count, dtype=dtype)
    column = 0
    for name, label in zip(names, dtype.names):
        field_dtype = dtype.fields[label][0]
        base, width = (field_dtype.subdtype[0], field_dtype.shape[0]) if field_dtype.shape else (field_dtype, 1)
        try:
            values = table[:, column : column + width].astype(base)
        except (ValueError, OverflowError) as err:
            raise _FormatError(f"field '{name}' holds a value that is not {base} ({err})") from None
        points[label] = values if width > 1 else values[:, 0]
        column += width
    return points


def _values_per_point(dtype: np.dtype) -> int:
    return sum(int(np.prod(dtype.fields[name][0].shape, dtype=np.int64)) for name in dtype.names)


def _pcd_uncompress(
    body: bytes, fields: Sequence[tuple[str, np.dtype, int]], dtype: np.dtype, count: int
) -> np.ndarray:
    """binary_compressed: two uint32 sizes, then LZF of the fields stored one after the other."""
    if len(body) < 8:
        raise _FormatError("truncated: binary_compressed data has no size words")
    compressed_size, raw_size = struct.unpack("<II", body[:8])
    if raw_size != count * dtype.itemsize:
        raise _FormatError(f"binary_compressed data unpacks to {raw_size} bytes, expected {count * dtype.itemsize}")
    if len(body) - 8 < compressed_size:
        raise _FormatError(f"truncated: {len(body) - 8} bytes of compressed data, expected {compressed_size}")
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
                raise _FormatError("corrupt compressed data: a literal run passes the end")
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
            raise _FormatError("corrupt compressed data: a back reference points before the start")
        period = len(out) - start
        out += (out[start:] * math.ceil(length / period))[:length] if length > period else out[start : start + length]
        if len(out) > size:
            break
    if len(out) != size:
        raise _FormatError(f"corrupt compressed data: unpacks to {len(out)} bytes, expected {size}")
    return bytes(out)


def _byte_at(data: bytes, position: int) -> int:
    if position >= len(data):
        raise _FormatError("corrupt compressed data: a back reference passes the end")
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
    packed = _as_packed_little_endian(_structured(points))
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


def write_bin(path: str | Path, points: np.ndarray) -> None:
    """Write float (N, 3) or (N, 4) points as a KITTI .bin (intensity 0 when absent)."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] not in (3, 4):
        raise DataError(f"write_bin needs an N×3 or N×4 array, got shape {points.shape}")
    out = np.zeros((len(points), 4), dtype="<f4")
    out[:, : points.shape[1]] = points
    Path(path).write_bytes(out.tobytes())


def _structured(points: np.ndarray) -> np.ndarray:
    """Structured view of the points: as given, or x, y, z[, intensity] columns."""
    if points.dtype.names is not None:
        return points
    if points.ndim != 2 or points.shape[1] not in (3, 4):
        raise DataError(f"expected a structured array or an N×3 / N×4 array, got {points.dtype} {points.shape}")
    names = [*XYZ, "intensity"][: points.shape[1]]
    return recfunctions.unstructured_to_structured(np.ascontiguousarray(points), names=names)


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


# PLY


def _read_ply(raw: bytes) -> np.ndarray:
    """The vertex element of a PLY file (ascii, binary little- or big-endian)."""
    if not raw.startswith(b"ply"):
        raise _FormatError("not a PLY file: it does not start with 'ply'")
    end = raw.find(b"end_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise _FormatError("not a PLY file: no end_header line")
    body_start = raw.find(b"\n", end) + 1 or len(raw)
    order, elements = _ply_header(raw[:end].decode("ascii", errors="replace"))
    names = [name for name, *_ in elements]
    if "vertex" not in names:
        raise _FormatError("PLY file has no vertex element")
    vertex = names.index("vertex")
    _, count, properties = elements[vertex]
    if any(kind is None for _, kind in properties):
        raise _FormatError("PLY vertex element has a list property; only scalar vertex properties are read")
    dtype = np.dtype([(name, (order or "<") + kind) for name, kind in properties])
    body = raw[body_start:]
    if order is None:
        skip_lines = sum(element_count for _, element_count, _ in elements[:vertex])
        lines = body.split(b"\n", skip_lines + count)[skip_lines : skip_lines + count]
        return _parse_ascii(b" ".join(lines), dtype, count, dtype.names)
    offset = 0
    for element_name, element_count, element_properties in elements[:vertex]:
        if any(kind is None for _, kind in element_properties):
            raise _FormatError(f"PLY element '{element_name}' with list properties comes before vertex")
        offset += element_count * np.dtype([(n, "<" + k) for n, k in element_properties]).itemsize
    needed = offset + count * dtype.itemsize
    if len(body) < needed:
        raise _FormatError(f"truncated: {len(body)} bytes of binary data, expected at least {needed}")
    return np.frombuffer(body, dtype=dtype, count=count, offset=offset).copy()


def _ply_header(text: str) -> tuple[str | None, list[tuple[str, int, list[tuple[str, str | None]]]]]:
    """Byte order ('<', '>', None for ascii) and (name, count, [(property, numpy code or None for lists)])."""
    order: str | None = None
    elements: list[tuple[str, int, list[tuple[str, str | None]]]] = []
    has_format = False
    for line in text.splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            if words[1] not in _PLY_FORMATS:
                raise _FormatError(f"PLY format '{words[1]}' is not one of {', '.join(_PLY_FORMATS)}")
            order, has_format = _PLY_FORMATS[words[1]], True
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1][2].append((words[4], None))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise _FormatError(f"PLY header line '{line.strip()}' is not understood")
    if not has_format:
        raise _FormatError("PLY header has no format line")
    return order, elements


_READERS: dict[str, Callable[[bytes], np.ndarray]] = {
    ".bin": _read_kitti_bin,
    ".npy": _read_npy,
    ".pcd": _read_pcd,
    ".ply": _read_ply,
}
