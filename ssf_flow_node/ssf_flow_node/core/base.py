"""The estimator interface: scan t, scan t+1 and an optional motion mask in, per-point flow for scan t out."""

from __future__ import annotations

import collections
import hashlib
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from ssf_common.geometry.ground import height_above_ground
from ssf_common.geometry.se3 import rigid_flow
from ssf_flow_node.core.preprocess import PreprocessConfig, Sample, check_mask, check_scan, downsample, propagate_motion


@dataclass(frozen=True)
class FlowResult:
    """Flow for every input point of scan t (its sensor frame) and the ego motion found on the way."""

    flow: np.ndarray  # (N, 3) float32: pc1 + flow lies on pc2's surfaces
    ego: np.ndarray  # (4, 4) float64: maps scan-t coordinates of static points into scan t+1's frame


class FlowEstimator(Protocol):
    """Anything that estimates scene flow between two scans."""

    name: str

    def estimate(self, pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None = None) -> FlowResult:
        """Flow for every point of pc1; mask is an optional per-point dynamic probability for pc1."""
        ...


def get_ready(estimator: FlowEstimator, pc1: np.ndarray, pc2: np.ndarray, measured: np.ndarray | None = None) -> None:
    """Do the work on a pair that does not need its mask (an estimator that keeps such work has `get_ready`), so that
    the mask, when it comes a little later, finds it done (`measured`: see `measured_prior`)."""
    ready = getattr(estimator, "get_ready", None)
    if ready is not None:
        ready(pc1, pc2, **measured_prior(estimator, measured))


def measured_prior(estimator: FlowEstimator, measured: np.ndarray | None) -> dict[str, np.ndarray]:
    """The keyword that hands an estimator the pair's ego motion as the vehicle measured it, where it takes one
    (`takes_measured`: its alignment starts from it and judges by it, in place of the previous pair's motion)."""
    return {"measured": measured} if measured is not None and getattr(estimator, "takes_measured", False) else {}


class PreparedPair(NamedTuple):
    """Validated scans, the points sampled from each and the mask on the sampled points of scan t."""

    pc1: np.ndarray
    pc2: np.ndarray
    sample1: Sample
    sample2: Sample
    mask: np.ndarray | None
    height1: np.ndarray | None = None  # where the ground is split: each point of scan t's height above the ground
    height2: np.ndarray | None = None  # and of scan t+1


class PreparedScan(NamedTuple):
    """One validated scan, its sample, and (where the ground is split) each point's height above the local ground."""

    xyz: np.ndarray
    sample: Sample
    height: np.ndarray | None


def fingerprint(*clouds: np.ndarray) -> bytes:
    """A short digest that tells one scan (or pair of scans) from another: shapes and a stride of their coordinates."""
    digest = hashlib.blake2b(digest_size=16)
    for cloud in clouds:
        array = np.asarray(cloud)
        digest.update(repr(array.shape).encode())
        digest.update(np.ascontiguousarray(array[:: max(1, len(array) // 1024)]).tobytes())
    return digest.digest()


def prepare_scan(points: np.ndarray, name: str, config: PreprocessConfig, key: bytes | None = None) -> PreparedScan:
    """Validate a scan and sample it; the sampling is seeded by the config's seed and the scan itself, so a scan is
    sampled the same way whichever pair it belongs to."""
    xyz = check_scan(points, name)
    key = fingerprint(xyz) if key is None else key
    height = height_above_ground(xyz, config.ground_cell, config.ground_zones) if config.remove_ground else None
    rng = np.random.default_rng([config.seed, int.from_bytes(key[:8], "little")])
    return PreparedScan(xyz, downsample(xyz, config, rng, height), height)


class ScanCache:
    """The last few scans prepared with one config, by content: in a stream, scan t+1 of one pair is scan t of the
    next, and the fusion loop asks for the same pair again, so each scan is validated, split and sampled once."""

    def __init__(self, config: PreprocessConfig, size: int = 3) -> None:
        self.config = config
        self.size = size
        self.scans: collections.OrderedDict[bytes, PreparedScan] = collections.OrderedDict()

    def get(self, points: np.ndarray, name: str) -> PreparedScan:
        """The prepared scan, from the cache when this scan was prepared recently."""
        key = fingerprint(np.asarray(points))
        if key in self.scans:
            self.scans.move_to_end(key)
            return self.scans[key]
        scan = self.scans[key] = prepare_scan(points, name, self.config, key)
        while len(self.scans) > self.size:
            self.scans.popitem(last=False)
        return scan


def prepare(pc1: np.ndarray, pc2: np.ndarray, mask: np.ndarray | None, config: PreprocessConfig,
            cache: ScanCache | None = None) -> PreparedPair:
    """Validate inputs and downsample both scans with the shared pre-processing (through `cache`, made with the same
    config, when given)."""
    if cache is not None:
        scan1, scan2 = cache.get(pc1, "scan t"), cache.get(pc2, "scan t+1")
    else:
        scan1, scan2 = prepare_scan(pc1, "scan t", config), prepare_scan(pc2, "scan t+1", config)
    mask = check_mask(mask, scan1.xyz.shape[0])
    return PreparedPair(scan1.xyz, scan2.xyz, scan1.sample, scan2.sample,
                        None if mask is None else mask[scan1.sample.indices], scan1.height, scan2.height)


def finish(pair: PreparedPair, sample_flow: np.ndarray, ego: np.ndarray, config: PreprocessConfig,
           still: np.ndarray | None = None) -> FlowResult:
    """Flow for every point of scan t: the ego motion, plus the sampled points' motion relative to it carried to
    the points near them (except the `still` ones, e.g. the ground)."""
    ego_flow = rigid_flow(ego, pair.pc1)
    relative = sample_flow.astype(np.float32) - ego_flow[pair.sample1.indices]
    flow = ego_flow + propagate_motion(pair.pc1, pair.sample1, relative, config.propagate_k, config.propagate_radius,
                                       still)
    return FlowResult(flow=flow, ego=np.asarray(ego, dtype=np.float64))
