"""Estimates cached beside exported pairs: an estimator's flow for scan t of `NAME.npz`, as `NAME.flow_EST.npy`
(float32 (N, 3)). The pair itself stays what was exported; several estimators' flows can sit side by side."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ssf_common.errors import DataError


def flow_estimate_path(pair_path: str | Path, estimator: str) -> Path:
    """Where the flow of `estimator` for the pair at pair_path is cached."""
    pair_path = Path(pair_path)
    return pair_path.with_name(f"{pair_path.stem}.flow_{estimator}.npy")


def write_flow_estimate(pair_path: str | Path, estimator: str, flow: np.ndarray) -> Path:
    """Cache an estimated flow beside its pair (atomically: a temporary file, then a rename)."""
    path = flow_estimate_path(pair_path, estimator)
    temporary = path.with_name(path.name + ".tmp")
    try:
        with temporary.open("wb") as handle:
            np.save(handle, np.ascontiguousarray(flow, dtype=np.float32))
        temporary.replace(path)
    except OSError as err:
        raise DataError(f"{path}: cannot write the flow estimate ({err.strerror})") from None
    return path


def read_flow_estimate(pair_path: str | Path, estimator: str, count: int) -> np.ndarray:
    """The cached flow (count, 3) of a pair; one DataError line when it is missing or does not fit."""
    path = flow_estimate_path(pair_path, estimator)
    if not path.is_file():
        raise DataError(f"{path}: no cached '{estimator}' flow beside the pair "
                        f"(write it with `ssf train seg-flow --data {Path(pair_path).parent} --estimator {estimator}`)")
    try:
        flow = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        raise DataError(f"{path}: not a readable flow estimate ({err})") from None
    if flow.shape != (count, 3) or flow.dtype.kind != "f" or not np.isfinite(flow).all():
        raise DataError(f"{path}: expected finite floats of shape ({count}, 3), got {flow.dtype} {flow.shape}")
    return flow.astype(np.float32)
