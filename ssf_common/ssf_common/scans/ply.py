"""PLY scans: the vertex element of an ascii, binary little-endian or binary big-endian file."""

from __future__ import annotations

import numpy as np

from ssf_common.scans.common import MAX_HEADER_BYTES, FormatError, parse_ascii

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def read_ply(raw: bytes) -> np.ndarray:
    """The vertex element of a PLY file (ascii, binary little- or big-endian)."""
    if not raw.startswith(b"ply"):
        raise FormatError("not a PLY file: it does not start with 'ply'")
    end = raw.find(b"end_header", 0, MAX_HEADER_BYTES)
    if end < 0:
        raise FormatError("not a PLY file: no end_header line")
    body_start = raw.find(b"\n", end) + 1 or len(raw)
    order, elements = _ply_header(raw[:end].decode("ascii", errors="replace"))
    names = [name for name, *_ in elements]
    if "vertex" not in names:
        raise FormatError("PLY file has no vertex element")
    vertex = names.index("vertex")
    _, count, properties = elements[vertex]
    if any(kind is None for _, kind in properties):
        raise FormatError("PLY vertex element has a list property; only scalar vertex properties are read")
    if not properties:
        raise FormatError("PLY vertex element has no properties")
    dtype = _element_dtype(properties, order or "<")
    body = raw[body_start:]
    if order is None:
        skip_lines = sum(element_count for _, element_count, _ in elements[:vertex])
        held = body.count(b"\n") + 1
        if skip_lines + count > held:
            raise FormatError(f"truncated: {held} lines of ASCII data, the header promises {skip_lines + count}")
        lines = body.split(b"\n", skip_lines + count)[skip_lines : skip_lines + count]
        return parse_ascii(b" ".join(lines), dtype, count, dtype.names)
    offset = 0
    for element_name, element_count, element_properties in elements[:vertex]:
        if any(kind is None for _, kind in element_properties):
            raise FormatError(f"PLY element '{element_name}' with list properties comes before vertex")
        offset += element_count * _element_dtype(element_properties, "<").itemsize
    needed = offset + count * dtype.itemsize
    if len(body) < needed:
        raise FormatError(f"truncated: {len(body)} bytes of binary data, expected at least {needed}")
    return np.frombuffer(body, dtype=dtype, count=count, offset=offset).copy()


def _element_dtype(properties: list[tuple[str, str | None]], order: str) -> np.dtype:
    names = [name for name, _ in properties]
    if len(set(names)) != len(names):
        raise FormatError(f"PLY element repeats a property name ({' '.join(names)})")
    return np.dtype([(name, order + kind) for name, kind in properties])


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
                raise FormatError(f"PLY format '{words[1]}' is not one of {', '.join(_PLY_FORMATS)}")
            order, has_format = _PLY_FORMATS[words[1]], True
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1][2].append((words[4], None))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise FormatError(f"PLY header line '{line.strip()}' is not understood")
    if not has_format:
        raise FormatError("PLY header has no format line")
    return order, elements
