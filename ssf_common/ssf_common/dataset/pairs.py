"""Scan pairs with exact ground truth: the one record every consumer uses (flow, segmentation, odometry, training),
written by the simulator's export and read back here, as `.npz` files of named arrays."""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, fields, replace
from enum import IntEnum
from pathlib import Path

import numpy as np

from ssf_common.errors import DataError
from ssf_common.geometry.se3 import relative_pose
from ssf_common.records import Obstacles



class PointClass(IntEnum):
    """Semantic class of a LiDAR point (and of the surface it hit)."""

    GROUND = 0
    BUILDING = 1
    POLE = 2
    VEGETATION = 3
    PARKED_CAR = 4
    VEHICLE = 5
    PEDESTRIAN = 6
    UNKNOWN = 255  # nobody labelled it


@dataclass(frozen=True)
class ScanPair:
    """Two consecutive scans, each in its own sensor frame, with the exact flow and labels of scan t.

    pc1 + flow lies on the surfaces seen in pc2 (ego motion included, the FlowNet3D / Argoverse 2 convention)."""

    pc1: np.ndarray  # (N, 3) float32, scan t
    pc2: np.ndarray  # (M, 3) float32, scan t+1
    flow: np.ndarray  # (N, 3) float32
    dynamic1: np.ndarray  # (N,) bool, point on an object that moved
    instance1: np.ndarray  # (N,) int32, object id, 0 = static scene
    class1: np.ndarray  # (N,) uint8 PointClass
    pose1: np.ndarray  # (4, 4) float64, world <- sensor at t
    pose2: np.ndarray  # (4, 4) float64, world <- sensor at t+1
    mask1: np.ndarray | None = None  # (N,) float32 dynamic probability from a segmentation, when one was stored
    boxes1: np.ndarray | None = None  # (M, 11) float64 true objects at t in scan t's frame: BOX_COLUMNS
    time1: np.ndarray | None = None  # (N,) float32 each point's time, s relative to scan t's stamp (None: instant)
    time2: np.ndarray | None = None  # (M,) float32 the same for scan t+1
    measured: np.ndarray | None = None  # (4, 4) float64 the sensor's motion over scan t+1's sweep as the vehicle
    # measured it (wheel speed, gyro), scan t's frame -> scan t+1's as `ego`; None: not measured

    @property
    def objects1(self) -> Obstacles | None:
        """The true objects at time t (boxes1) as obstacles in scan t's frame, when the pair has them."""
        return None if self.boxes1 is None else obstacles_from_boxes(self.boxes1)

    @property
    def ego(self) -> np.ndarray:
        """The ego motion: maps scan-t coordinates of static points into scan t+1's frame."""
        return relative_pose(self.pose1, self.pose2)

    def with_mask(self, mask: np.ndarray | None) -> ScanPair:
        """The same pair carrying another stored mask."""
        return replace(self, mask1=None if mask is None else np.asarray(mask, dtype=np.float32))


# boxes1 columns: instance id (as in instance1), kind (ObstacleKind), centre, size, yaw, velocity (m/s, scan t's axes)
BOX_COLUMNS = ("id", "kind", "x", "y", "z", "length", "width", "height", "yaw", "vx", "vy", "vz")


def boxes_from_obstacles(obstacles: Obstacles) -> np.ndarray:
    """(M, 12) boxes1 rows of obstacles."""
    return np.column_stack([obstacles.ids, obstacles.kinds, obstacles.centres, obstacles.sizes, obstacles.yaws,
                            obstacles.velocities]).astype(np.float64).reshape(-1, len(BOX_COLUMNS))


def obstacles_from_boxes(boxes: np.ndarray, frame_id: str = "sensor") -> Obstacles:
    """Obstacles of (M, 12) boxes1 rows."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, len(BOX_COLUMNS))
    return Obstacles(0, frame_id, ids=boxes[:, 0].astype(np.int64), kinds=boxes[:, 1].astype(np.uint8),
                     centres=boxes[:, 2:5], sizes=boxes[:, 5:8], yaws=boxes[:, 8], velocities=boxes[:, 9:12])


REQUIRED_KEYS = ("pc1", "pc2", "flow")
PAIR_KEYS = tuple(field.name for field in fields(ScanPair))


def make_pair(pc1: np.ndarray, pc2: np.ndarray, flow: np.ndarray, dynamic1: np.ndarray | None = None,
              instance1: np.ndarray | None = None, class1: np.ndarray | None = None, pose1: np.ndarray | None = None,
              pose2: np.ndarray | None = None, mask1: np.ndarray | None = None,
              boxes1: np.ndarray | None = None, time1: np.ndarray | None = None,
              time2: np.ndarray | None = None, measured: np.ndarray | None = None) -> ScanPair:
    """A ScanPair with canonical dtypes; missing labels are static, unknown class, identity poses, instant sweeps."""
    pc1 = np.ascontiguousarray(np.asarray(pc1)[:, :3], dtype=np.float32)
    count = pc1.shape[0]
    return ScanPair(
        pc1=pc1,
        pc2=np.ascontiguousarray(np.asarray(pc2)[:, :3], dtype=np.float32),
        flow=np.ascontiguousarray(flow, dtype=np.float32),
        dynamic1=np.zeros(count, bool) if dynamic1 is None else np.asarray(dynamic1).astype(bool),
        instance1=np.zeros(count, np.int32) if instance1 is None else np.asarray(instance1).astype(np.int32),
        class1=np.full(count, PointClass.UNKNOWN, np.uint8) if class1 is None else np.asarray(class1).astype(np.uint8),
        pose1=np.eye(4) if pose1 is None else np.asarray(pose1, dtype=np.float64),
        pose2=np.eye(4) if pose2 is None else np.asarray(pose2, dtype=np.float64),
        mask1=None if mask1 is None else np.asarray(mask1, dtype=np.float32),
        boxes1=None if boxes1 is None else np.asarray(boxes1, dtype=np.float64).reshape(-1, len(BOX_COLUMNS)),
        time1=None if time1 is None else np.asarray(time1, dtype=np.float32).reshape(-1),
        time2=None if time2 is None else np.asarray(time2, dtype=np.float32).reshape(-1),
        measured=None if measured is None else np.asarray(measured, dtype=np.float64).reshape(4, 4),
    )


def write_pair(path: str | Path, pair: ScanPair) -> Path:
    """Write one pair as an uncompressed .npz of its named arrays (mask1 only when present)."""
    path = Path(path)
    arrays = {key: getattr(pair, key) for key in PAIR_KEYS if getattr(pair, key) is not None}
    try:
        with path.open("wb") as handle:
            np.savez(handle, **arrays)
    except OSError as err:
        raise DataError(f"{path}: cannot write the pair ({err.strerror})") from None
    return path


_SHAPES = {"pc1": ("N", 3), "pc2": (None, 3), "flow": ("N", 3), "dynamic1": ("N",), "instance1": ("N",),
           "class1": ("N",), "pose1": (4, 4), "pose2": (4, 4), "mask1": ("N",), "boxes1": (None, len(BOX_COLUMNS)),
           "time1": ("N",), "time2": (None,), "measured": (4, 4)}
_KINDS = {"pc1": "f", "pc2": "f", "flow": "f", "pose1": "f", "pose2": "f", "mask1": "f", "boxes1": "f", "time1": "f", "time2": "f",
          "measured": "f", "dynamic1": "biu", "instance1": "iu", "class1": "iu"}


_KIND_NAMES = {"f": "floats", "biu": "booleans or integers", "iu": "integers"}


def read_pair(path: str | Path) -> ScanPair:
    """Read one pair, checking keys, dtypes, shapes and finiteness; one DataError line on anything wrong."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files if key in _SHAPES}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise DataError(f"{path}: not a readable .npz pair ({err})") from None
    missing = [key for key in REQUIRED_KEYS if key not in arrays]
    if missing:
        raise DataError(f"{path}: missing keys {', '.join(missing)} (expected an exported pair)")
    count = len(arrays["pc1"]) if arrays["pc1"].ndim else -1
    for key, array in arrays.items():
        if array.dtype.kind not in _KINDS[key]:
            raise DataError(f"{path}: '{key}' holds {array.dtype} values, expected {_KIND_NAMES[_KINDS[key]]}")
        shape = _SHAPES[key]
        if array.ndim != len(shape) or any(want is not None and (count if want == "N" else want) != got
                                           for want, got in zip(shape, array.shape)):
            expected = tuple("N" if want is None else want for want in shape)
            raise DataError(f"{path}: '{key}' has shape {array.shape}, expected {expected} with N = {count}")
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise DataError(f"{path}: '{key}' holds NaN or Inf")
    if "time2" in arrays and len(arrays["time2"]) != len(arrays["pc2"]):
        raise DataError(f"{path}: 'time2' has {len(arrays['time2'])} values for {len(arrays['pc2'])} points of pc2")
    mask = arrays.get("mask1")
    if mask is not None and (mask.min(initial=0.0) < 0.0 or mask.max(initial=0.0) > 1.0):
        raise DataError(f"{path}: 'mask1' must hold probabilities in [0, 1]")
    return make_pair(**arrays)


def pair_files(folder: str | Path) -> list[Path]:
    """The .npz pairs of an export folder (the folder itself, its pairs/ subfolder, or anywhere below), sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder of exported pairs")
    files = sorted(folder.glob("*.npz")) or sorted((folder / "pairs").glob("*.npz")) or sorted(folder.rglob("*.npz"))
    if not files:
        raise DataError(f"{folder}: holds no .npz pairs (export some with `ssf dataset export`)")
    return files


def read_pairs(folder: str | Path) -> Iterator[ScanPair]:
    """Every pair of an export folder, in order."""
    for path in pair_files(folder):
        yield read_pair(path)
