"""KITTI-odometry-style sequences: velodyne/*.bin (float32 x, y, z, intensity) plus poses.txt (3x4 rows)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ssf_common import scans
from ssf_common.errors import DataError


def read_poses(path: str | Path) -> np.ndarray:
    """Poses (N, 4, 4) from a KITTI poses.txt: one row of 12 numbers (a 3x4 matrix) per scan."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such poses file")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            values = np.array([float(value) for value in line.split()])
        except ValueError:
            raise DataError(f"{path}:{number}: not a row of numbers") from None
        if values.size != 12 or not np.isfinite(values).all():
            raise DataError(f"{path}:{number}: expected 12 finite numbers (a 3x4 pose), got {values.size}")
        rows.append(values.reshape(3, 4))
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if rows:
        poses[:, :3, :] = np.stack(rows)
    return poses


def write_poses(path: str | Path, poses: np.ndarray) -> None:
    """Write poses (N, 4, 4) as KITTI 3x4 rows."""
    lines = [" ".join(f"{value:.9e}" for value in pose[:3, :].reshape(-1)) for pose in poses]
    try:
        Path(path).write_text("\n".join(lines) + "\n")
    except OSError as err:
        raise DataError(f"{path}: cannot write the poses ({err.strerror})") from None


def write_tum(path: str | Path, stamps_s: np.ndarray, poses: np.ndarray) -> None:
    """Write poses (N, 4, 4) in the TUM trajectory format: one row `timestamp tx ty tz qx qy qz qw` per pose."""
    from scipy.spatial.transform import Rotation

    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    quaternions = Rotation.from_matrix(poses[:, :3, :3]).as_quat() if len(poses) else np.zeros((0, 4))
    lines = [f"{stamp:.9f} " + " ".join(f"{value:.9f}" for value in (*pose[:3, 3], *quaternion))
             for stamp, pose, quaternion in zip(np.asarray(stamps_s, dtype=np.float64), poses, quaternions)]
    try:
        Path(path).write_text("\n".join(lines) + "\n")
    except OSError as err:
        raise DataError(f"{path}: cannot write the trajectory ({err.strerror})") from None


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps (N,) and poses (N, 4, 4) of a TUM trajectory file (`#` comments allowed)."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such trajectory file")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            values = np.array([float(value) for value in line.split()])
        except ValueError:
            raise DataError(f"{path}:{number}: not a row of numbers") from None
        if values.size != 8 or not np.isfinite(values).all():
            raise DataError(f"{path}:{number}: expected 8 finite numbers (timestamp tx ty tz qx qy qz qw)")
        rows.append(values)
    table = np.array(rows).reshape(-1, 8)
    poses = np.tile(np.eye(4), (len(table), 1, 1))
    if len(table):
        poses[:, :3, :3] = Rotation.from_quat(table[:, 4:]).as_matrix()
        poses[:, :3, 3] = table[:, 1:4]
    return table[:, 0], poses


def read_bin(path: str | Path) -> np.ndarray:
    """A KITTI .bin scan as float32 (N, 4): x, y, z, intensity."""
    return scans.read_scan(path)


class KittiSequence:
    """A sequence folder with velodyne/*.bin and poses.txt (poses: world <- sensor of each scan)."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        velodyne = self.folder / "velodyne"
        if not velodyne.is_dir():
            raise DataError(f"{self.folder}: no velodyne/ folder (expected a KITTI odometry sequence)")
        self.scan_paths = sorted(velodyne.glob("*.bin"))
        if not self.scan_paths:
            raise DataError(f"{velodyne}: no .bin scans")
        self.poses = read_poses(self.folder / "poses.txt")
        if len(self.poses) != len(self.scan_paths):
            raise DataError(f"{self.folder}: {len(self.scan_paths)} scans but {len(self.poses)} poses in poses.txt")

    def __len__(self) -> int:
        return len(self.scan_paths)

    def scan(self, index: int) -> np.ndarray:
        """Scan index as float32 (N, 4): x, y, z, intensity in the sensor frame."""
        return read_bin(self.scan_paths[index])

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for index in range(len(self)):
            yield self.scan(index), self.poses[index]


class SequenceWriter:
    """Writes a KITTI odometry sequence: velodyne/NNNNNN.bin per scan, and on close poses.txt of every scan
    relative to the first."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.velodyne = self.folder / "velodyne"
        try:
            self.velodyne.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise DataError(f"{self.folder}: cannot create the sequence folder ({err.strerror})") from None
        self.poses: list[np.ndarray] = []

    def add(self, index: int, points: np.ndarray, intensity: np.ndarray, pose: np.ndarray) -> None:
        """Write scan `index` (sensor frame) taken at `pose` (world <- sensor)."""
        scans.write_bin(self.velodyne / f"{index:06d}.bin", np.c_[points, intensity])
        self.poses.append(np.asarray(pose, dtype=np.float64))

    def close(self) -> np.ndarray:
        """Write poses.txt; return the first scan's world pose (the sequence's origin)."""
        if not self.poses:
            raise DataError(f"{self.folder}: no scans were written")
        origin = self.poses[0]
        write_poses(self.folder / "poses.txt", np.linalg.inv(origin) @ np.stack(self.poses))
        return origin
