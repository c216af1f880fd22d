"""LiDAR scan files: .npy, KITTI .bin, PCD (ascii, binary, binary_compressed) and PLY vertices, one module each.

`read_points` returns every field of a file as a numpy structured array, bit for bit;
`read_scan` returns the float32 (N, 3) or (N, 4) x, y, z[, intensity] that the cores use, without the points
whose coordinates are not finite or lie beyond a plausibility bound (default 1 km), and reports how many it
dropped; `read_scan_with_time` adds each kept point's time (point_time.py: a driver's time field, or the azimuth of
a KITTI .bin). A file whose content is another format than its name says (a PCD renamed .bin) is refused.
Malformed or truncated files raise DataError with one line that names the file and the problem.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ssf_common.errors import DataError
from ssf_common.paths import read_input
from ssf_common.scans.common import XYZ, FormatError
from ssf_common.scans.kitti_bin import read_kitti_bin, write_bin
from ssf_common.scans.npy import read_npy
from ssf_common.scans.pcd import PCD_ENCODINGS, lzf_compress, lzf_decompress, read_pcd, write_pcd
from ssf_common.scans.ply import read_ply
from ssf_common.scans.point_time import KITTI_PERIOD_S, PointTime, azimuth_time, point_time
from ssf_common.scans.sniff import sniff

__all__ = [
    "MAX_COORDINATE_M",
    "PCD_ENCODINGS",
    "SUFFIXES",
    "XYZ",
    "KITTI_PERIOD_S",
    "LoadedScan",
    "PointTime",
    "TimedScan",
    "azimuth_time",
    "load_scan",
    "point_time",
    "lzf_compress",
    "lzf_decompress",
    "read_points",
    "read_scan",
    "read_scan_with_time",
    "sniff",
    "write_bin",
    "write_pcd",
]

MAX_COORDINATE_M = 1000.0  # |x|, |y|, |z| beyond this are not LiDAR returns
_READERS: dict[str, Callable[[bytes], np.ndarray]] = {
    ".bin": read_kitti_bin,
    ".npy": read_npy,
    ".pcd": read_pcd,
    ".ply": read_ply,
}
SUFFIXES = tuple(_READERS)


class LoadedScan(NamedTuple):
    """A scan as the cores take it, and what was left out of it."""

    points: np.ndarray  # float32 (N, 3) x, y, z or (N, 4) with intensity
    total: int  # points in the file
    non_finite: int  # dropped: x, y or z NaN or infinite
    too_far: int  # dropped: |x|, |y| or |z| beyond the bound
    max_coordinate: float
    time: np.ndarray | None = None  # float32 (N,) s per kept point, relative to the scan's stamp (for a KITTI .bin,
    # derived from the azimuth: relative to when the sensor faced forward); None: no usable time
    time_source: str = ""  # the time field read, "azimuth" for a KITTI .bin, "" when none
    time_problem: str | None = None  # one line: why a time field the file has gives no time

    @property
    def dropped(self) -> int:
        """Points of the file that are not in `points`."""
        return self.non_finite + self.too_far

    def report(self, source: str | Path) -> str | None:
        """One line on the dropped points, None when every point was kept."""
        if not self.dropped:
            return None
        parts = []
        if self.non_finite:
            parts.append(f"{self.non_finite} with non-finite x/y/z")
        if self.too_far:
            parts.append(f"{self.too_far} beyond {self.max_coordinate:g} m")
        return f"{source}: dropped {self.dropped} of {self.total} points ({', '.join(parts)})"


class TimedScan(NamedTuple):
    """A scan as the cores take it, with the time of each point when the file gives one."""

    points: np.ndarray  # float32 (N, 3) x, y, z or (N, 4) with intensity
    time: np.ndarray | None  # float32 (N,) s relative to the scan's stamp; None: no usable time


def print_warning(text: str) -> None:
    """The default report: one `ssf: warning:` line on stderr."""
    print(f"ssf: warning: {text}", file=sys.stderr, flush=True)


def read_scan(
    path: str | Path,
    *,
    max_coordinate: float = MAX_COORDINATE_M,
    warn: Callable[[str], None] | None = print_warning,
) -> np.ndarray:
    """float32 (N, 3) x, y, z, or (N, 4) with intensity when the file has it; implausible points dropped and
    reported through `warn` (one line; None to stay quiet)."""
    loaded = load_scan(path, max_coordinate=max_coordinate)
    line = loaded.report(path)
    if line and warn is not None:
        warn(line)
    return loaded.points


def read_scan_with_time(
    path: str | Path,
    *,
    max_coordinate: float = MAX_COORDINATE_M,
    sweep_period: float = KITTI_PERIOD_S,
    warn: Callable[[str], None] | None = print_warning,
) -> TimedScan:
    """read_scan and each kept point's time (s, relative to the scan's stamp; a KITTI .bin's from its azimuth over
    `sweep_period`); dropped points and an unusable time field reported through `warn`, one line each."""
    loaded = load_scan(path, max_coordinate=max_coordinate, sweep_period=sweep_period)
    for line in (loaded.report(path), loaded.time_problem and f"{path}: {loaded.time_problem}"):
        if line and warn is not None:
            warn(line)
    return TimedScan(loaded.points, loaded.time)


def load_scan(path: str | Path, *, max_coordinate: float = MAX_COORDINATE_M,
              sweep_period: float = KITTI_PERIOD_S) -> LoadedScan:
    """The scan of a file, the counts of points dropped as non-finite or beyond `max_coordinate` metres, and the time
    of each kept point (a KITTI .bin's derived from its azimuth over `sweep_period` seconds)."""
    path = Path(path)
    if not (max_coordinate > 0):  # also refuses NaN
        raise DataError(f"max_coordinate must be a positive number of metres, got {max_coordinate!r}")
    points = read_points(path)
    names = points.dtype.names
    missing = [name for name in XYZ if name not in names]
    if missing:
        raise DataError(f"{path}: no {'/'.join(missing)} field (fields: {', '.join(names) or 'none'})")
    columns = [*XYZ, "intensity"] if "intensity" in names else list(XYZ)
    for name in columns:
        field = points.dtype.fields[name][0]
        if field.shape:
            raise DataError(f"{path}: field '{name}' has count > 1; expected one value per point")
        if field.kind not in "iuf":
            raise DataError(f"{path}: field '{name}' holds {field} values; expected numbers (int, uint or float)")
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaNs and huge integers are judged below
        xyz = np.stack([points[name].reshape(-1).astype(np.float64) for name in XYZ], axis=1)
    finite = np.isfinite(xyz).all(axis=1)
    with np.errstate(invalid="ignore"):
        near = (np.abs(np.where(finite[:, None], xyz, 0.0)) <= max_coordinate).all(axis=1)
    scan = np.empty((points.size, len(columns)), dtype=np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        for index, name in enumerate(columns):
            scan[:, index] = points[name].reshape(-1)
    near &= np.isfinite(scan[:, :3]).all(axis=1)  # beyond float32 when the bound is off
    keep = finite & near
    if not keep.any():
        raise DataError(
            f"{path}: no point with finite x, y, z within {max_coordinate:g} m ({points.size} points in the file)"
        )
    kept = scan[keep]
    if path.suffix.lower() == ".bin":
        if not (0 < sweep_period <= 1):  # also refuses NaN
            raise DataError(f"sweep_period must be a number of seconds in (0, 1], got {sweep_period!r}")
        timing = PointTime(azimuth_time(kept[:, :3], sweep_period), "azimuth")
    else:
        timing = point_time(points, kept[:, :3], None, np.flatnonzero(keep))
    return LoadedScan(kept, int(points.size), int((~finite).sum()), int((finite & ~near).sum()), max_coordinate,
                      timing.time, timing.source, timing.problem)


def read_points(path: str | Path) -> np.ndarray:
    """Every field of every point of a scan file as a flat structured array, values bit-exact."""
    path = Path(path)
    suffix = path.suffix.lower()
    reader = _READERS.get(suffix)
    if reader is None:
        raise DataError(f"{path}: unsupported scan format '{path.suffix}' (supported: {', '.join(_READERS)})")
    raw = read_input(path, "scan")
    _check_content(path, suffix, raw)
    try:
        return reader(raw)
    except FormatError as err:
        raise DataError(f"{path}: {err}") from None


def _check_content(path: Path, suffix: str, raw: bytes) -> None:
    """Refuse a file whose first bytes say it is something other than its suffix claims."""
    found = sniff(raw)
    if found is None or found == suffix:
        return
    if found in _READERS:
        raise DataError(f"{path}: the content is a {found} file, not {suffix}; rename it to {path.stem}{found}")
    if suffix == ".bin":  # KITTI .bin has no header of its own: any other known content is a mistake
        raise DataError(f"{path}: the content is {found}, not KITTI .bin float32 points")
