"""Labelled scan pairs: the record every evaluation and training step uses, and the exported .npz reader."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator, NamedTuple

import numpy as np

from ssf_common.errors import DataError


class FlowPair(NamedTuple):
    """Two scans (each in its own sensor frame) with ground-truth flow for scan t (ego motion included)."""

    pc1: np.ndarray  # (N, 3) float32
    pc2: np.ndarray  # (M, 3) float32
    flow: np.ndarray  # (N, 3) float32: pc1 + flow lies on pc2's surfaces
    dynamic1: np.ndarray  # (N,) bool
    instance1: np.ndarray  # (N,) int32, 0 = static scene
    ego: np.ndarray  # (4, 4): scan-t coordinates of static points -> scan t+1's frame
    mask1: np.ndarray | None = None  # (N,) float32 dynamic probability from a segmentation, when exported


def ego_from_poses(pose1: np.ndarray, pose2: np.ndarray) -> np.ndarray:
    """T = pose2^-1 pose1 for world <- sensor poses."""
    return np.linalg.inv(np.asarray(pose2, dtype=np.float64)) @ np.asarray(pose1, dtype=np.float64)


def as_flow_pair(record: Any) -> FlowPair:
    """Adapt any record with the exporter's fields (pc1, pc2, flow, dynamic1, pose1, pose2, ...) to a FlowPair."""
    get = record.get if isinstance(record, dict) else lambda key, default=None: getattr(record, key, default)
    pc1 = np.asarray(get("pc1"), dtype=np.float32)[:, :3]
    flow = np.asarray(get("flow"), dtype=np.float32)
    dynamic = get("dynamic1")
    instance = get("instance1")
    pose1, pose2 = get("pose1"), get("pose2")
    mask = get("mask1", None)
    return FlowPair(
        pc1=np.ascontiguousarray(pc1),
        pc2=np.ascontiguousarray(np.asarray(get("pc2"), dtype=np.float32)[:, :3]),
        flow=flow,
        dynamic1=np.zeros(len(pc1), bool) if dynamic is None else np.asarray(dynamic).astype(bool),
        instance1=np.zeros(len(pc1), np.int32) if instance is None else np.asarray(instance).astype(np.int32),
        ego=np.eye(4) if pose1 is None or pose2 is None else ego_from_poses(pose1, pose2),
        mask1=None if mask is None else np.asarray(mask, dtype=np.float32),
    )


def read_pair(path: Path) -> FlowPair:
    """Read one exported pair (.npz with pc1, pc2, flow, dynamic1, ...), checking shapes."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            record = {key: archive[key] for key in archive.files}
    except (OSError, ValueError, EOFError) as err:
        raise DataError(f"{path}: not a readable .npz pair ({err})") from None
    missing = [key for key in ("pc1", "pc2", "flow") if key not in record]
    if missing:
        raise DataError(f"{path}: missing {', '.join(missing)} (expected an exported pair)")
    pair = as_flow_pair(record)
    count = pair.pc1.shape[0]
    if pair.flow.shape != (count, 3) or pair.dynamic1.shape != (count,) or pair.pc2.ndim != 2:
        raise DataError(f"{path}: pc1 {pair.pc1.shape}, flow {pair.flow.shape} and dynamic1 {pair.dynamic1.shape} do not match")
    if not (np.isfinite(pair.pc1).all() and np.isfinite(pair.pc2).all() and np.isfinite(pair.flow).all()):
        raise DataError(f"{path}: NaN/Inf values in points or flow")
    return pair


def pair_files(directory: Path) -> list[Path]:
    """The .npz pairs of an export directory (searched recursively), sorted."""
    if not directory.is_dir():
        raise DataError(f"{directory}: no such directory of exported pairs")
    files = sorted(directory.rglob("*.npz"))
    if not files:
        raise DataError(f"{directory}: holds no .npz pairs (export some with `ssf dataset export`)")
    return files


def read_pairs(directory: Path) -> Iterator[FlowPair]:
    """Every pair of an export directory."""
    for path in pair_files(directory):
        yield read_pair(path)


def noisy_mask(pair: FlowPair, rng: np.random.Generator, flip: float = 0.03, drop: float = 0.1) -> np.ndarray:
    """A motion mask as an imperfect segmentation gives it: ground truth, moving objects dropped, points flipped."""
    mask = pair.dynamic1.astype(np.float32)
    moving = np.unique(pair.instance1[pair.dynamic1])
    dropped = moving[rng.random(moving.size) < drop]
    mask[np.isin(pair.instance1, dropped) & pair.dynamic1] = 0.0
    flipped = rng.random(mask.size) < flip
    mask[flipped] = 1.0 - mask[flipped]
    return mask
