"""Motion masks as an imperfect segmentation hands them over: ground truth with objects dropped and points flipped."""

from __future__ import annotations

import numpy as np

from ssf_common.dataset.pairs import ScanPair


def noisy_mask(pair: ScanPair, rng: np.random.Generator, flip: float = 0.03, drop: float = 0.1) -> np.ndarray:
    """Ground-truth dynamic mask with a share `drop` of the moving objects missed and `flip` of the points flipped."""
    mask = pair.dynamic1.astype(np.float32)
    moving = np.unique(pair.instance1[pair.dynamic1])
    dropped = moving[rng.random(moving.size) < drop]
    mask[np.isin(pair.instance1, dropped) & pair.dynamic1] = 0.0
    flipped = rng.random(mask.size) < flip
    mask[flipped] = 1.0 - mask[flipped]
    return mask
