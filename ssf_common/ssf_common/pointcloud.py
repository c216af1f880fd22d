"""sensor_msgs/PointCloud2 <-> numpy for any field layout, without Python lists.

A cloud's fields become one numpy structured dtype (names, formats, offsets, itemsize = point_step),
so unaligned layouts (Velodyne XYZIRT, point_step 22), padding, count > 1, big-endian data and
row padding (row_step > width * point_step) are all read as zero-copy views of the message bytes.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple, overload

import numpy as np

from ssf_common import messages
from ssf_common.errors import MessageError
from ssf_common.scans.point_time import point_time

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POINTFIELD = "sensor_msgs/msg/PointField"

# PointField datatype -> numpy type code (byte order added per cloud).
DATATYPE_CODES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_DATATYPE_OF_CODE = {code: datatype for datatype, code in DATATYPE_CODES.items()}
XYZ = ("x", "y", "z")


class DecodedCloud(NamedTuple):
    """A validated cloud: finite xyz, where those points sit in the message, every field, and per-point time."""

    xyz: np.ndarray  # float32 (N, 3), points with finite coordinates only
    indices: np.ndarray  # int64 (N,), index of each kept point in `points`
    points: np.ndarray  # structured (height * width,), all fields of all points
    time: np.ndarray | None = None  # float32 (N,) s relative to the header stamp, from a driver's time field
    # (scans.point_time: velodyne `time`, ouster `t`, Hesai/nebula `timestamp`/`time_stamp`, Livox `offset_time`);
    # None: no field, an instant sweep (all 0), or an unusable one
    time_problem: str | None = None  # one line: why a time field the cloud has gives no time


def cloud_dtype(msg: Any) -> np.dtype:
    """Structured dtype of one point: field names, types, offsets and itemsize = point_step."""
    point_step = int(msg.point_step)
    if not 0 < point_step < 2**31:  # numpy's itemsize is a C int
        raise MessageError(f"PointCloud2 point_step is {point_step}; it must be positive and below 2**31")
    order = ">" if msg.is_bigendian else "<"
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    for field in msg.fields:
        name, offset, datatype, count = str(field.name), int(field.offset), int(field.datatype), int(field.count)
        if not name:
            raise MessageError(f"PointCloud2 has a field without a name at offset {offset}")
        if name in names:
            raise MessageError(f"PointCloud2 field '{name}' appears twice")
        if datatype not in DATATYPE_CODES:
            raise MessageError(f"PointCloud2 field '{name}' has unknown datatype {datatype} (known: 1..8)")
        if count < 1:
            raise MessageError(f"PointCloud2 field '{name}' has count {count}; it must be at least 1")
        base = np.dtype(order + DATATYPE_CODES[datatype])
        if offset < 0 or offset + base.itemsize * count > point_step:
            raise MessageError(
                f"PointCloud2 field '{name}' (offset {offset}, {base.itemsize * count} bytes) "
                f"lies outside point_step {point_step}"
            )
        names.append(name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(offset)
    _check_no_overlap(names, formats, offsets)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def _check_no_overlap(names: list[str], formats: list[Any], offsets: list[int]) -> None:
    """Raise MessageError when two fields share bytes."""
    spans = sorted(
        (offset, offset + np.dtype(fmt).itemsize, name) for name, fmt, offset in zip(names, formats, offsets)
    )
    for (start_a, end_a, name_a), (start_b, _, name_b) in zip(spans, spans[1:]):
        if start_b < end_a:
            raise MessageError(
                f"PointCloud2 fields '{name_a}' (bytes {start_a}..{end_a - 1}) and '{name_b}' "
                f"(from byte {start_b}) overlap"
            )


def _data_bytes(msg: Any) -> np.ndarray:
    """The message's data as a flat uint8 array, without copying when it is already a buffer."""
    data = msg.data
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise MessageError(f"PointCloud2 data has dtype {data.dtype}; it must be uint8")
        return data.reshape(-1)
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:
        pass
    try:
        return np.asarray(data, dtype=np.uint8).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise MessageError(f"PointCloud2 data of type {type(data).__name__} is not a sequence of bytes") from None


def cloud_to_array(msg: Any, *, organized: bool = False) -> np.ndarray:
    """Structured array of all points: (height * width,), or (height, width) when organized.

    A view of the message bytes (no copy) unless rows are padded and a flat array is asked for.
    """
    dtype = cloud_dtype(msg)
    height, width = int(msg.height), int(msg.width)
    row_step, point_step = int(msg.row_step), int(msg.point_step)
    if height < 0 or width < 0:
        raise MessageError(f"PointCloud2 has negative size height {height} × width {width}")
    data = _data_bytes(msg)
    if height * width == 0:
        return np.empty((height, width) if organized else 0, dtype=dtype)
    if row_step < width * point_step:
        raise MessageError(
            f"PointCloud2 row_step {row_step} is smaller than width {width} × point_step {point_step}"
        )
    if data.size != height * row_step:
        raise MessageError(
            f"PointCloud2 data holds {data.size} bytes, expected height {height} × row_step {row_step} "
            f"= {height * row_step}"
        )
    rows = data.reshape(height, row_step)[:, : width * point_step]
    points = rows.view(dtype)
    return points if organized else points.reshape(-1)


def _xyz_view(points: np.ndarray) -> np.ndarray:
    """x, y, z of a structured array as float32 (..., 3)."""
    missing = [name for name in XYZ if name not in (points.dtype.names or ())]
    if missing:
        present = ", ".join(points.dtype.names or ()) or "none"
        raise MessageError(f"PointCloud2 has no {'/'.join(missing)} field (fields: {present})")
    for name in XYZ:
        if points.dtype.fields[name][0].shape:
            raise MessageError(f"PointCloud2 field '{name}' has count > 1; x, y and z must be single values")
    xyz = np.empty(points.shape + (3,), dtype=np.float32)
    for axis, name in enumerate(XYZ):
        xyz[..., axis] = points[name]
    return xyz


@overload
def cloud_xyz(msg: Any, *, skip_nans: bool = True, with_indices: Literal[False] = False) -> np.ndarray: ...
@overload
def cloud_xyz(msg: Any, *, skip_nans: bool = True, with_indices: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...
def cloud_xyz(msg: Any, *, skip_nans: bool = True, with_indices: bool = False):
    """Coordinates as float32 (N, 3); without points whose x, y or z is NaN/Inf when skip_nans.

    with_indices=True also returns the int64 index of each kept point in the flat cloud.
    """
    xyz = _xyz_view(cloud_to_array(msg, organized=True)).reshape(-1, 3)
    if skip_nans and not np.isfinite(xyz).all():
        finite = _finite_rows(xyz)
        return (xyz[finite], np.flatnonzero(finite)) if with_indices else xyz[finite]
    return (xyz, np.arange(len(xyz), dtype=np.int64)) if with_indices else xyz


def _finite_rows(xyz: np.ndarray) -> np.ndarray:
    """Boolean mask of rows whose three coordinates are finite."""
    return np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1]) & np.isfinite(xyz[:, 2])


def validate_cloud(msg: Any) -> None:
    """Raise MessageError naming the problem when a cloud cannot serve as a scan."""
    decode_cloud(msg)


def decode_cloud(msg: Any) -> DecodedCloud:
    """Validate a scan-like cloud and return its finite points, their indices and all fields."""
    organized = cloud_to_array(msg, organized=True)
    points = organized.reshape(-1)
    if points.size == 0:
        raise MessageError(f"PointCloud2 is empty (height {msg.height} × width {msg.width})")
    xyz = _xyz_view(organized).reshape(-1, 3)
    if np.isfinite(xyz).all():
        return _with_time(msg, DecodedCloud(xyz, np.arange(len(xyz), dtype=np.int64), points), every_point=True)
    indices = np.flatnonzero(_finite_rows(xyz))
    if indices.size == 0:
        raise MessageError(f"PointCloud2 has no valid point: all {len(xyz)} points have NaN/Inf coordinates")
    return _with_time(msg, DecodedCloud(xyz[indices], indices, points), every_point=False)


def _with_time(msg: Any, decoded: DecodedCloud, every_point: bool) -> DecodedCloud:
    """The decoded cloud with the per-point time of its kept points, relative to the header stamp."""
    header = getattr(msg, "header", None)
    stamp_ns = messages.stamp_ns(header.stamp) if header is not None else None
    timing = point_time(decoded.points, decoded.xyz, stamp_ns, None if every_point else decoded.indices)
    return decoded._replace(time=timing.time, time_problem=timing.problem)


def array_to_cloud(arr: np.ndarray, header: Any, *, is_dense: bool | None = None) -> Any:
    """PointCloud2 from a structured array, (N,) or organized (H, W); its data shares arr's memory when contiguous.

    Field layout (offsets, padding, itemsize) is kept as it is in arr.dtype. is_dense defaults to
    whether every x, y, z is finite.
    """
    if arr.dtype.names is None:
        raise MessageError(f"array_to_cloud needs a structured array, got dtype {arr.dtype}")
    if arr.ndim not in (1, 2):
        raise MessageError(f"array_to_cloud needs a (N,) or (H, W) array, got shape {arr.shape}")
    arr = _with_one_byte_order(arr)
    height, width = (1, arr.shape[0]) if arr.ndim == 1 else arr.shape
    fields, big_endian = _point_fields(arr.dtype)
    if is_dense is None:
        is_dense = all(bool(np.isfinite(arr[name]).all()) for name in XYZ if name in arr.dtype.names)
    data = np.ascontiguousarray(arr).reshape(-1).view(np.uint8)
    return messages.msg_type(POINTCLOUD2)(
        header=header,
        height=height,
        width=width,
        fields=fields,
        is_bigendian=big_endian,
        point_step=arr.dtype.itemsize,
        row_step=width * arr.dtype.itemsize,
        data=data,
        is_dense=bool(is_dense),
    )


def _field_base(dtype: np.dtype, name: str) -> tuple[np.dtype, int]:
    """Scalar type and element count of one field of a structured dtype."""
    field_dtype = dtype.fields[name][0]
    base, shape = field_dtype.subdtype if field_dtype.subdtype else (field_dtype, ())
    if base.names is not None or f"{base.kind}{base.itemsize}" not in _DATATYPE_OF_CODE:
        raise MessageError(
            f"field '{name}' has dtype {base}, which a PointField cannot carry (8-32 bit integers, float32/64)"
        )
    return base, int(np.prod(shape, dtype=np.int64))


def _is_big(base: np.dtype) -> bool:
    """Whether a multi-byte scalar type is stored big-endian."""
    return base.itemsize > 1 and (base.byteorder == ">" or (base.byteorder == "=" and not np.little_endian))


def _with_one_byte_order(arr: np.ndarray) -> np.ndarray:
    """arr unchanged when all fields share one byte order, else converted to little-endian."""
    bases = [_field_base(arr.dtype, name)[0] for name in arr.dtype.names]
    if len({_is_big(base) for base in bases if base.itemsize > 1}) <= 1:
        return arr
    return arr.astype(arr.dtype.newbyteorder("<"))


def _point_fields(dtype: np.dtype) -> tuple[list[Any], bool]:
    """PointField list of a structured dtype and whether it is big-endian."""
    point_field = messages.msg_type(POINTFIELD)
    fields = []
    big_endian = False
    for name in dtype.names:
        base, count = _field_base(dtype, name)
        big_endian |= _is_big(base)
        datatype = _DATATYPE_OF_CODE[base.kind + str(base.itemsize)]
        fields.append(point_field(name=name, offset=int(dtype.fields[name][1]), datatype=datatype, count=count))
    return fields, big_endian


def xyz_to_cloud(xyz: np.ndarray, header: Any, **extra_fields: np.ndarray) -> Any:
    """PointCloud2 with float32 x, y, z plus per-point fields (e.g. flow_x=..., label=..., instance=...).

    xyz is (N, 3) or organized (H, W, 3); each extra field has shape xyz.shape[:-1], or one more axis
    for a field with count > 1. Types are kept where PointField can carry them; bool becomes uint8,
    int64/uint64 become int32/uint32 when their values fit, float16 becomes float32.
    """
    xyz = np.asarray(xyz)
    if xyz.ndim not in (2, 3) or xyz.shape[-1] != 3:
        raise MessageError(f"xyz_to_cloud needs xyz of shape (N, 3) or (H, W, 3), got {xyz.shape}")
    shape = xyz.shape[:-1]
    columns = {name: _carriable(name, np.asarray(values), shape) for name, values in extra_fields.items()}
    clash = set(columns) & set(XYZ)
    if clash:
        raise MessageError(f"xyz_to_cloud: extra field {sorted(clash)[0]!r} clashes with the coordinates")
    layout = [(name, np.float32) for name in XYZ]
    layout += [(name, values.dtype, values.shape[len(shape):]) for name, values in columns.items()]
    dtype = np.dtype(layout, align=True)
    packed = sum(dtype.fields[name][0].itemsize for name in dtype.names) == dtype.itemsize
    arr = (np.empty if packed else np.zeros)(shape, dtype=dtype)  # no stray bytes in the padding
    for axis, name in enumerate(XYZ):
        arr[name] = xyz[..., axis]
    for name, values in columns.items():
        arr[name] = values
    return array_to_cloud(arr, header)


def _carriable(name: str, values: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """values converted to a type PointField can carry, checked against the cloud's shape."""
    if values.shape[: len(shape)] != shape or values.ndim > len(shape) + 1:
        raise MessageError(f"field '{name}' has shape {values.shape}; expected {shape} or {shape} + (count,)")
    kind, size = values.dtype.kind, values.dtype.itemsize
    if kind == "b":
        return values.astype(np.uint8)
    if kind == "f" and size == 2:
        return values.astype(np.float32)
    if kind in "iu" and size == 8:
        narrow = np.dtype(kind + "4")
        info = np.iinfo(narrow)
        if values.size and (values.min() < info.min or values.max() > info.max):
            raise MessageError(f"field '{name}' has values outside {narrow}; PointField has no 64-bit integers")
        return values.astype(narrow)
    if kind not in "iuf" or (kind + str(size)) not in _DATATYPE_OF_CODE:
        raise MessageError(f"field '{name}' has dtype {values.dtype}, which a PointField cannot carry")
    return values
