"""Frame pairs with exact scene-flow ground truth from the simulator, written as .npz plus a KITTI sequence."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Literal

import numpy as np

from sim_bridge.dataset.kitti import write_bin, write_poses
from sim_bridge.scenario import Scenario, load_scenario
from sim_bridge.simulator import Frame, Simulator
from sim_bridge.world import PointClass
from pydantic import Field

from ssf_common.config import Section, build, dump
from ssf_common.errors import ConfigError, DataError

Sampling = Literal["random", "fps"]


class PairProtocol(Section):
    """How a pair is cut from two full scans: range crop, ground removal, then N points per scan."""

    points: int = Field(8192, ge=1, description="points per scan")
    sampling: Sampling = "random"
    max_range: float | None = Field(35.0, gt=0.0, description="points farther from the sensor are dropped (m); null keeps all")
    drop_ground: bool = Field(True, description="drop points on the ground (ground-truth class) before sampling")


PROTOCOLS = {
    # the scene-flow benchmarks' KITTI protocol (FlowNet3D onwards): ground removed, 35 m, 8192 points
    "paper": PairProtocol(),
    # whole scans, ground and all, as the node sees them
    "raw": PairProtocol(max_range=None, drop_ground=False),
}


def pair_protocol(name: str = "paper", **overrides) -> PairProtocol:
    """A named protocol with some fields replaced (None values are ignored)."""
    if name not in PROTOCOLS:
        raise ConfigError(f"unknown pair protocol '{name}'; choose one of {', '.join(PROTOCOLS)}")
    changes = {key: value for key, value in overrides.items() if value is not None}
    return build(PairProtocol, {**PROTOCOLS[name].model_dump(), **changes})


PAIR_KEYS = ("pc1", "pc2", "flow", "instance1", "class1", "dynamic1", "pose1", "pose2")


@dataclass(frozen=True)
class FramePair:
    """Consecutive scans, each in its own sensor frame, and the exact flow of pc1 (pc1 + flow lies on pc2)."""

    pc1: np.ndarray  # (N, 3) float32
    pc2: np.ndarray  # (M, 3) float32
    flow: np.ndarray  # (N, 3) float32
    instance1: np.ndarray  # (N,) int32, agent id or 0
    class1: np.ndarray  # (N,) uint8 PointClass
    dynamic1: np.ndarray  # (N,) bool
    pose1: np.ndarray  # (4, 4) world <- sensor at t
    pose2: np.ndarray  # (4, 4) world <- sensor at t+1


def sample_indices(points: np.ndarray, count: int, rng: np.random.Generator, sampling: Sampling) -> np.ndarray:
    """count point indices: random without replacement (with, if too few points) or farthest-point sampling."""
    if count <= 0:
        raise DataError(f"points must be positive, got {count}")
    if len(points) == 0:
        raise DataError("cannot sample from an empty scan")
    if len(points) <= count:
        extra = rng.choice(len(points), count - len(points), replace=True)
        return np.concatenate([rng.permutation(len(points)), extra])
    if sampling == "random":
        return np.sort(rng.choice(len(points), count, replace=False))
    return farthest_point_sampling(points, count, int(rng.integers(len(points))))


def farthest_point_sampling(points: np.ndarray, count: int, start: int) -> np.ndarray:
    """Indices of count points picked greedily farthest from those already picked."""
    xyz = points.astype(np.float32)
    chosen = np.empty(count, np.int64)
    chosen[0] = start
    nearest = np.sum((xyz - xyz[start]) ** 2, axis=1)
    for k in range(1, count):
        chosen[k] = int(np.argmax(nearest))
        np.minimum(nearest, np.sum((xyz - xyz[chosen[k]]) ** 2, axis=1), out=nearest)
    return chosen


def simulate(scenario: Scenario, seed: int | None, frames: int) -> Iterator[Frame]:
    """frames + 1 consecutive frames of the scenario driven by the built-in route follower."""
    sim = Simulator(scenario, seed)
    frame = sim.reset()
    driver = sim.follower()
    yield frame
    for _ in range(frames):
        frame = sim.step(driver.command(frame.base_pose, frame.ego.speed, frame.agents, frame.status.outcome))
        yield frame


def kept_points(frame: Frame, protocol: PairProtocol) -> np.ndarray:
    """Indices of the scan points the protocol keeps before sampling."""
    keep = np.ones(len(frame.scan.points), dtype=bool)
    if protocol.max_range is not None:
        keep &= np.linalg.norm(frame.scan.points[:, :2], axis=1) <= protocol.max_range
    if protocol.drop_ground:
        keep &= frame.scan.label != PointClass.GROUND
    return np.flatnonzero(keep)


def _pairs_of(
    frames: Iterator[Frame], seed: int, protocol: PairProtocol
) -> Iterator[tuple[FramePair, Frame, Frame]]:
    previous = next(frames)
    for frame in frames:
        rng = np.random.default_rng([seed, 4, previous.index])
        kept1, kept2 = kept_points(previous, protocol), kept_points(frame, protocol)
        first = kept1[sample_indices(previous.scan.points[kept1], protocol.points, rng, protocol.sampling)]
        second = kept2[sample_indices(frame.scan.points[kept2], protocol.points, rng, protocol.sampling)]
        pair = FramePair(
            pc1=previous.scan.points[first],
            pc2=frame.scan.points[second],
            flow=frame.flow.flow[first],
            instance1=previous.scan.instance[first],
            class1=previous.scan.label[first],
            dynamic1=frame.flow.dynamic[first],
            pose1=previous.pose.copy(),
            pose2=frame.pose.copy(),
        )
        yield pair, previous, frame
        previous = frame


def _scenario(scenario: Scenario | str) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def generate_pairs(
    scenario: Scenario | str, seed: int | None = None, frames: int = 10, protocol: PairProtocol = PROTOCOLS["paper"]
) -> Iterator[FramePair]:
    """frames consecutive pairs of the scenario (seeded, deterministic), cut from the scans by the protocol."""
    scenario = _scenario(scenario)
    seed = scenario.seed if seed is None else seed
    for pair, _, _ in _pairs_of(simulate(scenario, seed, frames), seed, protocol):
        yield pair


def export(
    scenario: Scenario | str,
    out: str | Path,
    seed: int | None = None,
    frames: int = 10,
    protocol: PairProtocol = PROTOCOLS["paper"],
    progress=None,
) -> Path:
    """Write pairs/NNNNNN.npz, sequence/velodyne/NNNNNN.bin + sequence/poses.txt and dataset.json under out."""
    scenario = _scenario(scenario)
    seed = scenario.seed if seed is None else seed
    out = Path(out)
    pair_dir, velodyne = out / "pairs", out / "sequence" / "velodyne"
    try:
        pair_dir.mkdir(parents=True, exist_ok=True)
        velodyne.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{out}: cannot create the output folders ({err.strerror})") from None
    poses = []
    for number, (pair, previous, frame) in enumerate(
        _pairs_of(simulate(scenario, seed, frames), seed, protocol)
    ):
        np.savez(pair_dir / f"{number:06d}.npz", **{key: getattr(pair, key) for key in PAIR_KEYS})
        if number == 0:
            write_bin(velodyne / f"{previous.index:06d}.bin", previous.scan.points, previous.scan.intensity)
            poses.append(previous.pose)
        write_bin(velodyne / f"{frame.index:06d}.bin", frame.scan.points, frame.scan.intensity)
        poses.append(frame.pose)
        if progress is not None:
            progress(number + 1, frames)
    origin = poses[0]
    write_poses(out / "sequence" / "poses.txt", np.linalg.inv(origin) @ np.stack(poses))
    description = {
        "scenario": scenario.model_dump(mode="json"),
        "seed": seed,
        "pairs": frames,
        "protocol": protocol.model_dump(mode="json"),
        "dt": scenario.episode.dt,
        "sensor": scenario.lidar.model_dump(mode="json"),
        "pair_keys": {
            "pc1": "float32 (N,3) scan t in its sensor frame",
            "pc2": "float32 (N,3) scan t+1 in its sensor frame",
            "flow": "float32 (N,3) pc1 + flow lies on the surfaces of scan t+1 "
            "(sensor frame t+1 coordinates minus pc1)",
            "instance1": "int32 agent id, 0 static",
            "class1": "uint8 class (0 ground, 1 building, 2 pole, 3 vegetation, "
            "4 parked car, 5 vehicle, 6 pedestrian)",
            "dynamic1": "bool point on a moving agent",
            "pose1": "float64 4x4 world <- sensor at t",
            "pose2": "float64 4x4 world <- sensor at t+1",
        },
        "sequence": "velodyne/NNNNNN.bin float32 x,y,z,intensity (full scans); poses.txt: KITTI 3x4 rows, "
        "sensor poses relative to the first scan",
        "world_from_first_scan": origin.tolist(),
    }
    (out / "dataset.json").write_text(json.dumps(description, indent=2))
    (out / "scenario.yaml").write_text(dump(scenario))
    return out


def load_pair(path: str | Path) -> FramePair:
    """Read one exported .npz pair, checking keys, shapes and types."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [key for key in PAIR_KEYS if key not in data.files]
            if missing:
                raise DataError(f"{path}: missing keys {', '.join(missing)}")
            arrays = {key: data[key] for key in PAIR_KEYS}
    except (OSError, ValueError) as err:
        raise DataError(f"{path}: not a readable .npz pair ({err})") from None
    count = len(arrays["pc1"])
    for key, shape in (
        ("pc1", (count, 3)),
        ("pc2", (None, 3)),
        ("flow", (count, 3)),
        ("instance1", (count,)),
        ("class1", (count,)),
        ("dynamic1", (count,)),
        ("pose1", (4, 4)),
        ("pose2", (4, 4)),
    ):
        actual = arrays[key].shape
        if len(actual) != len(shape) or any(want is not None and want != got for want, got in zip(shape, actual)):
            raise DataError(
                f"{path}: '{key}' has shape {actual}, expected {tuple('N' if s is None else s for s in shape)}"
            )
    for key in ("pc1", "pc2", "flow", "pose1", "pose2"):
        if not np.isfinite(arrays[key]).all():
            raise DataError(f"{path}: '{key}' holds NaN or Inf")
    return FramePair(
        pc1=arrays["pc1"].astype(np.float32),
        pc2=arrays["pc2"].astype(np.float32),
        flow=arrays["flow"].astype(np.float32),
        instance1=arrays["instance1"].astype(np.int32),
        class1=arrays["class1"].astype(np.uint8),
        dynamic1=arrays["dynamic1"].astype(bool),
        pose1=arrays["pose1"].astype(np.float64),
        pose2=arrays["pose2"].astype(np.float64),
    )


def load_pairs(folder: str | Path) -> Iterator[FramePair]:
    """Every pair of an exported folder (the folder itself or its pairs/ subfolder), in order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder")
    files = sorted(folder.glob("*.npz")) or sorted((folder / "pairs").glob("*.npz"))
    if not files:
        raise DataError(f"{folder}: no .npz pairs (expected an `ssf dataset export` folder)")
    for path in files:
        yield load_pair(path)


assert tuple(field.name for field in fields(FramePair)) == PAIR_KEYS
